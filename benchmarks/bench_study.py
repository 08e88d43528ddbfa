"""Speed of fleet studies: fleet-days per minute in-process, and Ray against in-process on the
same scenarios, side by side in one run. Prints a table; no assertions.

    python benchmarks/bench_study.py              # full run (a few minutes): 100 scenarios
    python benchmarks/bench_study.py --smoke      # CI: 4 short scenarios, same code paths

A fleet-day is the example study's line (six 12 m buses, a 13.5 h SORT 2 day, Gothenburg in
January) with its terminal and depot chargers, one seeded day. Ray's overhead is its wall time
over the in-process wall time for the same scenarios with the same number of workers (threads
in-process, Ray worker processes), with and without starting the Ray runtime.

On a machine that other jobs keep busy, wall-clock rates only say what the load left over;
the CPU time per fleet-day (``time.process_time`` of this process, the in-process runs) gives
the rate that two cores of one's own would reach, since the compiled passes that take most of
the time release the GIL and the threads scale.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from ebus_env.study import load_study  # noqa: E402
from ebus_env.study.backends import connect_ray, run_study  # noqa: E402
from ebus_env.study.runner import Site  # noqa: E402
from ebus_env.study.scenarios import scenarios  # noqa: E402

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


def fleet_days(service_h: float, days: int) -> None:
    spec = load_study(study(1, service_h))
    scenario = scenarios(spec)[0]
    sites = [Site(spec, scenario) for _ in range(2)]
    sites[0].day(0)  # compile or load the kernels
    walls, cpus = [], []
    for d in range(days):
        t0, c0 = time.perf_counter(), time.process_time()
        sites[0].day(d)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    one, cpu = statistics.median(walls), statistics.median(cpus)
    row(f"one fleet-day ({spec.lines[0].buses} buses, {service_h:g} h), 1 thread",
        f"{1e3 * one:.0f} ms", f"median of {days}; {60 / one:.0f} fleet-days/min")
    held = gil_held_share(sites[0], days)
    row("  CPU time per fleet-day", f"{1e3 * cpu:.0f} ms",
        f"{60 / cpu:.0f} fleet-days per CPU-minute")
    row("  share of it holding the GIL (outside the compiled passes)", f"{100 * held:.0f} %",
        f"2 threads at most {min(2.0, 1.0 / held):.2f} x one")
    row("  fleet-days per minute on 2 cores of our own (from CPU time)",
        f"{min(2.0, 1.0 / held) * 60 / cpu:.0f}", "target >= 500 (13.5 h days)")
    t0 = time.perf_counter()
    with ThreadPoolExecutor(2) as pool:
        list(pool.map(lambda s: [s.day(d) for d in range(days)], sites))
    both = time.perf_counter() - t0
    row("  fleet-days per minute, 2 threads", f"{60 * 2 * days / both:.0f}",
        "wall clock: what the machine's load left us")


def gil_held_share(site: Site, days: int) -> float:
    """The share of a fleet-day's CPU time spent outside the GIL-free compiled passes (the
    reference driving, and the physics with its scoring): what two threads cannot overlap."""
    inside = [0.0]

    def timed(method):
        def call(*args):
            t0 = time.thread_time()
            method(*args)
            inside[0] += time.thread_time() - t0
        return call

    for batch in site.lines:
        batch.drive, batch.run = timed(batch.drive), timed(batch.run)
    t0 = time.thread_time()
    for d in range(days):
        site.day(d)
    total = time.thread_time() - t0
    for batch in site.lines:
        del batch.drive, batch.run
    return 1.0 - inside[0] / total


def ray_side_by_side(n: int, service_h: float) -> None:
    spec = load_study(study(n, service_h))
    n = len(scenarios(spec))
    quiet = lambda _: None  # noqa: E731
    with tempfile.TemporaryDirectory() as tmp:
        walls, cpus = {}, {}
        for workers in (1, 2):
            t0, c0 = time.perf_counter(), time.process_time()
            run_study(spec, Path(tmp) / f"threads{workers}", workers=workers, say=quiet)
            walls["in-process", workers] = time.perf_counter() - t0
            cpus[workers] = time.process_time() - c0
            t0 = time.perf_counter()
            run_study(spec, Path(tmp) / f"ray{workers}", use_ray=True, workers=workers, say=quiet)
            walls["ray with start", workers] = time.perf_counter() - t0
            ray = connect_ray(workers=workers)  # started before the clock this time
            try:
                t0 = time.perf_counter()
                run_study(spec, Path(tmp) / f"ray_warm{workers}", use_ray=True, say=quiet)
                walls["ray", workers] = time.perf_counter() - t0
            finally:
                ray.shutdown()
    for workers in (1, 2):
        base = walls["in-process", workers]
        row(f"{n} scenarios, {workers} worker(s): in-process", f"{base:.1f} s",
            f"{60 * n / base:.0f} fleet-days/min")
        row("  CPU time per fleet-day (whole study: build, days, Parquet)",
            f"{1e3 * cpus[workers] / n:.0f} ms",
            f"{2 * 60 * n / cpus[workers]:.0f} fleet-days/min on 2 cores of our own")
        for kind in ("ray with start", "ray"):
            wall = walls[kind, workers]
            row(f"  {kind} (runtime {'started in' if kind != 'ray' else 'up before'} the run)",
                f"{wall:.1f} s", f"{60 * n / wall:.0f} fleet-days/min, overhead "
                f"{100 * (wall / base - 1):+.0f} % (target <= 15 %)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--smoke", action="store_true", help="small sizes, same code paths")
    parser.add_argument("--scenarios", type=int, default=100)
    args = parser.parse_args()
    service_h = 1.0 if args.smoke else 13.5
    print(f"fleet study speed ({'smoke' if args.smoke else 'full'} run)")
    fleet_days(service_h, 2 if args.smoke else 6)
    try:
        import ray  # noqa: F401
    except ImportError:
        row("Ray", "skipped", "not installed (pip install -e '.[scale]')")
        return
    ray_side_by_side(4 if args.smoke else args.scenarios, service_h)


if __name__ == "__main__":
    main()
