"""The out-of-family truth bench: service days from simulators that are not this model, each
with one hidden effect (or none), diagnosed and scored.

``python -m benchmarks.bench_diagnose --out-of-family`` runs it; other benchmarks import its
pieces (the cases, a cached day, the right-verdict rule).
"""

from __future__ import annotations

import json
import tempfile
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np

from ebus_env.config import load_bus
from ebus_env.diagnostics import diagnose
from ebus_env.diagnostics.ladder import Freedom, improvement
from ebus_env.io.measured import load_log

BENCHMARKS = Path(__file__).resolve().parent
USER_FILE = BENCHMARKS / "user_effects.py"
USER_EFFECTS = {"battery_chiller": f"{USER_FILE}:pack_chiller",
                "air_compressor": f"{USER_FILE}:air_compressor"}
"""For each load the library does not have, the effect a user writes for it
(``benchmarks/user_effects.py``): what the error ladder adds on those days."""



def line(what: str, value: str, note: str = "") -> None:
    print(f"  {what:58s} {value:>18s}  {note}", flush=True)


ORACLE = "replayed_load"
"""On an oracle day (``--oracle``) the log carries the hidden effect's own power, the day with
the effect against the same day without it, as ``logged_load_kw``; this library effect
replays it. Named, or added, it is the hidden effect in a perfect form: what the diagnosis
and the error ladder reach when the library's form is not what limits them."""
BASELINE_WITHOUT = ("cabin_hvac", "passenger_mass", "road_grade")
"""The baseline of the out-of-family bench: the 12 m bus without every sink effect that a
truth day may hide (the slot effects that may be hidden, regen_soc_limit and ambient_battery,
are refinements the 12 m bus does not have, and aux_schedule is not on it)."""
CELLS_PARALLEL = 3.0  # the 12 m pack's strings: the truth's pack capacity is theirs together
SOURCES = {"truthsim": "benchmarks.truth.cases", "fastsim": "benchmarks.truth.fastsim_source"}
SMOKE_HOURS = 4.0
DAYS_CACHE = Path(tempfile.gettempdir()) / "ebus-truth-days"  # the generated days, by default
BARS = {"top1": 0.90, "false_alarms": 0.05, "outside": 0.80, "fall": 0.50, "strength": 0.25,
        "coverage": 0.80, "time_s": 60.0}


def truth_module(source: str):
    """The truth source's module, or the reason it cannot be used."""
    import importlib

    try:
        return importlib.import_module(SOURCES[source]), ""
    except ImportError as exc:  # fastsim not installed, or the source not there
        return None, f"{source} not available ({exc})"


def truth_cases(source: str, smoke: bool, per_effect: int | None = None,
                controls: int | None = None, effects: tuple[str, ...] = ()) -> list:
    """The cases of a source: the whole bench (or its first ``per_effect`` days of each effect,
    of ``effects`` only when given, and first ``controls`` control days), or 1 day per effect
    and 3 controls, each the last ``SMOKE_HOURS`` of its day (so that an evening load stays in
    it)."""
    module, _ = truth_module(source)
    if not smoke:
        taken: dict = {}
        out = []
        for c in module.cases():
            limit = controls if c.hidden is None else per_effect
            taken[c.hidden] = taken.get(c.hidden, 0) + 1
            if (limit is None or taken[c.hidden] <= limit) and (
                    not effects or c.hidden is None or c.hidden in effects):
                out.append(c)
        return out
    return [replace(c, start_clock_h=round(c.start_clock_h + max(c.hours - SMOKE_HOURS, 0), 3),
                    hours=min(c.hours, SMOKE_HOURS)) for c in module.cases(1, 3)]


