"""Diagnosis speed and quality (issue 4). Prints tables; no assertions.

    python benchmarks/bench_diagnose.py            # full run (several minutes)
    python benchmarks/bench_diagnose.py --smoke    # CI: one case, same code paths

* Speed: ``ebus diagnose`` on a 13.5 h 1 Hz log (the cabin-heating case of
  ``ebus_env.diagnostics.hidden`` stretched to 13.5 h), without and with ``--calibrate``,
  in-process (medians) and as a command (process start, log loading and the HTML report
  included); the first run in a fresh kernel cache apart.
* Hidden-effect days (``data/measured/hidden``): verdict, held-out share, estimate against the
  truth, and the error ladder's fall in held-out NRMSE.
* Real data: BMW i3 trips B16 + B03 without the cabin-heating effect (verdict, correlation of
  the missing power with the logged heater power), B02's capacity problem, and the reserved
  trips B17, B38, A08 (run and reported only).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from ebus_env.config import load_bus  # noqa: E402
from ebus_env.diagnostics import diagnose, hidden  # noqa: E402
from ebus_env.diagnostics.ladder import improvement  # noqa: E402
from ebus_env.io.measured import load_log  # noqa: E402

BMW = ROOT / "data" / "measured" / "bmw_i3_tum"


def line(what: str, value: str, note: str = "") -> None:
    print(f"  {what:58s} {value:>18s}  {note}", flush=True)


def bmw_profiles(*trips):
    out = []
    for trip in trips:
        out += load_log(BMW / f"Trip{trip}_1hz.csv", columns="bmw_i3_tum").profiles
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
        print("  Twizy trips: no Renault Twizy bus config yet; not run.")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--smoke", action="store_true", help="one case, no ladder (CI)")
    parser.add_argument("--part", choices=("speed", "hidden", "bmw"), action="append",
                        help="run only these parts (repeatable; default all)")
    args = parser.parse_args()
    parts = set(args.part or ("speed", "hidden", "bmw"))
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


if __name__ == "__main__":
    main()
