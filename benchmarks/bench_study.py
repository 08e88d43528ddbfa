"""Speed of fleet studies: fleet-days per minute in-process, and Ray against in-process on the
same scenarios, side by side in one run. Prints a table; no assertions.

    python -m benchmarks.bench_study              # full run (a few minutes): 100 scenarios
    python -m benchmarks.bench_study --smoke      # CI: 4 short scenarios, same code paths

A fleet-day is the example study's line (six 12 m buses, a 13.5 h SORT 2 day, Gothenburg in
January) with its terminal and depot chargers, one seeded day. Ray's overhead is its wall time
over the in-process wall time for the same scenarios with the same number of workers (threads
in-process, Ray worker processes), with and without starting the Ray runtime.

On a machine that other jobs keep busy, wall-clock rates only say what the load left over.
The fleet-day rows therefore also give the rate on cores of one's own: each thread's wall time
less the time it was runnable but waiting for a CPU (Linux schedstat), which keeps its time
computing and its time blocked on the GIL.
"""

from __future__ import annotations

import argparse
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import yaml

from ebus_env.study import load_study, runner
from ebus_env.study.backends import connect_ray, run_study
from ebus_env.study.runner import Site, run_scenario
from ebus_env.study.scenarios import scenarios

ROOT = Path(__file__).resolve().parent.parent

EXAMPLE = ROOT / "configs" / "studies" / "example.yaml"


def row(what: str, value: str, note: str = "") -> None:
    print(f"  {what:56s} {value:>12s}  {note}", flush=True)


def study(n_options: int, service_h: float) -> dict:
    """The example line with ``n_options`` charging options (one strategy, one day)."""
    data = yaml.safe_load(EXAMPLE.read_text())
    data["lines"][0]["service_h"] = service_h
    counts, kws, limits = [1, 2, 3, 4, 5], [150, 300, 450, 600], [300, 450, 600, 900, 1200]
    options = [(c, k, x) for c in counts for k in kws for x in limits][:n_options]
    data["infrastructure"] = {"terminal_chargers": sorted({o[0] for o in options}),
                              "terminal_charger_kw": sorted({o[1] for o in options}),
                              "depot_chargers": 3, "depot_charger_kw": 100,
                              "site_limit_kw": sorted({o[2] for o in options})}
    data["strategies"] = [{"name": "baseline"}]
    data["days"]["count"] = 1
    return data


def thread_times() -> tuple[float, float, float]:
    """This thread's (wall clock, time on a CPU, time runnable but waiting for one) [s]; the
    last two from Linux's schedstat (zeros elsewhere)."""
    try:
        on_cpu_ns, queued_ns, _ = Path("/proc/thread-self/schedstat").read_text().split()
    except OSError:
        return time.perf_counter(), 0.0, 0.0
    return time.perf_counter(), int(on_cpu_ns) / 1e9, int(queued_ns) / 1e9


def run_threads(sites: list, days: int) -> tuple[float, float, float]:
    """Each site's ``days`` on a thread of its own, all at once. Returns the wall time, the
    CPU time per fleet-day, and the wall time without the waits for a CPU that other jobs
    caused (the longest thread's time on a CPU plus its time blocked, on the GIL or else)."""
    def one(site):
        start = thread_times()
        for d in range(days):
            site.day(d)
        return [b - a for a, b in zip(start, thread_times(), strict=True)]

    t0 = time.perf_counter()
    with ThreadPoolExecutor(len(sites)) as pool:
        spans = list(pool.map(one, sites))
    wall = time.perf_counter() - t0
    cpu = sum(on_cpu for _, on_cpu, _ in spans) / (len(sites) * days)
    return wall, cpu, max(w - queued for w, _, queued in spans)