def truth_day(source: str, case, folder: Path, current_voltage: bool = False,
              oracle: bool = False):
    """A truth day's profiles and truth record, generated once and cached in ``folder``. A
    case cut shorter (the smoke run's last hours of a day) is cached under its own name, so
    that the whole bench never reads a cut day from a shared folder, nor the reverse; so is
    a log with the pack's current and voltage (``current_voltage``, the truth simulator's)
    and a log with the hidden effect's own power (``oracle``, column ``logged_load_kw``)."""

    variant = ("-iv" if current_voltage else "") + ("-oracle" if oracle else "")

    def paths(stem):
        return folder / f"{stem}{variant}.csv.gz", folder / f"{stem}{variant}.json"

    log_path, truth_path = paths(f"{source}-{case.case_id}")
    if truth_path.exists():
        cached = json.loads(truth_path.read_text())
        if (cached["start_clock_h"], cached["hours"]) != (case.start_clock_h, case.hours):
            log_path, truth_path = paths(f"{source}-{case.case_id}-{case.hours:g}h-from-"
                                         f"{case.start_clock_h:g}h")
    if not truth_path.exists():
        module, _ = truth_module(source)
        options = {k: True for k, on in (("current_voltage", current_voltage),
                                          ("oracle", oracle)) if on}
        log, truth = module.generate(case, **options)
        tmp = log_path.with_name(log_path.name + ".tmp")
        log.to_csv(tmp, index=False, compression="gzip")
        tmp.replace(log_path)
        tmp = truth_path.with_name(truth_path.name + ".tmp")  # the record last: the day is whole
        tmp.write_text(json.dumps(truth, default=str))
        tmp.replace(truth_path)
    return load_log(log_path).profiles, json.loads(truth_path.read_text())


def same_bus_days(case, days: int) -> list:
    """The cases of ``days - 1`` more days of the bus of ``case`` (the truth simulator's:
    FASTSim's cases draw their hidden effect per day)."""
    from benchmarks.truth.cases import same_bus_case

    return [same_bus_case(case, day) for day in range(1, days)]


def named_right(expected, verdict: str | None, status: str, effects: list[str],
                oracle: bool) -> bool:
    """Whether a day's verdict is right: the expected effect (None on a control day: no
    verdict); on an oracle day also :data:`ORACLE`, the only right one for a load outside the
    library, or a tie of the library's effect and its perfect form (``effects``: the effect
    candidates, best first)."""
    right = {ORACLE} if oracle and expected == "outside_library" else \
        {expected, ORACLE} if oracle else {expected}
    tied = set(effects[:2]) if status == "tie" else set()
    return verdict in right or (oracle and tied == {expected, ORACLE})


