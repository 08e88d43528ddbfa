"""Retention: raw 1 Hz samples are kept ``keep_raw_days``, then reduced to 1-min aggregates
(mean and max speed, distance, last and lowest SoC, mean ambient, charging and door-open
shares, highest charger power), in one transaction per bus and run: a crash leaves either
the raw samples or their aggregates, never neither."""

from __future__ import annotations

import time

import numpy as np
import pandas as pd
import sqlalchemy as sa

from ebus_env.twin.store import Store, buses, minutes, samples


def aggregate(frame: pd.DataFrame) -> pd.DataFrame:
    """1-min rows of samples (``t``, ``speed_kmh``, ``soc_pct``, ...): the distance is
    the integral of speed over each sample's time to the next (at most 10 s) [km]."""
    t = frame["t"].to_numpy(float)
    step = np.minimum(np.diff(t, append=t[-1]), 10.0)
    work = frame.assign(m=np.floor(t / 60.0) * 60.0,
                        km=frame["speed_kmh"].to_numpy(float) * step / 3600.0)
    g = work.groupby("m", sort=True)
    out = pd.DataFrame({
        "t": g.size().index.to_numpy(float), "n": g.size().to_numpy(),
        "speed_kmh": g["speed_kmh"].mean().to_numpy(),
        "speed_kmh_max": g["speed_kmh"].max().to_numpy(),
        "distance_km": g["km"].sum().to_numpy()})
    for col, how, name in (("soc_pct", "last", "soc_pct"), ("soc_pct", "min", "soc_pct_min"),
                           ("ambient_degc", "mean", "ambient_degc"),
                           ("charging", "mean", "charging"), ("charger_kw", "max", "charger_kw"),
                           ("door_open", "mean", "door_open")):
        out[name] = g[col].agg(how).to_numpy() if col in work else np.nan
    return out


def reduce_old(store: Store, keep_raw_days: float, now: float | None = None) -> dict:
    """Aggregate and delete every bus's raw samples older than ``keep_raw_days`` (whole
    minutes only)."""
    cutoff = (now if now is not None else time.time()) - 86400.0 * keep_raw_days
    cutoff = np.floor(cutoff / 60.0) * 60.0
    done = {"samples": 0, "minutes": 0}
    with store.engine.connect() as conn:
        ids = list(conn.execute(sa.select(buses.c.id)).scalars())
    cols = ["t", "speed_kmh", "soc_pct", "ambient_degc", "charging", "charger_kw", "door_open"]
    for bus_id in ids:
        with store.engine.begin() as conn:
            rows = conn.execute(sa.select(*(samples.c[c] for c in cols)).where(
                samples.c.bus_id == bus_id, samples.c.t < cutoff).order_by(samples.c.t)).all()
            if not rows:
                continue
            agg = aggregate(pd.DataFrame(rows, columns=cols).astype(float))
            records = [{k: (None if pd.isna(v) else float(v)) for k, v in r.items()}
                       for r in agg.to_dict("records")]
            for r in records:
                r["bus_id"], r["n"] = bus_id, int(r["n"])
            conn.execute(store.insert(minutes).on_conflict_do_nothing(), records)
            conn.execute(samples.delete().where(samples.c.bus_id == bus_id,
                                                samples.c.t < cutoff))
            done["samples"] += len(rows)
            done["minutes"] += len(records)
    return done
