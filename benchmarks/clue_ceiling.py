"""What an operating-mode clue can see of a load outside the library: its ceiling on the bench.

    python -m benchmarks.clue_ceiling [--cache DIR] [--workers 2] [--per-effect N]
    python -m benchmarks.clue_ceiling --current-voltage   # on BMS logs (the counted charge)

On the truth simulator's days whose hidden load the library lacks (an air compressor, a
battery chiller), the log carries the load's own power as well (the oracle column
``logged_load_kw``, the day with the load against the same day without it). The diagnosis's
clue reads the missing power per window by operating mode (its mode table:
:func:`residual.decompose` over the windows' mode shares) and names the mode with the most
missing energy among those whose power stands ``CLUE_SIGMA`` standard errors above zero
(:func:`mode_clue`). This reads the hidden load three ways with the same table and rule,
the model calibrated as the diagnosis calibrates it (rung 0):

1. **the load itself**, as a perfect residual would show it: which mode the windowed reading
   gives the load's own power (largest positive energy, no noise);
2. **what the calibration leaves of it**: the load less what the calibrated parameters'
   signatures take up (:func:`left_over`, the attribution's weights), as a share of its
   power (weighted rms) and by mode;
3. **against the day's noise**: that left-over by mode against the standard errors of the
   day's own mode table: the best any reading of the day's missing power by mode can do.

A mode is right when it holds >= 25 % of the load's energy, row by row (the bench's rule,
``outside_modes``). Prints a row per day and the counts; no assertions.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from benchmarks import out_of_family as bench

OUTSIDE = ("air_compressor", "battery_chiller")


def left_over(load_w: np.ndarray, signatures_w: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """The part of a load (n_windows,) that no combination of the parameters' signatures
    (n_windows, k) takes up: load - S b, with b the weighted least-squares fit
    (weights ``weight``) of S b to the load."""
    root = np.sqrt(weight)
    b, *_ = np.linalg.lstsq(signatures_w * root[:, None], load_w * root, rcond=None)
    return load_w - signatures_w @ b


def ceiling_day(job) -> dict:
    """The three readings of one outside-library day (worker of the pool)."""
    from ebus_env.config import load_bus
    from ebus_env.diagnostics import attribution, residual
    from ebus_env.diagnostics.ladder import calibrate_rung, split_blocks
    from ebus_env.diagnostics.stage04_residual import residual_stage
    from ebus_env.diagnostics.stage05_candidates import candidate_stage
    from ebus_env.diagnostics.stage06_attribution import breakdowns, mode_clue

    source, case, folder, current_voltage = job
    profiles, truth = bench.truth_day(source, case, Path(folder), current_voltage, oracle=True)
    bus = load_bus("12m", without=list(bench.BASELINE_WITHOUT))
    dt_s = profiles[0].dt_s
    model = bus.build(dt_s)
    rung = calibrate_rung(bus, [], profiles, *split_blocks(profiles), dt_s, model=model)
    res = residual_stage(model, profiles, rung.values, None)
    candidates, _ = candidate_stage(bus, res, profiles, [], lambda text: None)
    by_name = {c.name: c for c in candidates}
    free = [n for n in rung.calibration_result.free if n in by_name]
    w, usable, every = res.windows, res.usable, res.anchored[0].record_every
    load_w = np.array([np.mean(residual.channel(res.anchored[w.profile_index[i]],
                                                "logged_load_w")[w.rows(i, every)])
                       for i in range(len(w))])
    weight = attribution.weights(res.noise_w)
    left_w = np.zeros(len(w))
    left_w[usable] = left_over(load_w[usable], np.column_stack(
        [by_name[n].signature_w[usable] for n in free]), weight[usable])

    def by_mode(power_w):  # the diagnosis's own mode table of a power per window
        return breakdowns(res.anchored, w, power_w, res.noise_w, usable)[0]

    own, day = by_mode(load_w), by_mode(res.missing_w)
    # the left-over against the standard errors of the day's own missing power
    kept = [{**k, "stderr_kw": d["stderr_kw"]} for k, d in zip(by_mode(left_w), day,
                                                                strict=True)]

    def largest(modes):
        shown = [m for m in modes if m["missing_kw"] > 0]
        return max(shown, key=lambda m: m["missing_kwh"])["mode"] if shown else None

    return {"case": case.case_id, "right_modes": truth["outside_modes"],
            "mean_load_kw": float(np.mean(load_w[usable])) / 1e3,
            "kept_frac": float(np.sqrt(np.sum(weight[usable] * left_w[usable]**2)
                                       / np.sum(weight[usable] * load_w[usable]**2))),
            "own_clue": largest(own), "left_clue": largest(kept), "clue": mode_clue(kept),
            # the most the left-over stands out of the day's noise in any mode
            "sigmas": max(m["missing_kw"] / m["stderr_kw"] for m in kept),
            "by_mode_kw": {o["mode"]: [round(x, 2) for x in (o["missing_kw"], k["missing_kw"],
                                                             k["stderr_kw"])]
                           for o, k in zip(own, kept, strict=True)}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", type=Path, default=bench.DAYS_CACHE,
                        help="folder of the generated days (shared with bench_diagnose.py)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--per-effect", type=int, default=None, help="the first N days of each")
    parser.add_argument("--current-voltage", action="store_true",
                        help="BMS logs: the pack's current and voltage logged too")
    parser.add_argument("--rows", type=Path, default=None, help="write each day's row (JSON)")
    args = parser.parse_args()
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    args.cache.mkdir(parents=True, exist_ok=True)
    cases = bench.truth_cases("truthsim", False, args.per_effect, 0, OUTSIDE)
    rows = []
    print(f"{'day':20s} {'load kW':>7s} {'left':>5s}  {'own power':14s} {'what is left':14s} "
          f"{'beyond noise':14s} {'sigmas':>6s} right modes")
    with ProcessPoolExecutor(args.workers, mp_context=get_context("spawn")) as pool:
        for row in pool.map(ceiling_day, [("truthsim", c, str(args.cache), args.current_voltage)
                                          for c in cases]):
            rows.append(row)
            print(f"{row['case']:20s} {row['mean_load_kw']:7.2f} {row['kept_frac']:5.0%}  "
                  f"{row['own_clue'] or '-':14s} {row['left_clue'] or '-':14s} "
                  f"{row['clue'] or '-':14s} {row['sigmas']:6.2f} "
                  f"{', '.join(row['right_modes'])}", flush=True)
    if args.rows:
        tmp = args.rows.with_name(args.rows.name + ".tmp")
        tmp.write_text(json.dumps(rows, indent=1))
        tmp.replace(args.rows)
    for key, label in (("own_clue", "the load's own power, read by mode"),
                       ("left_clue", "what the calibration leaves of it"),
                       ("clue", "... above CLUE_SIGMA standard errors (the clue's rule)")):
        right = sum(r[key] in r["right_modes"] for r in rows)
        print(f"right mode, {label}: {right} of {len(rows)}")
    print(f"the left-over's largest power by mode, in standard errors: at most "
          f"{max(r['sigmas'] for r in rows):.2f}")
    print(f"share of the load's power the calibration leaves (weighted rms): "
          f"{min(r['kept_frac'] for r in rows):.0%} to {max(r['kept_frac'] for r in rows):.0%}"
          f", median {np.median([r['kept_frac'] for r in rows]):.0%}")


if __name__ == "__main__":
    main()