def fleet_days(service_h: float, days: int) -> None:
    spec = load_study(study(1, service_h))
    scenario = scenarios(spec)[0]
    sites = [Site(spec, scenario) for _ in range(2)]
    sites[0].day(0)  # compile or load the kernels
    print(f"  one fleet-day: {spec.lines[0].buses} buses, {service_h:g} h, {days} days per "
          "thread; 'own cores': the wall time less the waits for a CPU that other jobs caused")
    for threads in (1, 2):
        wall, cpu, own = run_threads(sites[:threads], days)
        n = threads * days
        row(f"{threads} thread(s): fleet-days per minute", f"{60 * n / wall:.0f}",
            f"wall clock; CPU time {1e3 * cpu:.0f} ms per fleet-day")
        row("  fleet-days per minute on own cores", f"{60 * n / own:.0f}" if own > 0 else "n/a",
            "target >= 500 on 2 cores (13.5 h days)" if threads == 2 else "")


def in_process(spec, out: Path, workers: int) -> tuple[float, float, float]:
    """Run ``spec`` in this process on ``workers`` threads. Returns the wall time, this
    process's CPU time, and the wall time on own cores: less the waits for a CPU of the
    worker thread that waited least (so an underestimate of what own cores would gain)."""
    queued: dict[int, float] = {}

    def timed(*args):
        start = thread_times()
        try:
            return run_scenario(*args)
        finally:
            wait = thread_times()[2] - start[2]
            queued[threading.get_ident()] = queued.get(threading.get_ident(), 0.0) + wait

    t0, c0 = time.perf_counter(), time.process_time()
    runner.run_scenario = timed  # run_study looks it up at each call
    try:
        run_study(spec, out, workers=workers, say=lambda _: None)
    finally:
        runner.run_scenario = run_scenario
    wall = time.perf_counter() - t0
    return wall, time.process_time() - c0, wall - min(queued.values(), default=0.0)


def studies(n: int, service_h: float) -> None:
    """``n`` one-day scenarios in-process on 1 and 2 threads, and on Ray beside them."""
    spec = load_study(study(n, service_h))
    n = len(scenarios(spec))
    try:
        import ray  # noqa: F401
    except ImportError:
        ray = None
    with tempfile.TemporaryDirectory() as tmp:
        walls = {}
        for workers in (1, 2):
            wall, cpu, own = in_process(spec, Path(tmp) / f"threads{workers}", workers)
            walls["in-process", workers] = wall
            row(f"{n} scenarios, {workers} worker(s): in-process", f"{wall:.1f} s",
                f"{60 * n / wall:.0f} fleet-days/min; CPU time {1e3 * cpu / n:.0f} ms each")
            row("  fleet-days per minute on own cores", f"{60 * n / own:.0f}",
                "the whole study: build, days, Parquet")
            if ray is None:
                continue
            t0 = time.perf_counter()
            run_study(spec, Path(tmp) / f"ray{workers}", use_ray=True, workers=workers,
                      say=lambda _: None)
            walls["ray with start", workers] = time.perf_counter() - t0
            runtime = connect_ray(workers=workers)  # started before the clock this time
            try:
                t0 = time.perf_counter()
                run_study(spec, Path(tmp) / f"ray_warm{workers}", use_ray=True,
                          say=lambda _: None)
                walls["ray", workers] = time.perf_counter() - t0
            finally:
                runtime.shutdown()
            for kind in ("ray with start", "ray"):
                wall = walls[kind, workers]
                row(f"  {kind} (runtime {'started in' if kind != 'ray' else 'up before'} "
                    "the run)", f"{wall:.1f} s", f"{60 * n / wall:.0f} fleet-days/min, "
                    f"overhead {100 * (wall / walls['in-process', workers] - 1):+.0f} % "
                    "(target <= 15 %)")
    if ray is None:
        row("Ray", "skipped", "not installed (pip install -e '.[scale]')")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--smoke", action="store_true", help="small sizes, same code paths")
    parser.add_argument("--scenarios", type=int, default=100)
    args = parser.parse_args()
    service_h = 1.0 if args.smoke else 13.5
    print(f"fleet study speed ({'smoke' if args.smoke else 'full'} run)")
    fleet_days(service_h, 2 if args.smoke else 6)
    studies(4 if args.smoke else args.scenarios, service_h)


if __name__ == "__main__":
    main()
