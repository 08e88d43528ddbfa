"""The twin of a fleet: :class:`Twin` takes samples in, keeps them durable (its one writer
commits the batches of all buses in groups, :mod:`ebus_env.twin.group_commit`), and (through
its :class:`~ebus_env.twin.jobs.Jobs`) re-fits each bus's model, diagnoses finished service
days and predicts the SoC along each bus's block.
"""

from __future__ import annotations

import json
import time
from concurrent.futures import Future

import numpy as np
import pandas as pd
import sqlalchemy as sa

from ebus_env.errors import ConfigError
from ebus_env.twin import ingest as payload
from ebus_env.twin.group_commit import GroupWriter, Receipt
from ebus_env.twin.store import (
    SAMPLE_COLUMNS,
    Store,
    alarms,
    buses,
    diagnoses,
    fits,
    predictions,
    samples,
)

STALE_AFTER_S = 120.0
"""A bus that has sent nothing for this long (wall clock) is shown as stale: twelve 10-s
batches missed."""


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
        # forecast's ambient of the day before per bus: 1-min means of a span read once
        self.ambient_cache: dict[str, tuple] = {}
        # each bus's normal day as the diagnosis measured it (closed_days; a few kB a bus)
        self.reference_cache: dict[str, tuple] = {}
        self.writer = GroupWriter(store, clock, self._committed)

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
        Returns its :class:`~ebus_env.twin.group_commit.Receipt` once the batch is durable."""
        return self.submit(bus, frame, batch_id).result()

    def submit(self, bus: str, frame: pd.DataFrame | payload.Batch,
               batch_id: str | None = None) -> Future:
        """:meth:`ingest` without waiting: a future of the receipt, resolved once the batch
        is durable (the server and the MQTT subscriber answer from it)."""
        if not isinstance(frame, payload.Batch):
            frame = payload.batch(payload.from_frame(frame, self.clock()), batch_id)
        return self.writer.submit(bus, self.bus_id(bus), frame)

    def _committed(self, receipts: list[Receipt]) -> None:
        if self.jobs is not None:
            for r in receipts:
                if r.stored:
                    self.jobs.notify(r.bus, late=r.arrival == "late")

    def close(self) -> None:
        """Write what is queued and stop the writer."""
        self.writer.close()

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

    def predict(self, bus: str, schedule: dict | None = None, band: bool = True, **options):
        """The SoC along ``bus``'s block from its newest sample on: at each planned charger
        and at the block's end, with a band (:mod:`ebus_env.twin.forecast`). ``schedule``:
        a block (:mod:`ebus_env.twin.schedule`); by default the one stored for the day.
        ``options``: :func:`~ebus_env.twin.forecast.predict_bus`'s (``at_t``,
        ``model_error``, ``rate_weight``)."""
        from ebus_env.twin.forecast import predict_bus

        return predict_bus(self, bus, schedule, band=band, **options)

    def alarms(self, bus: str) -> list[dict]:
        return self.bus(bus)["alarms"]


