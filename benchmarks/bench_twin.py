"""The live twin's figures: ingest load and acknowledgement latency, re-fit and diagnosis
throughput, prediction latency, prediction accuracy on days the twin has not seen, and live
memory per bus. Prints a table; no assertions.

    python -m benchmarks.bench_twin               # full run (about an hour on 2 cores)
    python -m benchmarks.bench_twin --smoke       # CI: small sizes, same code paths

Ingest: ``ebus twin serve --no-jobs`` in its own process (uvicorn, one worker) on an SQLite
file, and on PostgreSQL where ``initdb`` is installed (``--postgres``); the load generator in
this process streams N buses at 1 Hz in 10-s batches (each bus's batch every 10 s of wall
time, spread over the 10 s), for ``--seconds``. Latency is from sending a batch to its
acknowledgement (durable). CPU shares are of the machine's cores over the run (Linux
``/proc`` times of the twin's process and this one's).

Accuracy (:mod:`benchmarks.twin_accuracy`): the shipped made-up fleet (``data/twin_fleet``)
and a larger made-up one written once by the truth simulator (``--fleet`` buses,
:mod:`benchmarks.twin_fleet`). Each bus's first two days go through the twin's fits whole;
each later day is predicted from the midpoint of its block, unseen: the SoC at the block's end
against the log's, beside a plain energy-per-km baseline (the SoC used per km so far times the
km left), the 90 % band's coverage, and the "will not make it" alarm (band top below the 30 %
reserve) scanned along each block against whether the log went below the reserve. The band's
one constant is set on half of the made-up buses; the figures are on the others.

Re-fit and night jobs: the wall time of each window re-fit and cross-day fit in those replays
(one core each), and of a day's diagnosis; from them, how many buses 2 cores keep up with.
Memory: the live state the twin keeps per bus after predicting it, at two later days.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import tempfile
import threading
import time
import tracemalloc
from pathlib import Path

import numpy as np

from ebus_env import paths

FLEET = paths.here_or_shipped("data/twin_fleet")


def row(what: str, value: str, note: str = "") -> None:
    print(f"  {what:58s} {value:>14s}  {note}", flush=True)


def _cpu_s(pid: int | None = None) -> float:
    stat = Path(f"/proc/{pid or os.getpid()}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(stat[11]) + int(stat[12])) / os.sysconf("SC_CLK_TCK")


def ingest_load(db: str, buses: int, seconds: float, label: str) -> dict:
    """N buses at 1 Hz in 10-s batches against a twin process on ``db``: each bus sends its
    batch every 10 s of wall time, the buses spread evenly over the 10 s; the load generator
    is 32 threads in this process, each with its own keep-alive connection (httpx)."""
    import httpx

    from ebus_env.twin import open_store
    from ebus_env.twin.tokens import create
    from tests.twin_services import free_port, serve

    store = open_store(db)
    tokens = [create(store, fleet="load", bus=f"load-{i:04d}") for i in range(buses)]
    store.engine.dispose()
    port = free_port()
    proc = serve(db, port, "--no-jobs")
    lat: list[float] = []
    lag: list[float] = []  # how late the generator sent (its own lag)
    inside: list[float] = []  # the twin's own time, body in to commit [ms]
    errors: list[int] = []
    work: queue.Queue = queue.Queue()
    t_start = time.time() - 3600.0
    n_rounds = max(1, int(seconds // 10))

    def worker():
        client = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=60)
        while True:
            item = work.get()
            if item is None:
                return
            due, i, k = item
            wait = due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            body = {"batch_id": f"{k}", "samples": [
                {"t": t_start + 10 * k + s, "speed_kmh": 20.0, "soc_pct": 80.0,
                 "ambient_degc": 10.0} for s in range(10)]}
            t0 = time.monotonic()
            lag.append(t0 - due)
            answer = client.post(f"/v1/buses/load-{i:04d}/samples", json=body,
                                 headers={"Authorization": f"Bearer {tokens[i]}"})
            lat.append(time.monotonic() - t0)
            if answer.status_code != 200:
                errors.append(answer.status_code)
            else:
                inside.append(float(answer.headers["server-timing"].split("dur=")[1]))

    threads = [threading.Thread(target=worker, daemon=True) for _ in range(32)]
    for th in threads:
        th.start()
    cpu0, twin0, w0 = _cpu_s(), _cpu_s(proc.pid), time.monotonic()
    load0 = os.getloadavg()[0]
    for k in range(n_rounds):
        for i in range(buses):
            work.put((w0 + 10.0 * k + 10.0 * i / buses, i, k))
    for _ in threads:
        work.put(None)
    for th in threads:
        th.join()
    wall = time.monotonic() - w0
    gen, twin = _cpu_s() - cpu0, _cpu_s(proc.pid) - twin0
    proc.kill()
    proc.wait()
    cores = os.cpu_count() or 1
    ms = 1e3 * np.array(lat)
    out = {"rate": len(lat) / wall, "offered": buses / 10.0, "p50": np.percentile(ms, 50),
           "p99": np.percentile(ms, 99), "max": ms.max(), "errors": len(errors),
           "twin_cpu": twin / wall / cores, "gen_cpu": gen / wall / cores,
           "lag_p99": 1e3 * np.percentile(lag, 99), "load": (load0 + os.getloadavg()[0]) / 2,
           "inside_p50": np.percentile(inside, 50), "inside_p99": np.percentile(inside, 99)}
    row(f"ingest {label}: {buses} buses, 1 Hz, 10-s batches, {wall:.0f} s",
        f"{out['rate']:.0f} batch/s", f"of {out['offered']:.0f} offered; "
        f"{10 * out['rate']:.0f} samples/s, {len(errors)} errors")
    row(f"  ack latency p50 / p99 / max ({label})",
        f"{out['p50']:.0f} / {out['p99']:.0f} / {out['max']:.0f} ms",
        "from sending to the durable answer")
    row(f"  inside the twin, body in to commit, p50 / p99 ({label})",
        f"{out['inside_p50']:.0f} / {out['inside_p99']:.0f} ms", "Server-Timing")
    row(f"  CPU: twin / load generator ({label}), of {cores} cores",
        f"{100 * out['twin_cpu']:.0f} / {100 * out['gen_cpu']:.0f} %",
        f"machine load average {out['load']:.1f}; the generator's own lag p99 "
        f"{out['lag_p99']:.0f} ms")
    return out


def bench_fleet(n: int, seed: int) -> Path:
    """A made-up fleet of ``n`` random buses over four days for the accuracy figures (not
    shipped; written once into the cache folder by the truth simulator)."""
    from benchmarks.twin_fleet import random_fleet, write

    folder = Path(os.environ.get("EBUS_CACHE_DIR", Path.home() / ".cache" / "ebus")) \
        / f"twin_fleet_{n}_{seed}"
    if not (folder / "fleet.json").exists():
        print(f"  (writing a made-up fleet of {n} buses to {folder}: a few minutes, once)",
              flush=True)
        write(folder, random_fleet(n, seed), quiet=True)
    return folder


def _replay(job):
    from benchmarks.twin_accuracy import replay_bus

    return replay_bus(*job)


def _predict(job):
    from benchmarks.twin_accuracy import predict_bus_days

    return predict_bus_days(*job)


def accuracy(fleets: list[tuple[Path, list[str]]], calibrate_on: set[str], out: Path,
             workers: int, days: tuple = ()) -> dict:
    """The accuracy figures (:mod:`benchmarks.twin_accuracy`): every bus's days through the
    twin's fits, the band's constant set on ``calibrate_on``, the figures on the others."""
    from concurrent.futures import ProcessPoolExecutor

    from benchmarks import twin_accuracy as acc
    from ebus_env.twin.forecast import MODEL_ERROR, RATE_WEIGHT

    jobs = [(fleet, bus) for fleet, names in fleets for bus in names]
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with ProcessPoolExecutor(workers) as pool:
        infos = list(pool.map(_replay, [(f, b, out, *days) for f, b in jobs]))
        replay_s = time.perf_counter() - t0
        # the rate's weight on the model's predictions alone, then, on the predictions with
        # it, the band's constant: both set on the buses not reported on
        alone = [r for part in pool.map(_predict, [(f, out, b, MODEL_ERROR, False, 0.0)
                                                   for f, b in jobs]) for r in part]
        rate_weight = acc.set_rate_weight([r for r in alone if r["bus"] in calibrate_on])
        rows = [r for part in pool.map(_predict, [(f, out, b, MODEL_ERROR, False, rate_weight)
                                                  for f, b in jobs]) for r in part]
        model_error = acc.set_model_error([r for r in rows if r["bus"] in calibrate_on])
        scans = list(pool.map(_predict, [(f, out, b, model_error, True, rate_weight)
                                         for f, b in jobs]))
    alarms = {(r["bus"], r["day"]): r for part in scans for r in part}
    for r in rows:
        r.update({k: alarms[r["bus"], r["day"]][k] for k in ("alarm_t", "alarm_says_t")})
    cal = [r for r in rows if r["bus"] in calibrate_on]
    # (the smoke sets the band on its one bus: its figures then are on that bus, code paths)
    rep = [r for r in rows if r["bus"] not in calibrate_on] or cal
    figures = acc.summary(rep, model_error)
    row(f"accuracy on {figures['blocks']} blocks of {figures['buses']} buses the band was "
        "not set on", "", f"their first half seen; replays {replay_s / 60:.0f} min "
        f"({workers} processes)")
    row("  median |error| at the block's end, twin / energy per km",
        f"{figures['twin_mae']:.2f} / {figures['baseline_mae']:.2f}", "SoC points")
    row("  the twin's error below the baseline's (medians)",
        f"{100 * figures['below_baseline']:.0f} %", "bar: >= 30 %")
    for key, label in (("True", "with terminal chargers"), ("False", "depot charging only")):
        if key in figures["chargers"]:
            twin_mae, base_mae, n = figures["chargers"][key]
            row(f"    blocks {label}: twin / baseline", f"{twin_mae:.2f} / {base_mae:.2f}",
                f"{n} blocks")
    row("  90 % band covers the log", f"{100 * figures['coverage']:.0f} %",
        f"bar: >= 85 %; on the {len(cal)} blocks it was set on: "
        f"{100 * acc.coverage(cal, model_error):.0f} %")
    row("  the band's model error (set on the other buses)", f"{model_error:.3f}",
        f"per SoC point moved; the code's default {MODEL_ERROR:.3f}")
    rated = [r for r in alone if r["bus"] in calibrate_on and r["rate_end"] is not None]
    row("  the bus's own rate's weight, no charger ahead (set on the other buses)",
        f"{rate_weight:.2f}", f"on {len(rated)} blocks; the code's default {RATE_WEIGHT:.2f}")
    row("  'will not make it' on blocks that made it",
        f"{figures['false_alarms']} of {figures['made_it']}", "bar: <= 5 %")
    row("  alarms before the bus ran below its reserve, median lead",
        f"{figures['alarmed_in_time']} of {figures['fell']}",
        f"{figures['lead_min']:.0f} min" if figures["lead_min"] is not None else "")
    row("  prediction latency in those runs, point / with band (median)",
        f"{1e3 * np.median([r['point_s'] for r in rows]):.0f} / "
        f"{1e3 * np.median([r['band_s'] for r in rows]):.0f} ms",
        f"{workers} processes on the cores at once")
    return {"infos": infos, "rows": rows, "model_error": model_error,
            "rate_weight": rate_weight, "figures": figures}


def keeping_up(infos: list[dict], ingest: dict | None, diagnose_s: list[float]) -> None:
    """How many buses 2 cores hold: the window re-fits within 15 min, the night's jobs."""
    cores = 2
    window = float(np.median([s for i in infos for s in i["window_s"]]))
    cross = float(np.median([s for i in infos for s in i["cross_day_s"]]))
    row("window re-fit of a bus's day so far (median)", f"{window:.2f} s",
        "one core; the day's first half")
    # the ingest's own CPU at one bus: 90 batches every 15 min
    batch_core_s = 0.0 if not ingest else ingest["twin_cpu"] * cores / ingest["rate"]
    per_bus = window + 90 * batch_core_s
    row("  buses whose windows 2 cores re-fit every 15 min", f"{cores * 900 / per_bus:.0f}",
        f"bar: >= 500; ingest {1e3 * batch_core_s:.1f} core-ms a batch counted")
    row("cross-day fit of a bus (its last 3 days, median)", f"{cross:.0f} s", "one core")
    night = cross + (float(np.median(diagnose_s)) if diagnose_s else 0.0)
    if diagnose_s:
        row("a day's diagnosis (calibrated, against the bus's first day)",
            f"{np.median(diagnose_s):.0f} s", f"one core; {len(diagnose_s)} bus-days")
    row("  buses whose night jobs 2 cores finish in 8 h", f"{cores * 8 * 3600 / night:.0f}",
        "bar: >= 100" + ("" if diagnose_s else "; diagnosis not timed in this run"))
    hold = min(cores * 900 / per_bus, cores * 8 * 3600 / night)
    row("  buses 2 cores hold (the tighter of the two)", f"{hold:.0f}",
        "a Ray cluster of N nodes of c cores: N c / 2 times that for the jobs (independent "
        "tasks; the twin processes and PostgreSQL take the ingest)")