def diagnose_truth_day(job, ladder: bool = True) -> dict:
    """Diagnose one truth day, calibrated, and (``ladder``) add the right effect and
    re-calibrate (worker of the pool). On an oracle day (the log carries the hidden effect's
    own power) the right effect is the library's or :data:`ORACLE`, and the ladder adds
    :data:`ORACLE`: the hidden effect in a perfect form. With ``days`` > 1 the case's day and
    ``days - 1`` more days of the same bus (:func:`~benchmarks.truth.cases.same_bus_case`)
    are diagnosed together, as one bus's logs."""
    from ebus_env.diagnostics.ladder import error_ladder, split_blocks

    source, case, folder, current_voltage, oracle, reference, known_mass, days = (
        *job, False, False, False, False, 1)[:8]
    profiles, truth = truth_day(source, case, Path(folder), current_voltage, oracle)
    for other in same_bus_days(case, days):
        more, their = truth_day(source, other, Path(folder), current_voltage, oracle)
        profiles = [*profiles, *more]
        truth["summary"]["effect_kwh"] += their["summary"]["effect_kwh"]
        truth["summary"]["soc_footprint_pct"] = max(truth["summary"]["soc_footprint_pct"],
                                                    their["summary"]["soc_footprint_pct"])
    bus = load_bus("12m", without=list(BASELINE_WITHOUT))
    freedom = None
    if known_mass:  # a weighed bus: its true curb mass held (the 12 m config's mass bounds
        # widened to the bench's spread of +-15 %)
        bus = replace(bus, bounds={**bus.bounds, "vehicle_body": {
            **bus.bounds.get("vehicle_body", {}), "curb_mass_kg": [9000.0, 17000.0]}})
        freedom = Freedom(fixed={"vehicle_body.curb_mass_kg": truth["base"]["curb_mass_kg"]})
    t0, cpu0 = time.perf_counter(), time.process_time()
    if reference:  # a normal day of the same bus
        from benchmarks.truth.cases import reference_case
        from ebus_env.diagnostics.diagnose import reference_stage

        normal_day = truth_day(source, reference_case(case), Path(folder), current_voltage)[0]
        reference = reference_stage(bus, normal_day, None, None, None, None)
    d = diagnose(bus, profiles, calibrate=True, reference=reference or None, freedom=freedom)
    plain = d.to_json()
    if reference:  # the ladder searches as the diagnosis did
        bus = bus.overlay(reference.overlay(), "the reference day")
        freedom = reference.freedom(bus.build(profiles[0].dt_s), freedom)
    row = {"cpu_s": time.process_time() - cpu0, "source": source, "case": case.case_id,
           "hidden": case.hidden, "expected": truth["expected_verdict"],
           "outside_modes": truth.get("outside_modes") or [],
           "truth": truth.get("strength", {}),
           "verdict": d.verdict, "status": d.status, "clue": d.mode_clue,
           # the missing power by operating mode the clue is read from, and what it moves
           # with: for analyses of the clue's rule
           "modes": plain["modes"], "clues": plain["clues"][:5],
           # on a BMS log: the pack's resistance the logged voltage shows, over the model's
           "resistance": {k: d.resistance[k] for k in ("level", "span", "significance",
                                                       "changes")} if d.resistance else None,
           "top": d.ranking[0]["effect"] if d.ranking else None,
           "estimate": d.named["parameters"] if d.verdict else {},
           "interval": d.named["interval"] if d.verdict else {},
           # the energy the named effect adds over the day, against the truth's: the one
           # strength two structurally different models share (a UA or a derating SoC is
           # defined by each model's own form)
           "energy_kwh": d.named.get("energy_kwh") if d.verdict else None,
           "energy_interval_kwh": d.named.get("energy_interval_kwh") if d.verdict else None,
           "truth_kwh": truth.get("summary", {}).get("effect_kwh"),
           "footprint_pct": truth.get("summary", {}).get("soc_footprint_pct"),
           "days": days, "time_s": time.perf_counter() - t0,
           "hours": sum(p.duration_s for p in profiles) / 3600.0, "why": d.why,
           "range_ends": d.range_ends}
    expected = truth["expected_verdict"]
    row["right"] = named_right(expected, d.verdict, d.status,
                               [r["effect"] for r in d.ranking], oracle)
    # the right effect: the library's, or for a load it lacks the user's own file; on an
    # oracle day the hidden effect's own power
    row["added"] = ORACLE if oracle else (
        USER_EFFECTS.get(case.hidden) if expected == "outside_library" else expected)
    if ladder and row["added"]:
        rungs = error_ladder(bus, profiles, [row["added"]], profiles[0].dt_s,
                             first=d.ladder[0], blocks=split_blocks(profiles), freedom=freedom)
        row["nrmse"] = (rungs[0].held_out["nrmse"], rungs[-1].held_out["nrmse"])
        row["fall"] = improvement(rungs)
        # against the diagnosis's own calibration, where the ladder searched the bus without
        # the effect again from where the bus with it ended and found it fitting better
        row["fall_first_search"] = improvement([d.ladder[0], rungs[-1]])
        if "charge_nrmse" in rungs[0].held_out:  # a BMS log: the counted charge's fall too
            row["fall_charge"] = improvement(rungs, "charge_nrmse")
        row["added_values"] = {k: v for k, v in rungs[-1].values.items()
                               if k.split(".")[0] == rungs[-1].effects[-1]}
    return row


