"""The live twin's figures: ingest load and acknowledgement latency, re-fit and diagnosis
throughput, prediction latency, prediction accuracy on days the twin has not seen, and live
memory per bus. Prints a table; no assertions.

    python -m benchmarks.bench_twin               # full run (about 30 min on 2 cores)
    python -m benchmarks.bench_twin --smoke       # CI: small sizes, same code paths

Ingest: ``ebus twin serve --no-jobs`` in its own process (uvicorn, one worker) on an SQLite
file, and on PostgreSQL where ``initdb`` is installed (``--postgres``); the load generator in
this process streams N buses at 1 Hz in 10-s batches (each bus's batch every 10 s of wall
time, spread over the 10 s), for ``--seconds``. Latency is from sending a batch to its
acknowledgement (durable). CPU shares are of the machine's cores over the run (Linux
``/proc`` times of the twin's process and this one's).

Accuracy: the shipped made-up fleet (``data/twin_fleet``). Each bus's first two days are
replayed through the twin with its jobs (window re-fits, cross-day fit); its last two days
are then predicted, unseen, from the first half of each block: the SoC at the block's end
against the log's, beside a plain energy-per-km baseline (the SoC used per km so far times
the km left), the band's coverage, and the "will not make it" alarm (band top below the 30 %
reserve) against whether the log went below the reserve.
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


def replay_days(twin, jobs, bus: str, days: list[str], half_last: bool = False) -> None:
    from ebus_env.twin.ingest import from_log_file

    for j, day in enumerate(days):
        twin.store.put_schedule(bus, day, json.loads(
            (FLEET / bus / f"{day}.block.json").read_text()))
        frame = from_log_file(FLEET / bus / f"{day}.csv.gz")
        n = len(frame) // 2 if half_last and j == len(days) - 1 else len(frame)
        for i in range(0, n, 600):
            twin.ingest(bus, frame.iloc[i:min(i + 600, n)])
            if jobs is not None:
                jobs.run_bus(bus)


def accuracy(buses: list[str], train: list[str], test: list[str], tmp: Path) -> None:
    from ebus_env.twin import Twin, open_store
    from ebus_env.twin.forecast import predict_bus
    from ebus_env.twin.ingest import from_log_file
    from ebus_env.twin.jobs import Jobs, JobSettings
    from ebus_env.twin.schedule import read_block
    from ebus_env.twin.tokens import create

    settings = JobSettings(diagnose=False)
    rows, timing = [], {"point": [], "band": [], "window": [], "cross": []}
    for bus in buses:
        store = open_store(tmp / f"{bus}.sqlite")
        create(store, fleet="acc", bus=bus, reserve_soc_pct=30.0)
        twin = Twin(store)
        jobs = Jobs(twin, settings)
        t0 = time.perf_counter()
        replay_days(twin, jobs, bus, train)
        timing["cross"].append(time.perf_counter() - t0)
        for day in test:
            # the twin sees the first half of the day, with its window re-fits
            replay_days(twin, jobs, bus, [day], half_last=True)
            truth = from_log_file(FLEET / bus / f"{day}.csv.gz")
            block = read_block(json.loads((FLEET / bus / f"{day}.block.json").read_text()))
            for band in (False, True):
                t1 = time.perf_counter()
                fc = predict_bus(twin, bus, band=band, settings=settings)
                timing["band" if band else "point"].append(time.perf_counter() - t1)
            t_now = fc.t
            seen = truth[truth["t"] <= t_now]
            km = np.sum(seen["speed_kmh"].to_numpy()[1:] * np.diff(seen["t"].to_numpy())) / 3600
            ahead = truth[truth["t"] > t_now]
            km_left = np.sum(ahead["speed_kmh"].to_numpy()[1:]
                             * np.diff(ahead["t"].to_numpy())) / 3600
            used_per_km = (seen["soc_pct"].iloc[0] - seen["soc_pct"].iloc[-1]) / km
            baseline = seen["soc_pct"].iloc[-1] - used_per_km * km_left
            end = float(truth[truth["t"] <= block.end_s]["soc_pct"].iloc[-1])
            low = float(truth[truth["t"] <= block.end_s]["soc_pct"].min())
            rows.append({"bus": bus, "day": day, "truth": end, "pred": fc.end_soc_pct,
                         "band": fc.end_band_pct, "base": baseline,
                         "alarm": fc.will_not_make_it, "below": low < 30.0,
                         "lead_min": None if not fc.will_not_make_it else
                         (truth[truth["soc_pct"] < 30.0]["t"].iloc[0] - t_now) / 60.0
                         if low < 30.0 else None})
            print(f"    {bus} {day}: truth {end:.1f} %, twin {fc.end_soc_pct:.1f} % "
                  f"({fc.end_band_pct[0]:.1f}-{fc.end_band_pct[1]:.1f}), energy/km "
                  f"{baseline:.1f} %{'  ALARM' if fc.will_not_make_it else ''}", flush=True)
        store.engine.dispose()
    err = np.array([abs(r["pred"] - r["truth"]) for r in rows])
    base = np.array([abs(r["base"] - r["truth"]) for r in rows])
    cover = np.mean([r["band"][0] <= r["truth"] <= r["band"][1] for r in rows])
    made_it = [r for r in rows if not r["below"]]
    false = sum(r["alarm"] for r in made_it)
    leads = [r["lead_min"] for r in rows if r["lead_min"] is not None]
    row(f"accuracy: {len(rows)} unseen days ({len(buses)} buses), from the first half",
        "", "block-end SoC")
    row("  median |error|, twin / energy-per-km baseline",
        f"{np.median(err):.2f} / {np.median(base):.2f}", "SoC points")
    row("  the twin's error below the baseline's (medians)",
        f"{100 * (1 - np.median(err) / np.median(base)):.0f} %")
    row("  90 % band covers the truth", f"{100 * cover:.0f} %", f"{len(rows)} days")
    row("  'will not make it' on blocks that made it", f"{false} of {len(made_it)}")
    row("  alarms on blocks that went below the reserve, median lead",
        f"{len(leads)} of {len(rows) - len(made_it)}",
        f"{np.median(leads):.0f} min" if leads else "")
    row("prediction latency, point / with band (median)",
        f"{1e3 * np.median(timing['point']):.0f} / {1e3 * np.median(timing['band']):.0f} ms")
    per_day = np.median(timing["cross"]) / len(train)
    row("replay with jobs (window re-fits + cross-day fit), per bus-day",
        f"{per_day:.0f} s", "1 core; a bus-day needs one such")
    row("  bus-days of fits 2 cores hold per 24 h (ingest and jobs)",
        f"{2 * 86400 / per_day:.0f}")


def memory_per_bus(tmp: Path) -> None:
    """Live state per bus: the Twin's caches after a prediction of each of 5 buses."""
    from ebus_env.twin import Twin, open_store
    from ebus_env.twin.tokens import create

    store = open_store(tmp / "mem.sqlite")
    twin = Twin(store)
    buses = sorted(p.name for p in FLEET.glob("bus-*"))
    for bus in buses:
        create(store, fleet="m", bus=bus)
        replay_days(twin, None, bus, ["2025-05-05", "2025-05-06"], half_last=True)
    twin.predict(buses[0])
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    for bus in buses:
        twin.predict(bus)
    after = tracemalloc.get_traced_memory()[0]
    tracemalloc.stop()
    row("live memory per bus (trip traces and ids the twin keeps)",
        f"{(after - before) / len(buses) / 1e6:.2f} MB", "not growing with days stored: "
        "the newest 8 trips of each direction")
    size = sum(f.stat().st_size for f in tmp.glob("mem.sqlite*"))
    row("storage per bus-day (SQLite, raw 1 Hz samples)",
        f"{size / (1.5 * len(buses)) / 1e6:.1f} MB", "1-min aggregates: ~0.1 MB")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--smoke", action="store_true")
    parser.add_argument("--buses", type=int, default=1000)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--postgres", action="store_true", help="also on a PostgreSQL")
    parser.add_argument("--skip", default="", help="comma list: ingest,accuracy,memory")
    args = parser.parse_args(argv)
    skip = set(filter(None, args.skip.split(",")))
    buses, seconds = (50, 10.0) if args.smoke else (args.buses, args.seconds)
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        print("ebus twin benchmark" + (" (smoke)" if args.smoke else ""))
        if "ingest" not in skip:
            ingest_load(str(tmp / "load.sqlite"), buses, seconds, "SQLite")
            if args.postgres:
                from tests.twin_services import postgres

                with postgres(tmp) as url:
                    ingest_load(url, buses, seconds, "PostgreSQL")
        if "accuracy" not in skip:
            fleet = sorted(p.name for p in FLEET.glob("bus-*"))
            if args.smoke:
                accuracy(fleet[:1], ["2025-05-05"], ["2025-05-06"], tmp)
            else:
                accuracy(fleet, ["2025-05-05", "2025-05-06"], ["2025-05-07", "2025-05-08"],
                         tmp)
        if "memory" not in skip:
            memory_per_bus(tmp)


if __name__ == "__main__":
    main()