def diagnosis_times(fleet: Path, buses: list[str]) -> list[float]:
    """The wall time of a day's diagnosis in the twin's adapter, per bus: its third day
    against its first, measured as a normal day once before (the twin keeps it per bus)."""
    from ebus_env.twin.closed_days import diagnose_task, reference_task
    from ebus_env.twin.ingest import from_log_file

    out = []
    for bus in buses:
        first, third = (from_log_file(fleet / bus / f"{d}.csv.gz")
                        for d in ("2025-05-05", "2025-05-07"))
        normal = reference_task(first, "12m", 0.2)
        t0 = time.perf_counter()
        diagnose_task(third, normal, "12m", 0.2)
        out.append(time.perf_counter() - t0)
    return out


def prediction_latency(fleets: list[tuple[Path, list[str]]], out: Path) -> None:
    """One bus's prediction at a time in this process (the jobs' way: a bus at a time per
    worker), at each predicted block's midpoint: the first untimed (its trips read, as a live
    twin has them between two trips), then the point and the band, each the median of 3."""
    from ebus_env.twin import Twin, open_store
    from ebus_env.twin.forecast import predict_bus
    from ebus_env.twin.schedule import read_block

    point, band = [], []
    for fleet, names in fleets:
        for bus in names:
            info = json.loads((out / f"{bus}.json").read_text())
            twin = Twin(open_store(out / f"{bus}.sqlite", migrate=False))
            for day, t_half in info["halves"].items():
                block = read_block(json.loads((fleet / bus / f"{day}.block.json")
                                              .read_text()), day)
                predict_bus(twin, bus, block, at_t=t_half)
                for kind, times in ((False, point), (True, band)):
                    took = []
                    for _ in range(3):
                        t0 = time.perf_counter()
                        predict_bus(twin, bus, block, at_t=t_half, band=kind)
                        took.append(time.perf_counter() - t0)
                    times.append(float(np.median(took)))
            twin.store.engine.dispose()
    row("prediction latency of one bus, point / with band (median)",
        f"{1e3 * np.median(point):.0f} / {1e3 * np.median(band):.0f} ms",
        f"bars: 50 ms / 0.5 s; {len(point)} blocks, one at a time; p90 "
        f"{1e3 * np.percentile(point, 90):.0f} / {1e3 * np.percentile(band, 90):.0f} ms")


