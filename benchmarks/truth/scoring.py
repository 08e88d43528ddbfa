"""The truth bench's figures: per log type and truth source, single days and multi-day buses,
against the bars of the diagnosis's targets; the headline is the worst source it was not
tuned on.

Every function reads the rows of :func:`benchmarks.out_of_family.run_job` (one per day or
bus, JSON-able), so a bench run part-way, or several runs' rows files, report alike.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

LOGS = ("bms", "soc")
LOG_NAMES = {"bms": "BMS logs (pack current and voltage)", "soc": "SoC-only logs"}
STRENGTH_TOLERANCE = 0.25
MIN_TRUTH_KWH = 0.5
"""Days whose hidden effect adds less energy than this (a weak cell group's extra losses)
are left out of the energy figures: a ratio to almost nothing says nothing."""
START_TOLERANCE_DAYS = 1
BARS = {
    # figure: (BMS logs, SoC only); "<=" figures are upper bars
    "top1": (0.90, 0.80),
    "top1_bus": (0.95, 0.90),
    "start_day": (0.90, 0.80),
    "wrong": (0.02, 0.02),
    "false_alarms": (0.05, 0.05),
    "outside_no_library": (0.90, 0.80),
    "outside_mode": (0.80, 0.80),
    "fall": (0.50, 0.50),
    "energy": (0.70, 0.60),
    "energy_coverage": (0.80, 0.80),
    "time_day_s": (45.0, 60.0),
    "time_bus_s": (180.0, 240.0),
}
UPPER = {"wrong", "false_alarms", "time_day_s", "time_bus_s"}
CEILING_MARGIN = 0.05
"""A top-1 bar above what the logs hold is met at the ceiling less this (5 points): the share
of the days whose hidden effect the source's own model separates (``benchmarks.ceiling``)."""
NOT_GIVEN = "not given"


def line(what: str, value: str, note: str = "") -> None:
    print(f"  {what:58s} {value:>18s}  {note}", flush=True)


def share(part, whole) -> tuple[float, int]:
    """(fraction, denominator); NaN of 0 where there is nothing to count."""
    return (len(part) / len(whole), len(whole)) if whole else (float("nan"), 0)


def log_of(row: dict) -> str:
    """A row's log type (rows of earlier runs carry none: a log with the pack's voltage
    gave a resistance reading)."""
    return row.get("log") or ("bms" if row.get("resistance") else "soc")


def kind_of(row: dict) -> str:
    return row.get("kind", "day")


def is_library(expected) -> bool:
    return expected not in (None, "outside_library")


def wrong(row: dict) -> bool:
    """A library effect named that is not the hidden one (on a control day or for a load
    outside the library, any library verdict)."""
    return bool(row["verdict"]) and not row["right"] and row["verdict"] != "replayed_load"


def fall_of(row: dict) -> float:
    """The held-out error fall after adding the right effect: on a BMS log the counted
    charge's (the power residual's) where the ladder gives it, else the SoC NRMSE's; NaN
    where none was measured."""
    fall = row.get("fall_charge") if log_of(row) == "bms" and "fall_charge" in row \
        else row.get("fall")
    return float("nan") if fall is None else fall


def confusion(rows, title: str = "") -> None:
    """True effect x verdict (counts)."""
    if not rows:
        return

    def label(value):
        return "control" if value is None else value

    truths = sorted({label(r["expected"]) for r in rows})
    verdicts = sorted({r["verdict"] or r["status"] for r in rows})
    width = max(map(len, truths)) + 2
    print(f"\nConfusion matrix{title} (rows: true effect; columns: verdict, or why none)")
    print(" " * width + " | ".join(f"{v[:15]:>15s}" for v in verdicts))
    for t in truths:
        counts = [sum(1 for r in rows if label(r["expected"]) == t
                      and (r["verdict"] or r["status"]) == v) for v in verdicts]
        print(f"{t:<{width}s}" + " | ".join(f"{c:>15d}" for c in counts))


def figures(rows) -> dict:
    """The single days' figures, each with the number of days behind it."""
    library = [r for r in rows if is_library(r["expected"])]
    control = [r for r in rows if r["expected"] is None]
    outside = [r for r in rows if r["expected"] == "outside_library"]
    right = [r for r in library if r["right"]]
    shared = [(r, k) for r in right for k in r["estimate"] if k in r["truth"]]
    energies = [r for r in right if r["energy_kwh"] is not None and r["truth_kwh"]
                and abs(r["truth_kwh"]) >= MIN_TRUTH_KWH]
    falls, falls_charge, falls_first = {}, {}, {}
    for r in library + outside:
        label = (f"{r['added'].split(':')[-1]} (user's file)"
                 if r["expected"] == "outside_library" else r["expected"])
        falls.setdefault(label, []).append(fall_of(r))
        if "fall_first_search" in r:
            falls_first.setdefault(label, []).append(r["fall_first_search"])
        if "fall_charge" in r:
            falls_charge.setdefault(label, []).append(r["fall_charge"])
    # what adding an effect that is not there does to a control day's held-out error
    rises = [-fall_of(r) for r in control if np.isfinite(fall_of(r))]
    rise_p95 = float(np.percentile(rises, 95)) if rises else float("nan")
    risen = [r for r in library + outside if np.isfinite(fall_of(r))
             and -fall_of(r) > rise_p95] if rises else []
    ten_h = [r["time_s"] * 10.0 / r["hours"] for r in rows]
    ten_h_cpu = [r["cpu_s"] * 10.0 / r["hours"] for r in rows]
    said_outside = [r for r in outside if r["status"] == "outside library"]
    with_mode = [r for r in said_outside if r["clue"]]
    checked = [r for r in rows if r.get("resistance")]  # logs with the pack's voltage

    def changing(days):
        return share([r for r in days if r["resistance"]["changes"]], days)

    return {
        "top1": share(right, library),
        # the ranking's first effect, named or not: a lead on a day left open (a control day's
        # ranking has a first effect too)
        "ranked_first": share([r for r in library if r.get("top") == r["expected"]], library),
        "open_ranked_first": share([r for r in library if not r["right"]
                                    and r.get("top") == r["expected"]],
                                   [r for r in library if not r["right"]]),
        "wrong": share([r for r in rows if wrong(r)], rows),
        "false_alarms": share([r for r in control if r["verdict"]], control),
        # the clue is right when it names a mode that takes >= 25 % of the load's energy
        "outside": share([r for r in said_outside if r["clue"] in r["outside_modes"]], outside),
        "outside_no_library": share(said_outside, outside),
        "outside_mode_named": share(with_mode, said_outside),
        "outside_mode": share([r for r in with_mode if r["clue"] in r["outside_modes"]],
                              with_mode),
        # "no library effect explains it" on a day with nothing hidden: the calibrated bus
        # misses power beyond the log's noise all the same
        "control_outside": share([r for r in control if r["status"] == "outside library"],
                                 control),
        # a clue on a day with nothing hidden: where the calibrated bus itself misses power,
        # what a clue on an outside-library day must stand out of
        "control_clue": share([r for r in control if r["clue"]], control),
        "control_modes": Counter(r["clue"] for r in control if r["clue"]).most_common(),
        # the calibrated bus pressed against the ends of its ranges with nothing hidden: how
        # far the other simulator's bus lies from what the library's parameters can take up
        "control_ends": share([r for r in control if r.get("range_ends")], control),
        "control_end_params": Counter(f"{n.split('.')[-1]} {side}" for r in control
                                      for n, side in r.get("range_ends", {}).items())
        .most_common(),
        # (no fall where the ladder was not run, --no-ladder)
        "fall": {k: float(np.nanmedian(v)) for k, v in falls.items() if np.isfinite(v).any()},
        "fall_charge": {k: float(np.nanmedian(v)) for k, v in falls_charge.items()},
        # the same against the diagnosis's first calibration, not searched again
        "fall_first_search": {k: float(np.nanmedian(v)) for k, v in falls_first.items()},
        "control_rise_p95": (rise_p95, len(rises)),
        "risen": share(risen, [r for r in library + outside if np.isfinite(fall_of(r))]),
        "strength": share([1 for r, k in shared if abs(r["estimate"][k] / r["truth"][k] - 1)
                           <= STRENGTH_TOLERANCE], shared),
        "coverage": share([1 for r, k in shared if r["interval"][k][0] <= r["truth"][k]
                           <= r["interval"][k][1]], shared),
        "energy": share([r for r in energies if abs(r["energy_kwh"] / r["truth_kwh"] - 1)
                         <= STRENGTH_TOLERANCE], energies),
        "energy_coverage": share([r for r in energies if r["energy_interval_kwh"][0]
                                  <= r["truth_kwh"] <= r["energy_interval_kwh"][1]], energies),
        # the logged voltage shows the pack's resistance changing: on cold-battery days
        # (a pack warming by its losses) and on the others
        "resistance_cold": changing([r for r in checked if r["hidden"] == "cold_battery"]),
        "resistance_other": changing([r for r in checked if r["hidden"] != "cold_battery"]),
        "time_s": (float(np.median(ten_h)) if ten_h else float("nan"), len(ten_h)),
        "cpu_s": (float(np.median(ten_h_cpu)) if ten_h else float("nan"), len(ten_h)),
    }


def start_day_found(row: dict) -> bool | None:
    """Whether a bus's diagnosis dated the change within ``START_TOLERANCE_DAYS`` of its
    days (the bus's service days, not calendar days) of the truth's start day; None where
    the diagnosis gives no start (``since`` absent or null)."""
    since = row.get("since")
    if not since:
        return None
    dates = np.array(row["dates"], dtype="datetime64[D]")
    found = int(np.argmin(np.abs(dates - np.datetime64(str(since)[:10], "D"))))
    return abs(found - row["start_day"]) <= START_TOLERANCE_DAYS


def bus_figures(rows) -> dict:
    """The multi-day buses' figures, each with the number of buses behind it."""
    library = [r for r in rows if is_library(r["expected"])]
    control = [r for r in rows if r["expected"] is None]
    outside = [r for r in rows if r["expected"] == "outside_library"]
    faults = [r for r in rows if r.get("condition_kind") == "from_day"]
    given = [r for r in faults if "since" in r]
    dated = [r for r in given if start_day_found(r)]
    said_outside = [r for r in outside if r["status"] == "outside library"]
    with_mode = [r for r in said_outside if r["clue"]]
    six = [r["time_s"] * 6.0 / r["days"] for r in rows]
    return {
        "top1_bus": share([r for r in library if r["right"]], library),
        "ranked_first": share([r for r in library if r.get("top") == r["expected"]], library),
        # the start day is scored where the diagnosis says one: "not given" where it never does
        "start_day": share(dated, given) if given else (NOT_GIVEN, len(faults)),
        "start_day_right_verdict": share([r for r in given if r["right"] and start_day_found(r)],
                                         [r for r in given if r["right"]]),
        "wrong": share([r for r in rows if wrong(r)], rows),
        "false_alarms": share([r for r in control if r["verdict"]], control),
        "outside_no_library": share(said_outside, outside),
        "outside_mode_named": share(with_mode, said_outside),
        "outside_mode": share([r for r in with_mode if r["clue"] in r["outside_modes"]],
                              with_mode),
        "time_bus_s": (float(np.median(six)) if six else float("nan"), len(six)),
    }


def fmt(value, n=None) -> str:
    if isinstance(value, str):
        return value
    if value is None or not np.isfinite(value):
        return "-"
    return f"{100 * value:.0f} %"


def bar_note(key: str, log: str, n: int, unit: str = "days") -> str:
    low, high = BARS[key]
    bar = low if log == "bms" else high
    sign = "<=" if key in UPPER else ">="
    shown = f"{bar:g} s" if key.startswith("time") else f"{100 * bar:g} %"
    return f"bar {sign} {shown}; {n} {unit}"


def ceiling_figures(rows, ceiling: dict, log: str, kind: str = "day") -> dict:
    """On the library days (or buses) ``ceiling`` read (its rows by (source, case)): the share
    whose hidden effect the source's own model separates (a BMS log in its power or its
    voltage), the diagnosis's top-1 on the same days, and the top-1 bar then (the bar, or the
    ceiling less :data:`CEILING_MARGIN` where that is lower). On buses also ``start``: of the
    faults that start on a day, the share whose start the source's own model dates, the
    diagnosis's start day within the tolerance on those, and the start-day bar then."""
    from benchmarks.ceiling import EITHER, with_either

    def reading(row: dict) -> dict:
        read = with_either(row)  # rows of a ceiling without the voltage: the power alone
        return read.get((EITHER if EITHER in read else "bms") if log == "bms" else "soc", {})

    column = 0 if log == "bms" else 1
    read = [r for r in rows if (r["source"], r["case"]) in ceiling]
    days = [r for r in read if is_library(r["expected"])]
    held = [r for r in days if reading(ceiling[(r["source"], r["case"])]).get("separable")]
    held_share, n = share(held, days)
    bar = BARS["top1" if kind == "day" else "top1_bus"][column]
    out = {"held": (held_share, n), "top1": share([r for r in days if r["right"]], days),
           "bar": min(bar, held_share - CEILING_MARGIN) if n else bar}
    if kind == "bus":
        faults = [r for r in read if r.get("condition_kind") == "from_day"]
        dated = [r for r in faults if reading(ceiling[(r["source"], r["case"])]).get("dated")]
        dated_share, n_faults = share(dated, faults)
        start_bar = BARS["start_day"][column]
        out["start"] = {"held": (dated_share, n_faults),
                        "top1": share([r for r in dated if start_day_found(r)], dated),
                        "bar": min(start_bar, dated_share - CEILING_MARGIN) if n_faults
                        else start_bar}
    return out


def print_ceiling(c: dict, unit: str = "days") -> None:
    """The line under a top-1 (or start-day) figure: what the logs hold and the bar then."""
    if c["held"][1]:
        line("  what the logs hold: the source's own model", fmt(c["held"][0]),
             f"the diagnosis on those {unit} {fmt(c['top1'][0])}, bar then >= {fmt(c['bar'])} "
             f"(the ceiling less 5 points where lower); {c['held'][1]} {unit}")


def print_day_figures(f: dict, log: str, workers: int) -> None:
    line("top-1 right over the library's effects", fmt(f["top1"][0]),
         bar_note("top1", log, f["top1"][1]))
    if "ceiling" in f:
        print_ceiling(f["ceiling"])
    line("  the hidden effect ranked first, named or not", fmt(f["ranked_first"][0]),
         f"{f['ranked_first'][1]} days")
    line("a wrong library effect named (all days)", fmt(f["wrong"][0]),
         bar_note("wrong", log, f["wrong"][1]))
    line("control days with a verdict", fmt(f["false_alarms"][0]),
         bar_note("false_alarms", log, f["false_alarms"][1]))
    line("outside library: 'no library effect explains it'", fmt(f["outside_no_library"][0]),
         bar_note("outside_no_library", log, f["outside_no_library"][1]))
    line("  ... an operating mode named", fmt(f["outside_mode_named"][0]),
         f"bar >= 70 %; {f['outside_mode_named'][1]} days")
    line("  ... the right mode when named", fmt(f["outside_mode"][0]),
         bar_note("outside_mode", log, f["outside_mode"][1]))
    line("control days: 'no library effect' all the same", fmt(f["control_outside"][0]),
         f"{f['control_outside'][1]} days")
    line("control days calibrated at an end of a range", fmt(f["control_ends"][0]),
         ", ".join(f"{p} {n}" for p, n in f["control_end_params"]) or "none")
    what = "counted charge's (power) NRMSE" if log == "bms" else "SoC NRMSE"
    for effect, fall in sorted(f["fall"].items()):
        line(f"held-out {what} fall, + {effect} (median)", fmt(fall), "bar >= 50 %")
    rise, n_rise = f["control_rise_p95"]
    line("  control days' rise with a wrong effect added, 95th pct", fmt(rise),
         f"{n_rise} control days")
    line("  effect days rising above it", fmt(f["risen"][0]), f"bar 0; {f['risen'][1]} days")
    line("the effect's energy within +-25 % (named right)", fmt(f["energy"][0]),
         bar_note("energy", log, f["energy"][1], "estimates"))
    line("  its 90 % interval covers the truth's", fmt(f["energy_coverage"][0]),
         bar_note("energy_coverage", log, f["energy_coverage"][1], "estimates"))
    line("strength in the library's terms within +-25 %", fmt(f["strength"][0]),
         f"{f['strength'][1]} estimates")
    line("diagnose --calibrate per 10 h of log (median)", f"{f['time_s'][0]:.0f} s",
         bar_note("time_day_s", log, f["time_s"][1]) + f"; {workers} at once")


def print_bus_figures(f: dict, log: str) -> None:
    line("top-1 right, a bus's days together", fmt(f["top1_bus"][0]),
         bar_note("top1_bus", log, f["top1_bus"][1], "buses"))
    if "ceiling" in f:
        print_ceiling(f["ceiling"], "buses")
    start, n = f["start_day"]
    line("faults from a day: start day within +-1 day", fmt(start),
         bar_note("start_day", log, n, "buses") + (" (the diagnosis gives no 'since')"
                                                  if start == NOT_GIVEN else ""))
    if "ceiling" in f:
        print_ceiling(f["ceiling"]["start"], "buses")
    line("a wrong library effect named (all buses)", fmt(f["wrong"][0]),
         bar_note("wrong", log, f["wrong"][1], "buses"))
    line("control buses with a verdict", fmt(f["false_alarms"][0]),
         bar_note("false_alarms", log, f["false_alarms"][1], "buses"))
    line("outside library: 'no library effect explains it'", fmt(f["outside_no_library"][0]),
         bar_note("outside_no_library", log, f["outside_no_library"][1], "buses"))
    line("  ... an operating mode named / right when named",
         f"{fmt(f['outside_mode_named'][0])} / {fmt(f['outside_mode'][0])}",
         f"bars >= 70 % / >= 80 %; {f['outside_mode_named'][1]} buses")
    line("diagnose --calibrate per 6 days of one bus (median)",
         f"{f['time_bus_s'][0]:.0f} s", bar_note("time_bus_s", log, f["time_bus_s"][1],
                                                 "buses"))


HEADLINE = (
    # (label, day or bus, figure key, how to read its value)
    ("top-1 right over the library's effects, single days", "day", "top1"),
    ("top-1 right, a bus's 6 days together", "bus", "top1_bus"),
    ("faults from a day: the start day within +-1 day", "bus", "start_day"),
    ("a wrong library effect named, days", "day", "wrong"),
    ("a wrong library effect named, buses", "bus", "wrong"),
    ("control days with a verdict", "day", "false_alarms"),
    ("control buses with a verdict", "bus", "false_alarms"),
    ("outside library: 'no library effect explains it', days", "day", "outside_no_library"),
    ("outside library: the right mode when named, days", "day", "outside_mode"),
    ("the effect's energy within +-25 %", "day", "energy"),
    ("  its 90 % interval covers the truth's", "day", "energy_coverage"),
)


def headline(groups: dict, tune_source: str) -> None:
    """Per log type, each figure's worst value over the sources the bench was not tuned on
    (the README's headline), beside the tuning source's."""
    sources = sorted({s for _, s, _ in groups})
    held_out = [s for s in sources if s != tune_source]
    print(f"\nHeadline (tuned on {tune_source}; the worst of {', '.join(held_out) or 'none'})")
    for log in LOGS:
        if not any(g[0] == log for g in groups):
            continue
        print(f"  {LOG_NAMES[log]}")
        for label, kind, key in HEADLINE:
            values = {s: groups.get((log, s, kind), {}).get(key) for s in sources}
            values = {s: v for s, v in values.items() if v is not None and v[1]}
            if not values:
                continue
            scored = {s: v[0] for s, v in values.items() if not isinstance(v[0], str)
                      and np.isfinite(v[0])}
            others = {s: v for s, v in scored.items() if s != tune_source}
            if others:
                pick = max if key in UPPER else min
                worst = pick(others, key=others.get)
                shown = f"{fmt(others[worst])} ({worst})"
            else:
                shown = NOT_GIVEN if any(isinstance(v[0], str) for v in values.values()) \
                    else "-"
            tuned = scored.get(tune_source)
            held = held_of(groups.get((log, worst, kind), {}), key) if others else None
            line(f"  {label}", shown, f"{tune_source} (tuning): {fmt(tuned)}; "
                 + bar_note(key, log, sum(v[1] for v in values.values()),
                            "buses" if kind == "bus" else "days")
                 + (f"; {worst}'s logs hold {fmt(held['held'][0])}, bar then >= "
                    f"{fmt(held['bar'])}" if held and held["held"][1] else ""))


def held_of(figures: dict, key: str) -> dict | None:
    """The ceiling's reading behind a headline figure: the top-1's of days or buses, the
    start day's of buses; None for the other figures."""
    c = figures.get("ceiling")
    if c is None or key not in ("top1", "top1_bus", "start_day"):
        return None
    return c.get("start") if key == "start_day" else c


FOOTPRINT_BINS_PCT = (0.0, 0.5, 1.0, 2.0, 5.0, np.inf)


def footprint_table(rows) -> None:
    """The library effects named right by the hidden effect's SoC footprint (the most it
    moves the SoC against the same day without it): what a SoC log can show of an effect."""
    days = [r for r in rows if is_library(r["expected"]) and r.get("footprint_pct") is not None]
    if not days:
        return
    print("\nNamed right by the hidden effect's SoC footprint (most it moves the SoC)")
    edges = FOOTPRINT_BINS_PCT
    for source in sorted({r["source"] for r in days}):
        for low, high in zip(edges[:-1], edges[1:], strict=True):
            group = [r for r in days if r["source"] == source
                     and low <= r["footprint_pct"] < high]
            if not group:
                continue
            total = Counter(r["expected"] for r in group)
            right = Counter(r["expected"] for r in group if r["right"])
            line(f"{source}: {low:g} to {high:g} percentage points" if np.isfinite(high)
                 else f"{source}: >= {low:g} percentage points",
                 f"{sum(right.values())} of {len(group)}",
                 ", ".join(f"{e} {right[e]}/{n}" for e, n in total.most_common()))


def oracle_table(rows, oracle_name: str) -> None:
    """Per hidden effect: the days named right when the log also carries the effect's own
    power, and the held-out NRMSE fall with that perfect form added."""
    print(f"\nWith the hidden effect in a perfect form ({oracle_name} of the logged effect power)")
    line("hidden effect (source)", "named right", "of them by its perfect form alone; held-out "
         "NRMSE fall with it added (median)")
    groups: dict = {}
    for r in rows:
        effect = r["hidden"] if r["expected"] == "outside_library" else r["expected"]
        groups.setdefault((effect, r["source"]), []).append(r)
    for (effect, source), group in sorted(groups.items()):
        right = [r for r in group if r["right"]]
        fall = np.nanmedian([r.get("fall", float("nan")) for r in group])
        line(f"{effect} ({source})", f"{len(right)} of {len(group)}",
             f"{sum(r['verdict'] == oracle_name for r in right)}; fall {100 * fall:.0f} %")


def report(rows, oracle: bool = False, workers: int = 2, tune_source: str = "truthsim",
           oracle_name: str = "replayed_load", ceiling: dict | None = None) -> dict:
    """Per log type and truth source (the tuning source marked): the confusion matrices and
    figures of single days and of multi-day buses; then the headline. Returns the figures
    by ``(log, source, kind)``. ``ceiling``: the ceiling's rows by (source, case or bus), read
    beside the top-1 of days and buses and the buses' start day (:func:`ceiling_figures`)."""
    groups: dict = {}
    for log in LOGS:
        for source in sorted({r["source"] for r in rows}):
            for kind in ("day", "bus"):
                part = [r for r in rows if log_of(r) == log and r["source"] == source
                        and kind_of(r) == kind]
                if not part:
                    continue
                tuned = " (the tuning source)" if source == tune_source else ""
                what = "single days" if kind == "day" else "multi-day buses"
                print(f"\n== {LOG_NAMES[log]}, {source}{tuned}: {what} ==")
                confusion(part)
                if kind == "day":
                    footprint_table(part)
                    if oracle:
                        oracle_table(part, oracle_name)
                        continue
                    groups[(log, source, kind)] = f = figures(part)
                    if ceiling:
                        f["ceiling"] = ceiling_figures(part, ceiling, log)
                    print("\nFigures against their bars")
                    print_day_figures(f, log, workers)
                else:
                    groups[(log, source, kind)] = f = bus_figures(part)
                    if ceiling:
                        f["ceiling"] = ceiling_figures(part, ceiling, log, "bus")
                    print("\nFigures against their bars")
                    print_bus_figures(f, log)
    if groups and not oracle:
        headline(groups, tune_source)
    return groups