def confusion(rows) -> None:
    """True effect x verdict (counts)."""
    def label(value):
        return "control" if value is None else value

    truths = sorted({label(r["expected"]) for r in rows})
    verdicts = sorted({r["verdict"] or r["status"] for r in rows})
    width = max(map(len, truths)) + 2
    print("\nConfusion matrix (rows: true effect; columns: verdict, or why none)")
    print(" " * width + " | ".join(f"{v[:15]:>15s}" for v in verdicts))
    for t in truths:
        counts = [sum(1 for r in rows if label(r["expected"]) == t
                      and (r["verdict"] or r["status"]) == v) for v in verdicts]
        print(f"{t:<{width}s}" + " | ".join(f"{c:>15d}" for c in counts))


def figures(rows) -> dict:
    """The issue's figures, each with the number of days behind it."""
    library = [r for r in rows if r["expected"] not in (None, "outside_library")]
    control = [r for r in rows if r["expected"] is None]
    outside = [r for r in rows if r["expected"] == "outside_library"]
    right = [r for r in library if r["right"]]
    shared = [(r, k) for r in right for k in r["estimate"] if k in r["truth"]]
    energies = [r for r in right if r["energy_kwh"] is not None and r["truth_kwh"]]
    falls, falls_charge, falls_first = {}, {}, {}
    for r in library + outside:
        label = (f"{r['added'].split(':')[-1]} (user's file)"
                 if r["expected"] == "outside_library" else r["expected"])
        falls.setdefault(label, []).append(r.get("fall", float("nan")))
        if "fall_first_search" in r:
            falls_first.setdefault(label, []).append(r["fall_first_search"])
        if "fall_charge" in r:
            falls_charge.setdefault(label, []).append(r["fall_charge"])
    ten_h = [r["time_s"] * 10.0 / r["hours"] for r in rows]
    ten_h_cpu = [r["cpu_s"] * 10.0 / r["hours"] for r in rows]

    def share(part, whole):
        return (len(part) / len(whole), len(whole)) if whole else (float("nan"), 0)

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
        "false_alarms": share([r for r in control if r["verdict"]], control),
        # the clue is right when it names a mode that takes >= 25 % of the load's energy
        "outside": share([r for r in outside if r["status"] == "outside library"
                          and r["clue"] in r["outside_modes"]], outside),
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
        "strength": share([1 for r, k in shared if abs(r["estimate"][k] / r["truth"][k] - 1)
                           <= BARS["strength"]], shared),
        "coverage": share([1 for r, k in shared if r["interval"][k][0] <= r["truth"][k]
                           <= r["interval"][k][1]], shared),
        "energy": share([r for r in energies if abs(r["energy_kwh"] / r["truth_kwh"] - 1)
                         <= BARS["strength"]], energies),
        "energy_coverage": share([r for r in energies if r["energy_interval_kwh"][0]
                                  <= r["truth_kwh"] <= r["energy_interval_kwh"][1]], energies),
        # the logged voltage shows the pack's resistance changing: on cold-battery days
        # (a pack warming by its losses) and on the others
        "resistance_cold": changing([r for r in checked if r["hidden"] == "cold_battery"]),
        "resistance_other": changing([r for r in checked if r["hidden"] != "cold_battery"]),
        "time_s": (float(np.median(ten_h)) if ten_h else float("nan"), len(ten_h)),
        "cpu_s": (float(np.median(ten_h_cpu)) if ten_h else float("nan"), len(ten_h)),
    }


FOOTPRINT_BINS_PCT = (0.0, 0.5, 1.0, 2.0, 5.0, np.inf)


