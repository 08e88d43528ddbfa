"""Speed of fleet studies: fleet-days per minute in-process, and Ray against in-process on the
same scenarios, side by side in one run; and a timetable (GTFS) network day. Prints a table;
no assertions.

    python -m benchmarks.bench_study              # full run (a few minutes): 100 scenarios
    python -m benchmarks.bench_study --smoke      # CI: 4 short scenarios, same code paths
    python -m benchmarks.bench_study --timetable  # only the network day (full size)

The network day tiles the example feed (King County 45 and 7, made-up timetable) into 200
blocks of at most 7 trips (about 1,300 trips over 5 copies of the routes, each with its own
stops), and times it from reading the feed to the written rows: in this process on 2 threads,
on Ray with 1 and 2 workers (2 days, one task each: a day's blocks share chargers, so a day is
the unit of parallel work), and 10 days on a local two-node cluster (one CPU each), against
in-process with as many threads. Then the depot's optimal plan for the 200 buses at 15-min
steps, with its cost against charging on arrival and a flat spread, from the same day.

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


def network_feed(folder: Path, blocks: int = 200, trips_per_block: int = 7
                 ) -> tuple[Path, Path, Path, int]:
    """The example feed's weekday blocks of routes 45 and 7 cut into blocks of at most
    ``trips_per_block`` trips, tiled (stops, shapes, trips renamed per copy) to ``blocks``
    blocks; the feed (zip), its altitude and speed-limit CSVs, and the number of trips."""
    import zipfile

    import pandas as pd

    from ebus_env import paths
    from ebus_env.gtfs.example_feed import ALTITUDE, FEED, SPEED_LIMITS

    with zipfile.ZipFile(paths.data("gtfs", FEED)) as z:
        t = {n: pd.read_csv(z.open(n), dtype=str, keep_default_na=False) for n in z.namelist()}
    trips = t["trips.txt"]
    trips = trips[(trips["service_id"] == "WK") & (trips["block_id"] != "")].copy()
    first = t["stop_times.txt"].groupby("trip_id")["departure_time"].first()
    trips["dep"] = trips["trip_id"].map(first)
    trips = trips.sort_values(["block_id", "dep"])
    piece = trips.groupby("block_id").cumcount() // trips_per_block
    trips["block_id"] = trips["block_id"] + "p" + piece.astype(str)
    trips = trips.drop(columns=["dep"])
    names = sorted(trips["block_id"].unique())
    side = {n: pd.read_csv(paths.data("gtfs", n), dtype=str) for n in (ALTITUDE, SPEED_LIMITS)}
    out: dict[str, list] = {k: [] for k in ("trips.txt", "stop_times.txt", "stops.txt",
                                            "shapes.txt", ALTITUDE, SPEED_LIMITS)}
    for k in range(-(-blocks // len(names))):
        sfx = f"_t{k}"
        tr = trips[trips["block_id"].isin(names[:blocks - k * len(names)])].copy()
        st = t["stop_times.txt"][t["stop_times.txt"]["trip_id"].isin(tr["trip_id"])].copy()
        parts = {"trips.txt": (tr, ("trip_id", "block_id", "shape_id")),
                 "stop_times.txt": (st, ("trip_id", "stop_id")),
                 "stops.txt": (t["stops.txt"].copy(), ("stop_id",)),
                 "shapes.txt": (t["shapes.txt"].copy(), ("shape_id",)),
                 ALTITUDE: (side[ALTITUDE].copy(), ("shape_id",)),
                 SPEED_LIMITS: (side[SPEED_LIMITS].copy(), ("shape_id",))}
        for name, (frame, columns) in parts.items():
            for c in columns:
                frame[c] = frame[c] + sfx
            out[name].append(frame)
    folder.mkdir(parents=True, exist_ok=True)
    feed = folder / "network.zip"
    with zipfile.ZipFile(feed, "w", zipfile.ZIP_DEFLATED) as z:
        for name, frame in t.items():
            frame = pd.concat(out[name]) if name in out else frame
            z.writestr(name, (frame.iloc[0:0] if name == "frequencies.txt" else frame)
                       .to_csv(index=False))
    for name in (ALTITUDE, SPEED_LIMITS):
        pd.concat(out[name]).to_csv(folder / name, index=False)
    return feed, folder / ALTITUDE, folder / SPEED_LIMITS, sum(map(len, out["trips.txt"]))


def network_study(feed: Path, altitude: Path, limits: Path, days: int, plans=("optimal",)
                  ) -> dict:
    """The example timetable study on the tiled feed: one option (a 150 kW plug at each
    tile's route-45 terminal, depot plugs for 60 % of the buses), ``days`` days."""
    import zipfile

    import pandas as pd

    with zipfile.ZipFile(feed) as z:
        stops = set(pd.read_csv(z.open("stops.txt"), dtype=str)["stop_id"])
    data = yaml.safe_load((ROOT / "configs" / "studies" / "gtfs_example.yaml").read_text())
    data["gtfs"].update(feed=str(feed), altitude=str(altitude), speed_limits=str(limits),
                        routes=None, terminals=sorted(s for s in stops
                                                      if s.startswith("kc45_A_t")))
    buses = len(data["gtfs"]["terminals"]) * 12
    data["infrastructure"].update(terminal_chargers=1, terminal_charger_kw=150,
                                  depot_chargers=int(0.6 * buses), site_limit_kw=30.0 * buses)
    data["strategies"] = [{"name": p, "depot_plan": p} for p in plans]
    data["days"]["count"] = days
    return data


def fresh_run(data: dict, out: Path, **kwargs) -> tuple[float, float]:
    """Wall and CPU time of a timetable study from reading its feed to its written rows."""
    from ebus_env.study import network

    network._STUDIES.clear()  # read the feed again: its reading is part of the time
    network._PHYSICS.clear()
    t0, c0 = time.perf_counter(), time.process_time()
    run_study(load_study(data), out, say=lambda _: None, **kwargs)
    return time.perf_counter() - t0, time.process_time() - c0


def timetable(smoke: bool) -> None:
    """The network day in-process, on Ray, on a two-node cluster, and the depot plan."""
    import os

    import pandas as pd

    blocks = 20 if smoke else 200
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        feed, altitude, limits, trips = network_feed(tmp / "feed", blocks)
        print(f"timetable network day: {blocks} blocks, {trips} trips (the example feed tiled), "
              "10 Hz, one charging option")
        fresh_run(network_study(feed, altitude, limits, 1), tmp / "warm", workers=2)
        data = network_study(feed, altitude, limits, 1, ("optimal", "on_arrival", "flat"))
        wall, cpu = fresh_run(data, tmp / "one", workers=2)
        row("in-process, 2 threads: feed to rows (3 depot plans)", f"{wall:.1f} s",
            f"CPU {cpu:.1f} s; target <= 20 s on 2 cores")
        rows = pd.read_parquet(tmp / "one" / "rows")
        for _, r in rows.sort_values("cost_day").iterrows():
            row(f"  depot plan {r['strategy']}: cost per day", f"{r['cost_day']:.0f}",
                f"{r['cost_per_km']:.3f}/km, 15-min peak {r['site_peak_15min_kw']:.0f} kW, "
                f"{int(r['buses_not_recharged'])} bus(es) short; {r['depot_plan_solve_s']:.2f} s")
        depot_lp(tmp)
        try:
            import ray  # noqa: F401
        except ImportError:
            row("Ray", "skipped", "not installed (pip install -e '.[scale]')")
            return
        if smoke:  # the Ray runs start runtimes and a cluster: minutes (the full run has them)
            row("Ray and the two-node cluster", "skipped", "in the smoke run")
            return
        days = network_study(feed, altitude, limits, 2)
        for workers in (1, 2):
            local, _ = fresh_run(days, tmp / f"in{workers}", workers=workers)
            runtime = connect_ray(workers=workers)  # up before the run, its workers warm
            try:
                warm(runtime, workers)
                wall, _ = fresh_run(days, tmp / f"ray{workers}", use_ray=True)
            finally:
                runtime.shutdown()
            row(f"2 days, {workers} worker(s): Ray / in-process", f"{wall:.1f} s",
                f"in-process {local:.1f} s, overhead {100 * (wall / local - 1):+.0f} % "
                "(target <= 15 %)")
        from tests.test_study_ray import two_node_cluster

        ten = network_study(feed, altitude, limits, 2 if smoke else 10)
        local, _ = fresh_run(ten, tmp / "in10", workers=2)
        with two_node_cluster(dict(os.environ, EBUS_THREADS="1")) as address:
            runtime = connect_ray(address)
            try:
                warm(runtime, 2)
                wall, _ = fresh_run(ten, tmp / "ray10", address=address)
            finally:
                runtime.shutdown()
        n = ten["days"]["count"]
        row(f"{n} days, two-node cluster (1 CPU each) / in-process", f"{wall:.1f} s",
            f"in-process 2 threads {local:.1f} s, overhead {100 * (wall / local - 1):+.0f} % "
            "(target <= 15 %)")


def _warm_one(seconds: float) -> int:
    """A worker's start: the package imported and the bus model's kernel loaded."""
    import os

    from ebus_env.config import load_bus
    from ebus_env.study import network  # noqa: F401

    load_bus("12m").build(0.1).compile(record=True)
    time.sleep(seconds)  # hold the worker so that the next warm task lands on another
    return os.getpid()


def warm(runtime, workers: int) -> None:
    """Start ``workers`` Ray workers and warm them (import, kernel from the disk cache): the
    runtime is up before the run, as a standing cluster's is."""
    task = runtime.remote(num_cpus=1)(_warm_one)
    pids = set(runtime.get([task.remote(2.0) for _ in range(workers)]))
    if len(pids) < workers:
        print(f"  (warmed {len(pids)} of {workers} workers)")


def depot_lp(tmp: Path) -> None:
    """The depot's optimal plan for 200 buses at 15-min steps: solve time and cost against
    charging on arrival and a flat spread, on a made-up night (arrivals 19-25 h, departures
    04:30-07:00 the next day, needs 80-300 kWh, 120 plugs of 100 kW, 6 MW)."""
    import numpy as np

    from ebus_env.study.depot_plan import STEP_S, plan

    data = yaml.safe_load((ROOT / "configs" / "studies" / "gtfs_example.yaml").read_text())
    prices = np.asarray(data["costs"]["energy_price_per_kwh"], float)
    demand = data["costs"]["demand_charge_per_kw_month"] * 12 / data["costs"][
        "operating_days_per_year"]
    rng = np.random.default_rng(0)
    arrive, depart = rng.uniform(19, 25, 200) * 3600, rng.uniform(28.5, 31, 200) * 3600
    need = rng.uniform(80, 300, 200)
    costs = {}
    for method in ("optimal", "on_arrival", "flat"):
        t0 = time.perf_counter()
        p = plan(method, arrive, depart, need, 120, 100.0, 0.95, 6000.0, prices, demand)
        took = time.perf_counter() - t0
        load = p.folded_kw()
        costs[method] = (float((load * STEP_S / 3600 * prices[np.arange(96) // 4]).sum()
                               + demand * load.max()), took, int(p.short.sum()), load.max())
    for method, (cost, took, short, peak) in costs.items():
        row(f"depot, 200 buses, 15-min steps: {method}", f"{cost:.0f} /day",
            f"{took:.2f} s{' (target <= 10 s)' if method == 'optimal' else ''}; peak "
            f"{peak:.0f} kW; {short} short; {100 * (cost / costs['optimal'][0] - 1):+.0f} % "
            "vs optimal")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--smoke", action="store_true", help="small sizes, same code paths")
    parser.add_argument("--scenarios", type=int, default=100)
    parser.add_argument("--timetable", action="store_true", help="only the network day")
    args = parser.parse_args()
    service_h = 1.0 if args.smoke else 13.5
    print(f"fleet study speed ({'smoke' if args.smoke else 'full'} run)")
    if not args.timetable:
        fleet_days(service_h, 2 if args.smoke else 6)
        studies(4 if args.smoke else args.scenarios, service_h)
    timetable(args.smoke)


if __name__ == "__main__":
    main()