def _compacted_size(path: Path) -> int:
    """The SQLite file's size once compacted (VACUUM writes through the WAL: checkpointed)."""
    import sqlite3

    db = sqlite3.connect(path)
    try:
        db.execute("VACUUM")
        db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    finally:
        db.close()
    return path.stat().st_size


def memory_and_storage(out: Path, buses: list[str]) -> None:
    """Live state per bus (what a Twin keeps after predicting it: its trips' traces), at the
    midpoint of its third and of its fourth day (more days stored: the state must not grow);
    storage per bus-day of the replays' SQLite files, raw and reduced to 1-min rows."""
    import shutil

    from ebus_env.twin import Twin, open_store
    from ebus_env.twin.forecast import history
    from ebus_env.twin.retention import reduce_old

    live: dict[int, list[float]] = {}
    for k, bus in enumerate([buses[0]] + buses):  # the first: imports and the first read
        info = json.loads((out / f"{bus}.json").read_text())
        twin = Twin(open_store(out / f"{bus}.sqlite", migrate=False))
        for j, (day, t_half) in enumerate(sorted(info["halves"].items())):
            twin.trip_cache.clear()
            tracemalloc.start()
            history(twin, bus, twin.bus_id(bus), day, t_half)
            if k:  # not the warm-up
                live.setdefault(j, []).append(tracemalloc.get_traced_memory()[0] / 1e6)
            tracemalloc.stop()
        twin.store.engine.dispose()
    for k, sizes in sorted(live.items()):
        row(f"live state per bus at day {k + 3}'s midpoint (median of {len(sizes)})",
            f"{np.median(sizes):.2f} MB", f"max {max(sizes):.2f} MB; bar: <= 5 MB, "
            "not growing with the days stored")
    raw, reduced, days = 0, 0, 0
    for bus in buses[:3]:
        info = json.loads((out / f"{bus}.json").read_text())
        days += info["days"]
        copy = out / f"{bus}.copy.sqlite"
        shutil.copy(out / f"{bus}.sqlite", copy)
        raw += _compacted_size(copy)
        store = open_store(copy, migrate=False)
        reduce_old(store, keep_raw_days=0.0, now=4e9)
        store.engine.dispose()
        reduced += _compacted_size(copy)
        for f in out.glob(f"{bus}.copy.sqlite*"):
            f.unlink()
    row("storage per bus-day, SQLite (raw 1 Hz samples, fits, predictions)",
        f"{raw / days / 1e6:.2f} MB", f"{days} bus-days")
    row("  after retention (1-min aggregates)", f"{reduced / days / 1e6:.3f} MB")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--smoke", action="store_true")
    parser.add_argument("--buses", type=int, default=1000, help="ingest: buses streaming")
    parser.add_argument("--seconds", type=float, default=60.0, help="ingest: how long")
    parser.add_argument("--postgres", action="store_true", help="ingest also on PostgreSQL")
    parser.add_argument("--fleet", type=int, default=25,
                        help="accuracy: made-up buses besides the shipped five")
    parser.add_argument("--seed", type=int, default=7, help="accuracy: the made-up fleet's")
    parser.add_argument("--replays", type=Path, default=None,
                        help="accuracy: keep the replays here (reused when there)")
    parser.add_argument("--workers", type=int, default=2, help="accuracy: processes")
    parser.add_argument("--skip", default="", help="comma list: ingest,accuracy,diagnosis")
    args = parser.parse_args(argv)
    skip = set(filter(None, args.skip.split(",")))
    buses, seconds = (50, 10.0) if args.smoke else (args.buses, args.seconds)
    print(f"ebus twin benchmark{' (smoke)' if args.smoke else ''}; machine load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores", flush=True)
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        ingest = None
        if "ingest" not in skip:
            ingest = ingest_load(str(tmp / "load.sqlite"), buses, seconds, "SQLite")
            if args.postgres:
                from tests.twin_services import postgres

                with postgres(tmp) as url:
                    ingest_load(url, buses, seconds, "PostgreSQL")
        if "accuracy" in skip:
            return
        shipped = sorted(p.name for p in FLEET.glob("bus-*"))
        if args.smoke:  # one shipped bus, its band set on itself: the code paths only
            fleets = [(FLEET, shipped[-1:])]
            calibrate_on = set(shipped[-1:])
        else:
            made_up = bench_fleet(args.fleet, args.seed)
            names = sorted(p.name for p in made_up.glob("bus-*"))
            fleets = [(FLEET, shipped), (made_up, names)]
            calibrate_on = set(names[: len(names) // 2])
            row("the band's constant is set on", f"{len(calibrate_on)} buses",
                f"{min(calibrate_on)}..{max(calibrate_on)} (made up, seed {args.seed}); "
                "the figures on the others")
        out = args.replays or tmp / "replays"
        result = accuracy(fleets, calibrate_on, out, args.workers,
                          (2, 1) if args.smoke else ())
        diagnose_s = [] if args.smoke or "diagnosis" in skip else \
            diagnosis_times(FLEET, shipped[:2])
        prediction_latency([(f, [b for b in names if b not in calibrate_on] or names)
                            for f, names in fleets], out)
        keeping_up(result["infos"], ingest, diagnose_s)
        memory_and_storage(out, [i["bus"] for i in result["infos"]][:8])


if __name__ == "__main__":
    main()
