"""The twin of a fleet: :class:`Twin` takes samples in, keeps them durable, and (through its
:class:`~ebus_env.twin.jobs.Jobs`) re-fits each bus's model, diagnoses finished service days
and predicts the SoC along each bus's block.

Each ingest is one transaction: the batch row, its new samples and the bus's newest sample
(for the fleet page) commit together or not at all. What a batch was is said in its receipt:

* ``duplicate``: its ``(bus, batch_id)`` is stored already; nothing is stored again;
* ``out of order``: it starts before the newest sample stored for the bus; stored;
* ``late``: it starts within a service day that the twin has closed already; stored, and
  the day is diagnosed again with it;
* ``rows_already_stored``: samples at times the bus has a sample for already (from another
  batch); the first one stored is kept, and the receipt counts them.
"""

from __future__ import annotations

import json
import threading
import time
from contextlib import nullcontext
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import sqlalchemy as sa

from ebus_env.errors import ConfigError
from ebus_env.twin import ingest as payload
from ebus_env.twin.store import (
    SAMPLE_COLUMNS,
    Store,
    alarms,
    batches,
    buses,
    diagnoses,
    fits,
    predictions,
    samples,
    service_days,
)

STALE_AFTER_S = 120.0
"""A bus that has sent nothing for this long (wall clock) is shown as stale: twelve 10-s
batches missed."""


@dataclass
class Receipt:
    """What the twin did with one batch (the HTTP answer's body)."""

    bus: str
    batch_id: str
    rows: int
    stored: int
    status: str  # "stored" or "duplicate"
    arrival: str  # "in order", "out of order", "late"
    rows_already_stored: int = 0
    notes: list[str] = field(default_factory=list)

    def to_json(self) -> dict:
        return dict(self.__dict__)


