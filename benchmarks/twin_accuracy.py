"""The live twin's accuracy on days it has not seen, for :mod:`benchmarks.bench_twin`.

Each bus's days go through the twin's fits as the running twin makes them: its first
:data:`TEST_FROM` days whole (the cross-day fit after each), then each later day's first half
(the block's start to its midpoint), a window re-fit there, and the day's second half (the
cross-day fit after it). At each midpoint the twin predicts the SoC at the block's end; the
log says what it was. Beside it, a plain energy-per-km baseline: the SoC the bus used per km
so far in the block times the km it drove in the rest of it (the log's km: the baseline is
given the true distance).

The "will not make it" alarm is scanned along every predicted block: the twin predicts every
:data:`SCAN_S` of data time from an hour after the block's start on, with the fits it had at
that time; the first prediction whose band top lies below the 30 % reserve is the alarm. On a
block whose log goes below the reserve, its lead is the time from the alarm to that moment;
on a block that stays above, it is a false alarm.

The band's one constant (:data:`ebus_env.twin.forecast.MODEL_ERROR`) is set on some buses
(the smallest value whose 90 % band covers the log on 90 % of their blocks) and the figures
are reported on the others (DESIGN.md section 9).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pandas as pd

TEST_FROM = 2
SCAN_S = 1800.0
RESERVE_PCT = 30.0


def bus_days(fleet: Path, bus: str) -> list[str]:
    return sorted(p.name[:10] for p in (fleet / bus).glob("*.csv.gz"))


def replay_bus(fleet: Path, bus: str, out: Path, days: int | None = None,
               test_from: int = TEST_FROM) -> dict:
    """The bus's first ``days`` days (all by default) through the twin's fits into
    ``out/<bus>.sqlite`` (see the module docstring; the days from ``test_from`` on are
    predicted); returns their midpoints and what each fit cost [s of wall time]."""
    from ebus_env.twin import Twin, bus_refit, closed_days, open_store
    from ebus_env.twin.ingest import from_log_file
    from ebus_env.twin.jobs import JobSettings
    from ebus_env.twin.schedule import read_block
    from ebus_env.twin.tokens import create

    done = out / f"{bus}.json"
    if done.exists():
        return json.loads(done.read_text())
    for f in out.glob(f"{bus}.sqlite*"):
        f.unlink()
    store = open_store(out / f"{bus}.sqlite")
    create(store, fleet="bench", bus=bus, reserve_soc_pct=RESERVE_PCT)
    twin = Twin(store)
    settings = JobSettings(refit_every_min=1.0)  # a window re-fit wherever one is asked
    info: dict = {"bus": bus, "halves": {}, "window_s": [], "cross_day_s": [],
                  "samples": 0}
    names = bus_days(fleet, bus)[:days]
    info["days"] = len(names)
    for k, day in enumerate(names):
        data = json.loads((fleet / bus / f"{day}.block.json").read_text())
        store.put_schedule(bus, day, data)
        block = read_block(data, day)
        frame = from_log_file(fleet / bus / f"{day}.csv.gz")
        info["samples"] += len(frame)
        if k >= test_from:
            t_half = block.start_s + 0.5 * (block.end_s - block.start_s)
            first = frame[frame["t"] <= t_half]
            twin.ingest(bus, first)
            t0 = time.perf_counter()
            bus_refit.maybe_refit(twin, bus, settings)
            info["window_s"].append(time.perf_counter() - t0)
            info["halves"][day] = float(first["t"].iloc[-1])
            frame = frame[frame["t"] > t_half]
        twin.ingest(bus, frame)
        if k == len(names) - 1:
            break  # no prediction needs the last day's fit
        for closed in closed_days.close_days(twin, bus, settings):
            t0 = time.perf_counter()
            bus_refit.cross_day_fit(twin, bus, closed, settings)
            info["cross_day_s"].append(time.perf_counter() - t0)
    twin.close()
    store.engine.dispose()
    done.write_text(json.dumps(info))
    return info


def _km(frame: pd.DataFrame) -> float:
    from ebus_env.twin.forecast import driven_km

    return driven_km(frame, max_step_s=np.inf)


def predict_bus_days(fleet: Path, out: Path, bus: str, model_error: float,
                     scan: bool = True, rate_weight: float = 0.0) -> list[dict]:
    """Each predicted block of ``bus``: the twin's prediction from the midpoint (and its two
    ingredients, the model's alone and the bus's rate's), the baseline's, the log's, and
    (``scan``) the reserve alarm along the block."""
    from ebus_env.twin import Twin, open_store
    from ebus_env.twin.forecast import predict_bus
    from ebus_env.twin.ingest import from_log_file
    from ebus_env.twin.schedule import read_block

    info = json.loads((out / f"{bus}.json").read_text())
    store = open_store(out / f"{bus}.sqlite", migrate=False)
    twin = Twin(store)
    rows = []
    for day, t_half in info["halves"].items():
        log = from_log_file(fleet / bus / f"{day}.csv.gz")
        block = read_block(json.loads((fleet / bus / f"{day}.block.json").read_text()), day)
        inside = log[(log["t"] >= block.start_s) & (log["t"] <= block.end_s)]
        seen, ahead = inside[inside["t"] <= t_half], inside[inside["t"] > t_half]
        # untimed first: a live twin predicts a bus every 15 min of data with its model
        # compiled and its trips read (kept until another trip ends)
        predict_bus(twin, bus, block, at_t=t_half, band=False)
        t0 = time.perf_counter()
        predict_bus(twin, bus, block, at_t=t_half, band=False)  # timed: the point alone
        t1 = time.perf_counter()
        fc = predict_bus(twin, bus, block, at_t=t_half, model_error=model_error,
                         rate_weight=rate_weight)
        t2 = time.perf_counter()
        soc = seen["soc_pct"].to_numpy(float)
        per_km = (soc[0] - soc[-1]) / max(_km(seen), 1e-6)
        below = inside["t"][inside["soc_pct"] < RESERVE_PCT]
        row = {"bus": bus, "day": day, "chargers": bool(block.charger_stops),
               "soc_now": fc.soc_now_pct, "truth": float(inside["soc_pct"].iloc[-1]),
               "twin": fc.end_soc_pct, "low": fc.end_band_pct[0], "high": fc.end_band_pct[1],
               "p5": fc.band_parts["members_pct"][0], "p95": fc.band_parts["members_pct"][1],
               "moved": fc.band_parts["moved_pct"],
               "model_end": fc.model_end_soc_pct, "rate_end": fc.rate_end_soc_pct,
               "baseline": float(soc[-1] - per_km * _km(ahead)),
               "crossed_t": float(below.iloc[0]) if len(below) else None,
               "point_s": t1 - t0, "band_s": t2 - t1}
        if scan:
            row.update(scan_alarm(twin, bus, block, model_error, rate_weight))
        rows.append(row)
    twin.close()
    store.engine.dispose()
    return rows


def scan_alarm(twin, bus: str, block, model_error: float, rate_weight: float) -> dict:
    """The first prediction along ``block`` (every :data:`SCAN_S` from an hour after its
    start) that says the bus will run below its reserve, made with a fitted model."""
    from ebus_env.twin.forecast import predict_bus

    t = block.start_s + 3600.0
    while t < block.end_s - 600.0:
        samples = twin.samples(bus, t - 60.0, t, ("soc_pct",))
        if len(samples):
            fc = predict_bus(twin, bus, block, at_t=float(samples["t"].iloc[-1]),
                             model_error=model_error, rate_weight=rate_weight)
            if fc.will_not_make_it and fc.fitted:
                return {"alarm_t": fc.t, "alarm_says_t": fc.below_reserve_t}
        t += SCAN_S
    return {"alarm_t": None, "alarm_says_t": None}


def set_rate_weight(rows: list[dict]) -> float:
    """The least-squares weight (0 to 1, on a 0.05 grid) of the bus's rate against the model
    over ``rows`` predicted with the model alone: ``sum e_m (e_m - e_r) / sum (e_m - e_r)^2``
    (e: each one's error at the block's end; Bates and Granger's combination)."""
    both = [r for r in rows if r["rate_end"] is not None]
    if not both:
        return 0.0
    e_m = np.array([r["model_end"] - r["truth"] for r in both])
    e_r = np.array([r["rate_end"] - r["truth"] for r in both])
    denom = float(np.sum((e_m - e_r) ** 2))
    w = float(np.sum(e_m * (e_m - e_r))) / denom if denom > 0 else 0.0
    return float(np.clip(np.round(w / 0.05) * 0.05, 0.0, 1.0))


def band(rows: list[dict], model_error: float) -> tuple[np.ndarray, np.ndarray]:
    """The 90 % band at the block's end that ``model_error`` gives (as the forecast builds
    it from its members and the SoC still moved)."""
    from ebus_env.twin.forecast import Z90

    p5 = np.array([r["p5"] for r in rows])
    p95 = np.array([r["p95"] for r in rows])
    spread = Z90 * model_error * np.array([r["moved"] for r in rows])
    return p5 - spread, p95 + spread


def coverage(rows: list[dict], model_error: float) -> float:
    low, high = band(rows, model_error)
    truth = np.array([r["truth"] for r in rows])
    return float(np.mean((low <= truth) & (truth <= high)))


def set_model_error(rows: list[dict], target: float = 0.90) -> float:
    """The smallest model error (on a 0.005 grid) whose band covers ``target`` of ``rows``."""
    for k in np.arange(0.0, 0.5001, 0.005):
        if coverage(rows, float(k)) >= target:
            return float(round(k, 3))
    return 0.5


def summary(rows: list[dict], model_error: float) -> dict:
    """The accuracy figures of ``rows`` (see bench_twin's table)."""
    twin = np.array([abs(r["twin"] - r["truth"]) for r in rows])
    base = np.array([abs(r["baseline"] - r["truth"]) for r in rows])
    made_it = [r for r in rows if r["crossed_t"] is None]
    fell = [r for r in rows if r["crossed_t"] is not None]
    leads = [(r["crossed_t"] - r["alarm_t"]) / 60.0 for r in fell
             if r.get("alarm_t") is not None and r["alarm_t"] < r["crossed_t"]]
    return {"blocks": len(rows), "buses": len({r["bus"] for r in rows}),
            "twin_mae": float(np.median(twin)), "baseline_mae": float(np.median(base)),
            "below_baseline": float(1.0 - np.median(twin) / np.median(base)),
            "coverage": coverage(rows, model_error),
            "made_it": len(made_it), "false_alarms": sum(r.get("alarm_t") is not None
                                                         for r in made_it),
            "fell": len(fell), "alarmed_in_time": len(leads),
            "lead_min": float(np.median(leads)) if leads else None,
            "chargers": {str(c): (float(np.median([abs(r["twin"] - r["truth"]) for r in g])),
                                  float(np.median([abs(r["baseline"] - r["truth"])
                                                   for r in g])), len(g))
                         for c in (True, False)
                         for g in [[r for r in rows if r["chargers"] == c]] if g}}