def footprint_table(rows) -> None:
    """The library effects named right by the hidden effect's SoC footprint (the most it
    moves the SoC against the same day without it): what a SoC log can show of an effect."""
    days = [r for r in rows if r["expected"] not in (None, "outside_library")
            and r.get("footprint_pct") is not None]
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


def oracle_table(rows) -> None:
    """Per hidden effect (the library's effect it should be named as; a load outside the
    library by its own name): the days named right when the log also carries the effect's
    own power (named as the library's effect or as that power, :data:`ORACLE`), and the
    held-out NRMSE fall with the effect in that perfect form added: bounds for what a better
    form of the library's effect could reach on these days."""
    print(f"\nWith the hidden effect in a perfect form ({ORACLE} of the logged effect power)")
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
             f"{sum(r['verdict'] == ORACLE for r in right)}; fall {100 * fall:.0f} %")


def out_of_family(folder: Path, smoke: bool, workers: int = 2,
                  sources: tuple[str, ...] = tuple(SOURCES), per_effect: int | None = None,
                  controls: int | None = None, current_voltage: bool = False,
                  rows_path: Path | None = None, oracle: bool = False,
                  reference: bool = False, effects: tuple[str, ...] = (),
                  resume: bool = False, known_mass: bool = False, ladder: bool = True,
                  days: int = 1) -> None:
    from concurrent.futures import ProcessPoolExecutor
    from functools import partial
    from multiprocessing import get_context

    print("\nOut-of-family truth days (baseline: 12m --without " + ",".join(BASELINE_WITHOUT)
          + " --calibrate)" + (", logs with the pack's current and voltage"
                               if current_voltage else "")
          + (", logs with the hidden effect's own power (oracle; control days left out: "
             "they have none)" if oracle else "")
          + (", each against a normal day of the same bus (--reference)" if reference else "")
          + (", the true curb mass held (--known-curb-mass)" if known_mass else "")
          + (f", {days} days of each bus diagnosed together (--days-per-bus)" if days > 1
             else ""))
    jobs = []
    for source in sources:
        module, why = truth_module(source)
        if module is None:
            print(f"  {why}: skipped")
            continue
        if current_voltage and source != "truthsim":
            print(f"  {source}: its logs have no pack current (SoC only): skipped")
            continue
        if days > 1 and source != "truthsim":
            print(f"  {source}: its days draw their hidden effect each day, not per bus: "
                  "skipped")
            continue
        jobs += [(source, c, str(folder), current_voltage, oracle, reference, known_mass, days)
                 for c in truth_cases(source, smoke, per_effect, controls, effects)
                 if not (oracle and c.hidden is None)]
    rows = []
    if resume and rows_path is not None and rows_path.exists():  # the days already done
        rows = json.loads(rows_path.read_text())
        done = {(r["source"], r["case"]) for r in rows}
        jobs = [j for j in jobs if (j[0], j[1].case_id) not in done]
        print(f"  {len(done)} days from {rows_path}, {len(jobs)} to run")
    with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
        for row in pool.map(partial(diagnose_truth_day, ladder=ladder), jobs):
            rows.append(row)
            if rows_path is not None:  # every day so far, for analyses without a re-run
                tmp = rows_path.with_name(rows_path.name + ".tmp")
                tmp.write_text(json.dumps(rows, default=float, indent=1))
                tmp.replace(rows_path)
            fall = f"; held-out NRMSE fall {100 * row['fall']:.0f} %" if "fall" in row else ""
            line(f"{row['source']}/{row['case']}", str(row["verdict"] or row["status"]),
                 f"expected {row['expected']}; top {row['top']}; clue {row['clue']}; "
                 f"{row['estimate'] or ''} (truth {row['truth'] or '-'})"
                 + (f"; {row['energy_kwh']:.2f} kWh [{row['energy_interval_kwh'][0]:.2f}, "
                    f"{row['energy_interval_kwh'][1]:.2f}] (truth {row['truth_kwh']:.2f})"
                    if row["energy_kwh"] is not None else "") + f"{fall}"
                 + (f" (+ user's {row['added_values']})" if row["expected"] == "outside_library"
                    and "added_values" in row else "") + "; "
                 f"{row['time_s']:.0f} s" + ("" if row["verdict"] else f"; {row['why']}"))
    report(rows, oracle, workers)