class Twin:
    """The live twin of the buses in ``store``.

    Parameters
    ----------
    store
        The :class:`~ebus_env.twin.store.Store` (``open_store("twin.sqlite")``).
    jobs
        Where re-fits, diagnoses and predictions run (:class:`~ebus_env.twin.jobs.Jobs`); None
        runs none (an ingest-only process).
    clock
        Wall clock [s] (injected in tests).
    stale_after_s
        No data for this long [s] shows a bus as stale.
    """

    def __init__(self, store: Store, jobs=None, clock=time.time,
                 stale_after_s: float = STALE_AFTER_S):
        self.store, self.jobs, self.clock = store, jobs, clock
        self.stale_after_s = stale_after_s
        self._ids: dict[str, int] = {}
        self.trip_cache: dict[str, tuple] = {}  # forecast's trips per bus (its live state)
        # one SQLite writer at a time in this process: waiting here beats busy retries
        self._write_lock = threading.Lock() if store.dialect == "sqlite" else nullcontext()

    # ------------------------------------------------------------------ data in
    def bus_id(self, bus: str) -> int:
        if bus not in self._ids:
            with self.store.engine.connect() as conn:
                found = self.store.bus_id(conn, bus)
            if found is None:
                raise ConfigError(f"unknown bus '{bus}': create it with its write token "
                                  f"(ebus twin token create --fleet NAME --bus {bus})")
            self._ids[bus] = found
        return self._ids[bus]

    def ingest(self, bus: str, frame: pd.DataFrame | payload.Batch,
               batch_id: str | None = None) -> Receipt:
        """Store a batch of ``bus``'s samples (a DataFrame with ``t`` or ``timestamp`` and
        canonical columns, checked here, or a checked :class:`~ebus_env.twin.ingest.Batch`).
        Returns when the batch is durable."""
        if not isinstance(frame, payload.Batch):
            frame = payload.batch(payload.from_frame(frame, self.clock()), batch_id)
        with self._write_lock:
            receipt = self._write(bus, frame)
        if self.jobs is not None and receipt.stored:
            self.jobs.notify(bus, late=receipt.arrival == "late")
        return receipt

    def _write(self, bus: str, batch: payload.Batch) -> Receipt:
        bus_id = self.bus_id(bus)
        frame = batch.frame
        t = frame["t"].to_numpy(float)
        now = self.clock()
        receipt = Receipt(bus, batch.batch_id, len(frame), 0, "stored", "in order")
        with self.store.engine.begin() as conn:
            new = conn.execute(self.store.insert(batches).values(
                bus_id=bus_id, batch_id=batch.batch_id, received_at=now, n_rows=len(frame),
                n_new=0, t_first=float(t[0]), t_last=float(t[-1]), arrival="in order")
                .on_conflict_do_nothing().returning(batches.c.batch_id)).first()
            if new is None:
                receipt.status = "duplicate"
                receipt.notes.append("this batch is stored already (same bus and batch id): "
                                     "nothing stored again")
                return receipt
            last_t = conn.execute(sa.select(buses.c.last_t).where(buses.c.id == bus_id)
                                  .with_for_update()).scalar()
            closed = conn.execute(sa.select(sa.func.max(service_days.c.t_end))
                                  .where(service_days.c.bus_id == bus_id)).scalar()
            if closed is not None and t[0] <= closed:
                receipt.arrival = "late"
                receipt.notes.append("late: it falls in a service day the twin has closed; "
                                     "stored, and that day is diagnosed again")
            elif last_t is not None and t[0] <= last_t:
                receipt.arrival = "out of order"
                receipt.notes.append(f"out of order: it starts {last_t - t[0]:.0f} s before "
                                     "the newest sample stored; stored in its place by time")
            have = set(conn.execute(sa.select(samples.c.t).where(
                samples.c.bus_id == bus_id, samples.c.t >= float(t[0]),
                samples.c.t <= float(t[-1]))).scalars())
            keep = ~np.isin(t, np.fromiter(have, float, len(have))) if have else \
                np.ones(len(t), bool)
            receipt.rows_already_stored = int((~keep).sum())
            if receipt.rows_already_stored:
                receipt.notes.append(f"{receipt.rows_already_stored} sample(s) at times the "
                                     "bus has samples for already: the first stored is kept")
            rows = _rows(frame[keep], bus_id, batch.batch_id)
            if rows:
                conn.execute(self.store.insert(samples).on_conflict_do_nothing(), rows)
            receipt.stored = len(rows)
            conn.execute(batches.update().where(batches.c.bus_id == bus_id,
                                                batches.c.batch_id == batch.batch_id)
                         .values(n_new=len(rows), arrival=receipt.arrival))
            if rows and (last_t is None or t[-1] > last_t):
                newest = frame.iloc[-1]
                conn.execute(buses.update().where(buses.c.id == bus_id).values(
                    last_t=float(t[-1]), last_soc_pct=_float(newest.get("soc_pct")),
                    last_speed_kmh=float(newest["speed_kmh"]), seen_at=now))
            else:
                conn.execute(buses.update().where(buses.c.id == bus_id).values(seen_at=now))
        return receipt

    # ------------------------------------------------------------------ data out
    def samples(self, bus: str, t_from: float = -np.inf, t_to: float = np.inf,
                columns=SAMPLE_COLUMNS) -> pd.DataFrame:
        """The stored 1 Hz samples of ``bus`` in ``[t_from, t_to]`` (``t`` UTC epoch s)."""
        cols = [samples.c.t, *(samples.c[c] for c in columns)]
        query = sa.select(*cols).where(samples.c.bus_id == self.bus_id(bus))
        if np.isfinite(t_from):
            query = query.where(samples.c.t >= float(t_from))
        if np.isfinite(t_to):
            query = query.where(samples.c.t <= float(t_to))
        with self.store.engine.connect() as conn:
            rows = list(map(tuple, conn.execute(query.order_by(samples.c.t))))
        return pd.DataFrame.from_records(rows, columns=["t", *columns], coerce_float=True)

    def fleet(self, fleet: str) -> list[dict]:
        """Each bus of ``fleet``: last seen, SoC now, stale or not, the latest prediction of
        its block's end, its open alarms."""
        now = self.clock()
        with self.store.engine.connect() as conn:
            rows = conn.execute(sa.select(buses).where(buses.c.fleet == fleet)
                                .order_by(buses.c.name)).all()
            out = []
            for r in rows:
                pred = conn.execute(sa.select(predictions).where(predictions.c.bus_id == r.id)
                                    .order_by(predictions.c.id.desc()).limit(1)).first()
                n_alarms = conn.execute(sa.select(sa.func.count()).select_from(alarms)
                                        .where(alarms.c.bus_id == r.id)).scalar()
                latest = conn.execute(sa.select(alarms.c.message).where(
                    alarms.c.bus_id == r.id).order_by(alarms.c.id.desc()).limit(1)).scalar()
                age = None if r.seen_at is None else now - r.seen_at
                out.append({
                    "bus": r.name, "last_t": r.last_t, "soc_pct": r.last_soc_pct,
                    "speed_kmh": r.last_speed_kmh, "seen_s_ago": age,
                    "state": "no data" if age is None else
                    "stale" if age > self.stale_after_s else "live",
                    "reserve_soc_pct": r.reserve_soc_pct,
                    "predicted_end_soc_pct": None if pred is None else pred.end_soc_pct,
                    "predicted_end_band_pct": None if pred is None else
                    [pred.end_low_pct, pred.end_high_pct],
                    "alarms": n_alarms, "latest_alarm": latest})
        return out

    def bus(self, bus: str, since_t: float | None = None) -> dict:
        """One bus's page: its measured SoC (1-min means), the twin's SoC ahead of it, the
        parameter history, the diagnosis timeline and its alarms."""
        bus_id = self.bus_id(bus)
        with self.store.engine.connect() as conn:
            head = conn.execute(sa.select(buses).where(buses.c.id == bus_id)).first()
            last = head.last_t or 0.0
            start = since_t if since_t is not None else last - 12 * 3600.0
            frame = self.samples(bus, start, last, ("soc_pct", "speed_kmh"))
            fit_rows = conn.execute(sa.select(fits).where(fits.c.bus_id == bus_id)
                                    .order_by(fits.c.id)).all()
            diag = conn.execute(sa.select(diagnoses).where(diagnoses.c.bus_id == bus_id)
                                .order_by(diagnoses.c.day)).all()
            alarm_rows = conn.execute(sa.select(alarms).where(alarms.c.bus_id == bus_id)
                                      .order_by(alarms.c.id)).all()
            pred = conn.execute(sa.select(predictions).where(predictions.c.bus_id == bus_id)
                                .order_by(predictions.c.id.desc()).limit(1)).first()
        minute = (frame.assign(m=(frame["t"] // 60) * 60).groupby("m")["soc_pct"].mean()
                  if len(frame) else pd.Series(dtype=float))
        return {
            "bus": bus, "fleet": head.fleet, "last_t": head.last_t,
            "soc_pct": head.last_soc_pct, "reserve_soc_pct": head.reserve_soc_pct,
            "measured": {"t": minute.index.tolist(),
                         "soc_pct": [None if np.isnan(x) else round(float(x), 2)
                                     for x in minute.to_numpy()]},
            "prediction": None if pred is None else {
                "data_t": pred.data_t, "end_soc_pct": pred.end_soc_pct,
                "band_pct": [pred.end_low_pct, pred.end_high_pct],
                **json.loads(pred.detail)},
            "fits": [{"kind": f.kind, "fitted_at": f.fitted_at, "t_from": f.t_from,
                      "t_to": f.t_to, "nrmse": f.nrmse, "values": json.loads(f.fit_values)}
                     for f in fit_rows],
            "diagnoses": [{"day": d.day, "verdict": d.verdict, "status": d.status,
                           "finding": d.finding, "why": d.why, "sentence": d.sentence}
                          for d in diag],
            "alarms": [{"kind": a.kind, "day": a.day, "data_t": a.data_t,
                        "raised_at": a.raised_at, "message": a.message, "lead_s": a.lead_s}
                       for a in alarm_rows]}

    def predict(self, bus: str, schedule: dict | None = None, band: bool = True):
        """The SoC along ``bus``'s block from its newest sample on: at each planned charger
        and at the block's end, with a band (:mod:`ebus_env.twin.forecast`). ``schedule``:
        a block (:mod:`ebus_env.twin.schedule`); by default the one stored for the day."""
        from ebus_env.twin.forecast import predict_bus

        return predict_bus(self, bus, schedule, band=band)

    def alarms(self, bus: str) -> list[dict]:
        return self.bus(bus)["alarms"]


def _float(x) -> float | None:
    return None if x is None or pd.isna(x) else float(x)


def _rows(frame: pd.DataFrame, bus_id: int, batch_id: str) -> list[dict]:
    """Sample rows for an executemany insert: every sample column present (None where the
    sample has none), so all rows share one statement."""
    out = {"bus_id": np.full(len(frame), bus_id), "batch_id": [batch_id] * len(frame),
           "t": frame["t"].to_numpy(float)}
    for col in SAMPLE_COLUMNS:
        out[col] = frame[col].to_numpy(float) if col in frame.columns else \
            np.full(len(frame), np.nan)
    table = pd.DataFrame(out).astype(object)
    table = table.where(pd.notna(table), None)
    return [{k: (v if v is None or isinstance(v, str) else
                 int(v) if k == "bus_id" else float(v)) for k, v in row.items()}
            for row in table.to_dict("records")]
