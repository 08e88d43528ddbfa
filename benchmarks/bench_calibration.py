"""Calibration speed and quality (issue 3). Prints tables; no assertions.

    python -m benchmarks.bench_calibration            # full run (several minutes)
    python -m benchmarks.bench_calibration --smoke    # CI: small sizes, same code paths

Problems: a synthetic twin (the 12 m bus on a 13.5 h SORT 2 day with 12 charging layovers and a
cold-to-mild ambient ramp, logged at 1 Hz with SoC quantised to 0.1 %; true parameters known),
validated on a second twin day; and the real BMW i3 trip B16 (validated on B03).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ebus_env.calibration import CalibrationProblem, ISOPTSettings, calibrate, isopt
from ebus_env.config import load_bus
from ebus_env.cycles import service_day
from ebus_env.io.measured import load_log
from ebus_env.synthetic import synthetic_log

ROOT = Path(__file__).resolve().parent.parent

TRUTH = {"passenger_load.load_frac": 0.7, "cabin_hvac.setpoint_degc": 21.5,
         "static_rcd.rcd_frac": 0.12, "cccv_taper.cv_soc_pct": 90.0,
         "cccv_taper.decay_per_pct": 0.35, "grid_charger.power_kw": 300.0,
         "regen_cutoff.cutoff_speed_mps": 2.5}
BMW = ROOT / "data" / "measured" / "bmw_i3_tum"


def line(what: str, value: str, note: str = "") -> None:
    print(f"  {what:60s} {value:>16s}  {note}", flush=True)


def twin(model, bus, hours, ambient, seed, folder):
    service = replace(bus.service, layover_charger_kw=None)
    day = service_day("sort2", hours, model.dt_s, service)
    day = day.with_channels(ambient_degc=np.linspace(*ambient, day.n_steps))
    frame = synthetic_log(model, day, TRUTH, soc_start=0.95, period_s=1.0, soc_step_pct=0.1,
                          seed=seed)
    path = Path(folder) / f"twin_{seed}.csv"
    frame.to_csv(path, index=False)
    return load_log(path, model.dt_s).profiles


def one_sim_time(model, profiles) -> float:
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        for p in profiles:
            model.simulate(p, record=False)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def offline_vs_windowed(model, cal, val, settings, seeds):
    steps = sum(p.n_steps for p in cal)
    t_sim = one_sim_time(model, cal)
    line("one simulation of the calibration data (T_sim)", f"{1e3 * t_sim:.1f} ms",
         f"{steps:,} steps")
    for label, kwargs in (("offline iSOPT (11 x 50)", {"polish_starts": 0}),
                          ("offline iSOPT + least-squares polish", {}),
                          ("windowed (online) tuning", {"windowed": True})):
        runs = [calibrate(model, cal, settings=replace(settings, seed=seed), validate=val,
                          **kwargs) for seed in seeds]
        wall = statistics.median(r.wall_time_s for r in runs)
        search = statistics.median(r.timings["search_s"] for r in runs)
        n = statistics.median(r.simulated_steps / steps for r in runs)
        line(label, f"{wall:.1f} s",
             f"of which the search (iSOPT / windows) {search:.1f} s")
        line("", "",
             f"median of {len(runs)} seeds: NRMSE "
             f"{statistics.median(r.fit['nrmse'] for r in runs):.4f}, validation "
             f"{statistics.median(r.validation['nrmse'] for r in runs):.4f}, "
             f"{statistics.median(r.evaluations for r in runs):.0f} evaluations")
        line("    simulated: n full-data equivalents; T_opt vs n x T_sim", f"n = {n:.0f}",
             f"T_opt = {wall:.1f} s vs n x T_sim = {n * t_sim:.1f} s")
        for name in runs[0].free:
            low, high = runs[0].bounds[name]
            errors = [100 * abs(r.values[name] - TRUTH[name]) / (high - low) for r in runs]
            status = [r.determinacy[name].status.split()[0] for r in runs if r.determinacy]
            line(f"    {name}", f"{statistics.median(errors):.1f} %",
                 f"|fit - truth| / range (median); reported: {', '.join(status)}")


def compare_optimisers(problem: CalibrationProblem, budget: int, target: float, seeds):
    """iSOPT, differential evolution (scipy) and CMA-ES (cma) at the same budget."""
    import cma
    from scipy.optimize import differential_evolution

    dim = len(problem.free)

    def tracked(fn):
        log = {"evals": [], "best": []}

        def wrapped(u, threshold=np.inf):
            c = fn(np.atleast_2d(u), threshold)
            best = min(log["best"][-1] if log["best"] else np.inf, float(np.min(c)))
            log["evals"].append((log["evals"][-1] if log["evals"] else 0) + len(c))
            log["best"].append(best)
            return c
        return wrapped, log

    def reach(log):
        hit = [e for e, b in zip(log["evals"], log["best"], strict=True) if b <= target]
        return hit[0] if hit else None

    results = {"iSOPT": [], "differential evolution": [], "CMA-ES": []}
    for seed in seeds:
        f, log = tracked(problem.cost)
        t0 = time.perf_counter()
        run = isopt(f, dim, ISOPTSettings(seed=seed, iterations=(budget - 11) // 22))
        results["iSOPT"].append((run.cost, reach(log), time.perf_counter() - t0, log["evals"][-1]))

        f, log = tracked(lambda u, th=np.inf: problem.cost(u))
        t0 = time.perf_counter()
        pop = 2 * dim  # scipy: popsize x dim members
        de = differential_evolution(lambda x, f=f: f(x.T), [(0.0, 1.0)] * dim, popsize=2,
                                    maxiter=max(1, budget // pop - 1), vectorized=True,
                                    updating="deferred", polish=False, seed=seed, tol=0.0)
        results["differential evolution"].append((float(de.fun), reach(log),
                                                  time.perf_counter() - t0, log["evals"][-1]))

        f, log = tracked(lambda u, th=np.inf: problem.cost(u))
        t0 = time.perf_counter()
        es = cma.CMAEvolutionStrategy(np.full(dim, 0.5), 0.3,
                                      {"bounds": [0, 1], "popsize": 11, "maxfevals": budget,
                                       "seed": seed + 1, "verbose": -9})
        while not es.stop():
            x = np.array(es.ask())
            es.tell(list(x), list(f(x)))
        results["CMA-ES"].append((float(es.result.fbest), reach(log), time.perf_counter() - t0,
                                  log["evals"][-1]))
    for name, runs in results.items():
        costs = [r[0] for r in runs]
        reached = [r[1] for r in runs if r[1] is not None]
        line(name, f"{statistics.median(costs):.4f}",
             f"median final cost of {len(runs)} seeds; target {target:g} reached in "
             f"{len(reached)}/{len(runs)}"
             + (f" after {statistics.median(reached):.0f} evaluations" if reached else "")
             + f"; {statistics.median(r[2] for r in runs):.1f} s, "
             f"{statistics.median(r[3] for r in runs):.0f} evaluations")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--smoke", action="store_true")
    parser.add_argument("--part", choices=("twin", "bmw"), action="append",
                        help="only this part (repeatable; default both): the 12 m twin day "
                        "(offline, windowed, optimisers) or the BMW i3 trips")
    args = parser.parse_args()
    parts = set(args.part or ("twin", "bmw"))
    hours = 2.5 if args.smoke else 13.5
    settings = ISOPTSettings(seed=1, iterations=4 if args.smoke else 50)
    print(f"ebus-env calibration benchmark ({'smoke' if args.smoke else 'full'})")
    if "twin" in parts:
        twin_part(args.smoke, hours, settings)
    if "bmw" in parts:
        bmw_part(args.smoke, settings)


def twin_part(smoke: bool, hours: float, settings: ISOPTSettings) -> None:
    """The 12 m twin day: offline against windowed tuning, and the optimisers."""
    bus = load_bus("12m")
    model = bus.build()
    model.compile(sample=True)
    with tempfile.TemporaryDirectory() as folder:
        cal = twin(model, bus, hours, (-2.0, 12.0), 0, folder)
        val = twin(model, bus, hours, (4.0, 16.0), 1, folder)
        print(f"\nTwin: 12 m bus, {hours:g} h SORT 2, 7 free parameters")
        offline_vs_windowed(model, cal, val, settings, [1] if smoke else [1, 2, 3])
        print("\nOptimisers at the same budget on the twin")
        problem = CalibrationProblem(model, cal)
        budget = 111 if smoke else 1111
        compare_optimisers(problem, budget, 0.01, [1] if smoke else [1, 2, 3])


def bmw_part(smoke: bool, settings: ISOPTSettings) -> None:
    """The BMW i3 calibrated on B16 and validated on B03; the reserved trips run only."""
    print("\nReal data: BMW i3, calibrated on B16, validated on B03 (reserved trips: run only)")
    i3 = load_bus("bmw_i3").build()
    logs = {t: load_log(BMW / f"Trip{t}_1hz.csv", i3.dt_s, columns="bmw_i3_tum").profiles
            for t in ("B16", "B03", "B17", "B38", "A08")}
    car_params = [None, ["passenger_load.load_frac", "cabin_hvac.setpoint_degc",
                         "static_rcd.rcd_frac", "regen_cutoff.cutoff_speed_mps",
                         "auxiliaries.base_power_w", "rolling_resistance.rolling_coef",
                         "efficiency_map.gearbox_efficiency"]]
    for free in car_params[:1] if smoke else car_params:
        label = "paper's seven" if free is None else "car set (7)"
        before = {t: i3.simulate(p[0]).summary()["soc_nrmse"] for t, p in logs.items()}
        result = calibrate(i3, logs["B16"], free, settings=replace(settings, seed=0),
                           validate=logs["B03"])
        params = i3.param_vector(result.values)
        after = {t: i3.simulate(p[0], params).summary()["soc_nrmse"] for t, p in logs.items()}
        line(f"{label}: NRMSE B16 (calibration) / B03 (validation)",
             f"{result.fit['nrmse']:.4f} / {result.validation['nrmse']:.4f}",
             f"defaults: {before['B16']:.4f} / {before['B03']:.4f}; {result.wall_time_s:.1f} s")
        line(f"{label}: reserved B17 / B38 / A08 with these values",
             " / ".join(f"{after[t]:.3f}" for t in ("B17", "B38", "A08")),
             "defaults: " + " / ".join(f"{before[t]:.3f}" for t in ("B17", "B38", "A08")))
        if free is None:  # the same fit with the charge the trips' current counts (--charge)
            counted = calibrate(i3, logs["B16"], free, settings=replace(settings, seed=0),
                                validate=logs["B03"], charge=True)
            for how, r in (("SoC", result), ("SoC and counted charge", counted)):
                line(f"{label}, fitting {how}: NRMSE, energy-drawn error B16 / B03",
                     " / ".join(f"{f['nrmse']:.4f}, {f['energy_error_pct']:+.1f} %"
                                for f in (r.fit, r.validation)), f"{r.wall_time_s:.1f} s")


if __name__ == "__main__":
    main()