def report(rows, oracle: bool = False, workers: int = 2) -> None:
    """The confusion matrix, the footprint table and the figures against their bars (the
    oracle's table on oracle days) of the days' rows."""
    confusion(rows)
    footprint_table(rows)
    if oracle:
        oracle_table(rows)
        return
    f = figures(rows)
    print("\nFigures against their bars")
    line("top-1 right over the library's effects", f"{100 * f['top1'][0]:.0f} %",
         f"bar >= 90 %; {f['top1'][1]} days")
    line("  the hidden effect ranked first, named or not", f"{100 * f['ranked_first'][0]:.0f} %",
         f"{f['ranked_first'][1]} days")
    line("  ... on the days without the right verdict", f"{100 * f['open_ranked_first'][0]:.0f} %",
         f"{f['open_ranked_first'][1]} days")
    line("control days with a verdict", f"{100 * f['false_alarms'][0]:.0f} %",
         f"bar <= 5 %; {f['false_alarms'][1]} days")
    line("outside library: 'no library effect' + right mode", f"{100 * f['outside'][0]:.0f} %",
         f"bar >= 80 %; {f['outside'][1]} days")
    line("control days: 'no library effect' all the same",
         f"{100 * f['control_outside'][0]:.0f} %", f"{f['control_outside'][1]} days")
    line("control days whose report names a mode all the same", f"{100 * f['control_clue'][0]:.0f} %",
         ", ".join(f"{mode} {n}" for mode, n in f["control_modes"]) or "none")
    line("control days calibrated at an end of a range", f"{100 * f['control_ends'][0]:.0f} %",
         ", ".join(f"{p} {n}" for p, n in f["control_end_params"]) or "none")
    if f["resistance_cold"][1] + f["resistance_other"][1]:
        for which, days in (("cold-battery", "cold"), ("other", "other")):
            line(f"the voltage shows the pack's resistance changing: {which} days",
                 f"{100 * f['resistance_' + days][0]:.0f} %",
                 f"{f['resistance_' + days][1]} days")
    for effect, fall in sorted(f["fall"].items()):
        line(f"held-out NRMSE fall, + {effect} (median)", f"{100 * fall:.0f} %", "bar >= 50 %")
        if effect in f["fall_first_search"]:
            line("  against the first calibration, not searched again",
                 f"{100 * f['fall_first_search'][effect]:.0f} %",
                 "what an unlucky first search adds to the fall")
        if effect in f["fall_charge"]:
            line("  the counted charge's held-out NRMSE fall",
                 f"{100 * f['fall_charge'][effect]:.0f} %", "a log of the pack's current")
    line("strength within +-25 % (named right)", f"{100 * f['strength'][0]:.0f} %",
         f"{f['strength'][1]} estimates")
    line("interval covers the truth", f"{100 * f['coverage'][0]:.0f} %",
         f"bar >= 80 %; {f['coverage'][1]} estimates")
    line("the effect's energy within +-25 % (named right)", f"{100 * f['energy'][0]:.0f} %",
         f"{f['energy'][1]} estimates")
    line("  its interval covers the truth's", f"{100 * f['energy_coverage'][0]:.0f} %",
         f"{f['energy_coverage'][1]} estimates")
    line("diagnose --calibrate per 10 h of log (median)", f"{f['time_s'][0]:.0f} s",
         f"bar <= 60 s on 2 cores; {workers} days at once on a shared machine")
    line("  the same, CPU time of the diagnosing process", f"{f['cpu_s'][0]:.0f} s",
         "what it takes when the process has a core to itself")
