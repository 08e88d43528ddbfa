"""Diagnosis speed and quality. Prints tables; no assertions.

    python -m benchmarks.bench_diagnose            # full run (several minutes)
    python -m benchmarks.bench_diagnose --smoke    # CI: one case, same code paths
    python -m benchmarks.bench_diagnose --out-of-family [--smoke] [--per-effect N]   # truth bench
    python -m benchmarks.bench_diagnose --out-of-family --log bms   # ... BMS logs only
    python -m benchmarks.bench_diagnose --out-of-family --shard 0/8 --rows r0.json --resume
    python -m benchmarks.bench_diagnose --out-of-family --oracle   # ... the effects' own power
    python -m benchmarks.bench_diagnose --out-of-family --reference   # ... against a normal day

* Out of family (``--out-of-family``): service days made by simulators that are not this
  model (``benchmarks/truth``: an independent forward simulator, a backward-facing
  ADVISOR/VECTO-style model, and FASTSim 3 where installed), one hidden effect per day, base
  parameters drawn per day; and multi-day buses (6 days each, November to February, a fault
  from a given day or an effect every day). Each day, and each bus's days together, is
  diagnosed from its BMS log (the pack's current and voltage) and from its SoC-only log,
  calibrated, on the 12 m bus without the effects that may be hidden (``BASELINE_WITHOUT``);
  on single days the right effect (the library's, or for a load or force the library lacks
  the user's file ``benchmarks/user_effects.py``) is then added and the bus re-calibrated
  (the error ladder). Prints, per log type and source, the confusion matrices and the figures
  against their bars, and the headline: the worst source the rules were not tuned on
  (``--tune-source``). ``--smoke``: the CI subset (``benchmarks.out_of_family.ci_jobs``: a
  few 2.5 h days and one bus of six 1 h days per source, from both log types).

* Speed: ``ebus diagnose`` on a 13.5 h 1 Hz log (the cabin-heating case of
  ``ebus_env.diagnostics.hidden`` stretched to 13.5 h), without and with ``--calibrate``,
  in-process (medians) and as a command (process start, log loading and the HTML report
  included); the first run in a fresh kernel cache apart.
* Hidden-effect days (``data/measured/hidden``): verdict, held-out share, estimate against the
  truth, and the error ladder's fall in held-out NRMSE.
* Real data: BMW i3 trips B16 + B03 without the cabin-heating effect (verdict, correlation of
  the missing power with the logged heater power), B02's capacity problem, and the reserved
  trips B17, B38, A08 (run and reported only); the Renault Twizy trips (all reserved: run
  and reported only), from SoC alone, as configured and without road grade, which the error
  ladder adds back.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks.out_of_family import (
    DAYS_CACHE,
    SOURCES,
    TUNE_SOURCE,
    line,
    out_of_family,
    report,
    row_key,
)
from ebus_env.config import load_bus
from ebus_env.diagnostics import diagnose, hidden
from ebus_env.diagnostics.ladder import improvement
from ebus_env.io.measured import load_log

ROOT = Path(__file__).resolve().parent.parent

BMW = ROOT / "data" / "measured" / "bmw_i3_tum"
TWIZY = ROOT / "data" / "measured" / "rsk_twizy"
def bmw_profiles(*trips, columns="bmw_i3_tum"):
    out = []
    for trip in trips:
        out += load_log(BMW / f"Trip{trip}_1hz.csv", columns=columns).profiles
    return out


def window_mean(d, name):
    """Mean of a logged signal over each window of a diagnosis."""
    out = np.zeros(len(d.windows))
    for w in range(len(d.windows)):
        p = d.runs[d.windows.profile_index[w]].profile
        out[w] = np.mean(p.measured[name][d.windows.start_step[w]:d.windows.stop_step[w]])
    return out


def speed(folder: Path, repeats: int) -> None:
    print("\nSpeed: a 13.5 h 1 Hz log (cabin-heating case, 13.5 h)")
    case = replace(hidden.case("cabin_heating"), hours=13.5)
    path = folder / "day_13h5.csv.gz"
    hidden.generate(case).to_csv(path, index=False)
    bus = hidden.baseline_bus(case)
    t0 = time.perf_counter()
    profiles = load_log(path).profiles
    line("load the log", f"{time.perf_counter() - t0:.2f} s")
    diagnose(bus, profiles)  # compile or load every kernel once
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        d = diagnose(bus, profiles)
        times.append(time.perf_counter() - t0)
    line("diagnose (no calibration), median", f"{statistics.median(times):.2f} s",
         f"target < 10 s; {d.verdict}")
    stages = ", ".join(f"{k[:-2]} {v:.2f}" for k, v in d.timings.items() if k != "total_s")
    line("  stages [s]", "", stages)
    t0 = time.perf_counter()
    d = diagnose(bus, profiles, calibrate=True)
    after = d.nrmse.get("after", d.nrmse["before"])["held_out"]
    line("diagnose --calibrate", f"{time.perf_counter() - t0:.1f} s",
         f"target < 60 s; verdict {d.verdict}; held-out NRMSE "
         f"{d.nrmse['before']['held_out']:.4f} -> {after:.4f}")
    if d.verdict is None:
        line("", "", d.why)
    stages = ", ".join(f"{k[:-2]} {v:.1f}" for k, v in d.timings.items() if k != "total_s")
    line("  stages [s]", "", stages)
    command = [sys.executable, "-m", "ebus_env.cli", "diagnose", str(path), "--bus", "12m",
               "--without", "cabin_hvac", "--html", str(folder / "r.html"), "--json",
               str(folder / "r.json")]
    for label, extra, env, n in (
            ("command, warm kernel cache, median", [], {}, repeats),
            ("command --calibrate, warm kernel cache", ["--calibrate"], {}, 1),
            ("command, fresh kernel cache (compiles every model)", [],
             {"EBUS_CACHE_DIR": str(folder / "fresh-cache")}, 1)):
        times = []
        for _ in range(n):
            t0 = time.perf_counter()
            subprocess.run(command + extra, check=True, capture_output=True,
                           env={**os.environ, **env})
            times.append(time.perf_counter() - t0)
        line(label, f"{statistics.median(times):.1f} s")


def hidden_cases(names, ladder: bool) -> None:
    print("\nHidden-effect days (baseline 12m without the hidden effect)")
    for name in names:
        c = hidden.case(name)
        profiles = load_log(hidden.OUT_DIR / f"{name}.csv.gz").profiles
        t0 = time.perf_counter()
        d = diagnose(hidden.baseline_bus(c), profiles)
        top = d.ranking[0] if d.ranking else {"effect": "-", "explained_fraction": 0.0}
        estimate = ", ".join(f"{k.split('.')[1]} {v:.3g} (true {c.truth.get(k, '-')})"
                             for k, v in (top.get("parameters") or {}).items())
        line(f"{name}: verdict", str(d.verdict),
             f"hidden {c.effect}; top {top['effect']} {100 * top['explained_fraction']:.0f} %;"
             f" {estimate}; {time.perf_counter() - t0:.1f} s")
        if ladder and c.effect:
            t0 = time.perf_counter()
            d = diagnose(hidden.baseline_bus(c), profiles, add=[c.effect])
            r = d.ladder
            line(f"{name}: ladder held-out NRMSE",
                 f"{r[0].held_out['nrmse']:.4f} -> {r[-1].held_out['nrmse']:.4f}",
                 f"fall {100 * improvement(r):.0f} % (needs >= 50 %); calibrated verdict "
                 f"{d.verdict}; {time.perf_counter() - t0:.1f} s")


def pack_temperature(d) -> str:
    """The report's note on the pack's resistance, with what the trips' logged pack
    temperature did (a signal the model does not use: the check on the voltage's finding)."""
    temp = window_mean(d, "batt_temp_c")
    rise = "; ".join(f"{temp[d.windows.of(k)][0]:.1f} -> {temp[d.windows.of(k)][-1]:.1f}"
                     for k in range(len(d.logs)))
    return f"{d.pack_note} Logged pack temperature [degC], first to last window: {rise}."


def bmw(reserved: bool) -> None:
    print("\nBMW i3 (model without cabin_hvac)")
    bus = load_bus("bmw_i3", without=["cabin_hvac"])
    for trips in (("B16", "B03"), ("B03",), ("B16",)):
        d = diagnose(bus, bmw_profiles(*trips))
        heat = window_mean(d, "heating_power_can_kw")
        ok = d.usable
        r_missing = np.corrcoef(d.missing_w[ok], heat[ok])[0, 1]
        note = f"r(missing power, logged heater power) = {r_missing:.2f}"
        if d.verdict_w is not None:
            note += f"; r(inferred heating, logged) = {np.corrcoef(d.verdict_w[ok], heat[ok])[0, 1]:.2f}"
        line(f"{' + '.join(trips)}: verdict", str(d.verdict), note)
        if d.verdict is None:
            line("", "", d.why)
        line("", "", pack_temperature(d))
    print("\nBMW i3 (model without cabin_hvac), the logged heater power as a load "
          "(--columns bmw_i3_tum_heater)")
    for trips in (("B16", "B03"), ("B03",), ("B16",), ("B02",)) + (
            (("B17",), ("B38",)) if reserved else ()):
        d = diagnose(bus, bmw_profiles(*trips, columns="bmw_i3_tum_heater"))
        note = d.why
        if d.verdict and d.status != "voltage":
            top = d.named
            (name, value), = top["parameters"].items()
            low, high = top["interval"][name]
            note = (f"{100 * top['explained_fraction']:.0f} %; {name} {value:.2f} ({low:.2f} to "
                    f"{high:.2f}); held-out NRMSE {d.nrmse['before']['held_out']:.4f} -> "
                    f"{d.nrmse['after']['held_out']:.4f}")
        line(f"{' + '.join(trips)}: verdict", str(d.verdict), note)
        line("", "", pack_temperature(d))
    d = diagnose(load_bus("bmw_i3"), bmw_profiles("B02"))
    for issue in d.data_issues:
        line("B02 data problem", "", issue.get("detail", issue["issue"]))
    if reserved:
        print("\nReserved trips (validation only: run and report)")
        for trip in ("B17", "B38", "A08"):
            d = diagnose(bus, bmw_profiles(trip))
            heat = window_mean(d, "heating_power_can_kw")
            r = np.corrcoef(d.missing_w[d.usable], heat[d.usable])[0, 1] \
                if np.std(heat[d.usable]) > 0 else float("nan")
            line(f"{trip} (without cabin_hvac): verdict", str(d.verdict),
                 f"r(missing, heater) = {r:.2f}; {d.why}")
            line("", "", pack_temperature(d))


def twizy() -> None:
    """The Renault Twizy trips (all reserved: run and reported only), SoC alone: the
    calibrated model as configured, and without road grade, which the error ladder then adds
    back (the trips climb and descend up to 160 m)."""
    print("\nRenault Twizy trips (reserved: run and report), --calibrate, from SoC alone")
    falls = []
    for path in sorted(TWIZY.glob("*_1hz.csv.gz")):
        trip = path.name.removesuffix("_1hz.csv.gz")
        profiles = load_log(path, columns="rsk_twizy").profiles
        d = diagnose(load_bus("twizy"), profiles, calibrate=True)
        line(f"{trip}: verdict, as configured", str(d.verdict),
             f"held-out NRMSE {d.nrmse['configured']['held_out']:.4f} uncalibrated, "
             f"{d.nrmse['before']['held_out']:.4f} "
             f"calibrated; {len(d.windows)} windows; {d.why[:60]}")
        d = diagnose(load_bus("twizy", without=["road_grade"]), profiles, add=["road_grade"])
        r = d.ladder
        falls.append(improvement(r))
        line(f"{trip}: verdict without road_grade", str(d.verdict),
             f"+ road_grade: held-out NRMSE {r[0].held_out['nrmse']:.4f} -> "
             f"{r[-1].held_out['nrmse']:.4f} (fall {100 * falls[-1]:.0f} %); {d.why[:60]}")
    line("held-out NRMSE fall after adding road_grade (median)",
         f"{100 * statistics.median(falls):.0f} %", f"{len(falls)} trips")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--smoke", action="store_true", help="one case, no ladder (CI)")
    parser.add_argument("--part", choices=("speed", "hidden", "bmw", "twizy"), action="append",
                        help="run only these parts (repeatable; default all)")
    parser.add_argument("--out-of-family", action="store_true",
                        help="the truth bench: days from other simulators")
    parser.add_argument("--cache", type=Path, default=None,
                        help="keep the generated truth days here (default: a temp folder)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--per-effect", type=int, default=None,
                        help="out of family: only the first N days of each hidden effect")
    parser.add_argument("--controls", type=int, default=None,
                        help="out of family: only the first N control days")
    parser.add_argument("--source", choices=tuple(SOURCES), action="append",
                        help="truth sources to run (repeatable; default all)")
    parser.add_argument("--current-voltage", action="store_true",
                        help="out of family: BMS logs only (the same as --log bms)")
    parser.add_argument("--log", choices=("bms", "soc"), action="append",
                        help="out of family: the log types (repeatable; default both: BMS logs "
                        "with the pack's current and voltage, and SoC-only logs)")
    parser.add_argument("--kind", choices=("day", "bus"), action="append",
                        help="out of family: single days and/or multi-day buses (repeatable; "
                        "default both)")
    parser.add_argument("--per-condition", type=int, default=None,
                        help="out of family: only the first N multi-day buses of each condition")
    parser.add_argument("--control-buses", type=int, default=None,
                        help="out of family: only the first N control buses of each source")
    parser.add_argument("--shard", default=None,
                        help="out of family: I/N runs every N-th job from the I-th (I from 0), "
                        "with --rows and --resume a resumable part of the whole bench")
    parser.add_argument("--tune-source", choices=tuple(SOURCES), default=TUNE_SOURCE,
                        help="out of family: the source the diagnosis is tuned on; the "
                        "headline is the worst of the others")
    parser.add_argument("--generate-only", action="store_true",
                        help="out of family: make and cache the days (--cache), diagnose none")
    parser.add_argument("--oracle", action="store_true",
                        help="out of family: each log also carries its hidden effect's own "
                        "power (a perfect form of the effect), for bounds")
    parser.add_argument("--rows", type=Path, default=None,
                        help="out of family: write every day's result here (JSON)")
    parser.add_argument("--reference", action="store_true",
                        help="out of family: diagnose each day against a normal day of the "
                        "same bus (diagnose --reference)")
    parser.add_argument("--known-curb-mass", action="store_true",
                        help="out of family: hold each day's true curb mass (a weighed bus; "
                        "diagnose --set vehicle_body.curb_mass_kg=...)")
    parser.add_argument("--effect", action="append", default=[],
                        help="out of family: only the days and buses hiding this effect "
                        "(repeatable; the truth bench's names, e.g. cold_battery), and the "
                        "control days and buses")
    parser.add_argument("--resume", action="store_true",
                        help="out of family: keep the days already in the --rows file and run "
                        "only the others (a bench stopped part-way)")
    parser.add_argument("--no-ladder", action="store_true",
                        help="out of family: verdicts and estimates only, without adding the "
                        "right effect and re-calibrating (about half the time; no falls)")
    parser.add_argument("--from-rows", type=Path, action="append", default=[],
                        help="out of family: report the days of these --rows files, together "
                        "(repeatable), without running them; the first file's row of a day "
                        "is kept")
    parser.add_argument("--ceiling", type=Path, action="append", default=[],
                        help="with --from-rows: the rows of python -m benchmarks.ceiling "
                        "--rows FILE (repeatable; days and --kind bus), read beside the "
                        "top-1 of days and buses and the buses' start day: what the logs "
                        "hold, and the bar then (the ceiling less 5 points where lower)")
    parser.add_argument("--days-per-bus", type=int, default=1,
                        help="out of family: diagnose N days of each case's bus together "
                        "(its day and N - 1 more, the same effect hidden; the truth "
                        "simulator's days)")
    parser.add_argument("--power-domain", action="store_true",
                        help="out of family: the power domain (diagnose --domain power): "
                        "BMS logs second by second, SoC-only logs by the charge the SoC "
                        "counts in each window")
    args = parser.parse_args()
    if args.days_per_bus < 1:
        parser.error(f"--days-per-bus must be 1 or more, not {args.days_per_bus}")
    shard = None
    if args.shard:
        try:
            shard = tuple(int(x) for x in args.shard.split("/"))
            assert len(shard) == 2 and 0 <= shard[0] < shard[1]
        except (ValueError, AssertionError):
            parser.error(f"--shard takes I/N with 0 <= I < N (e.g. 0/8), not {args.shard!r}")
    parts = set(args.part or ("speed", "hidden", "bmw", "twizy"))
    if args.from_rows:
        rows = {}
        for path in args.from_rows:
            for row in json.loads(path.read_text()):
                rows.setdefault(row_key(row), row)
        ceiling = {(r["source"], r["case"]): r for path in args.ceiling
                   for r in json.loads(path.read_text())}
        report(list(rows.values()), args.oracle, args.workers, args.tune_source,
               ceiling or None)
        return
    if args.out_of_family:
        cache = args.cache or DAYS_CACHE
        cache.mkdir(parents=True, exist_ok=True)
        logs = tuple(args.log) if args.log else (("bms",) if args.current_voltage else None)
        out_of_family(cache, args.smoke, args.workers, tuple(args.source or SOURCES),
                      args.per_effect, args.controls, args.current_voltage, args.rows,
                      args.oracle, args.reference, tuple(args.effect), args.resume,
                      args.known_curb_mass, not args.no_ladder, args.days_per_bus,
                      logs=logs, kinds=tuple(args.kind or ("day", "bus")),
                      per_condition=args.per_condition, control_buses=args.control_buses,
                      shard=shard, tune_source=args.tune_source,
                      generate_only=args.generate_only, power_domain=args.power_domain)
        return
    with tempfile.TemporaryDirectory() as folder:
        if args.smoke:
            hidden_cases(["evening_auxiliaries"], ladder=False)
            bmw(reserved=False)
            return
        if "speed" in parts:
            speed(Path(folder), repeats=3)
        if "hidden" in parts:
            hidden_cases([c.name for c in hidden.CASES], ladder=True)
        if "bmw" in parts:
            bmw(reserved=True)
        if "twizy" in parts:
            twizy()


if __name__ == "__main__":
    main()
