"""Group commit: one writer per twin process stores the batches of every bus.

The batches that wait while a commit is on its way to disk are written together in the next
transaction and committed once; each batch's sender is answered only after that commit has
returned. The flush to disk that makes a commit durable (SQLite's WAL ``fsync`` under
``synchronous=FULL``, PostgreSQL's WAL flush) is then paid once per group, not once per
batch: the *group commit* of database engines (Gray and Reuter, *Transaction Processing:
Concepts and Techniques*, 1993, section 9.4.7; PostgreSQL's ``commit_delay`` does the same
inside its server). Under load the groups grow by themselves: the more batches come while a
commit is flushed, the more the next one takes.

What stays true, batch by batch:

* **acknowledged = durable**: a batch's :class:`~concurrent.futures.Future` resolves after
  the commit of its group returned;
* **whole or not at all**: a group is one transaction; a process killed before its commit
  leaves none of the group stored, and none of it was acknowledged;
* **stored once**: ``(bus, batch_id)`` is the batch table's primary key, samples are keyed
  by ``(bus, t)``; a batch sent twice within one group finds the first (same transaction);
* **one bad batch refuses only itself**: a group whose transaction fails is written again
  batch by batch, each in its own transaction;
* **no deadlock between processes** (PostgreSQL, several twins): a group writes its batches
  in the order of their bus ids (a bus's own batches keep their order), so the row locks of
  two groups are always taken in the same order.

What a batch was is said in its :class:`Receipt`:

* ``duplicate``: its ``(bus, batch_id)`` is stored already; nothing is stored again;
* ``out of order``: it starts before the newest sample stored for the bus; stored;
* ``late``: it starts within a service day that the twin has closed already; stored, and
  the day is diagnosed again with it;
* ``rows_already_stored``: samples at times the bus has a sample for already (from another
  batch); the first one stored is kept, and the receipt counts them.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field

import numpy as np
import sqlalchemy as sa

from ebus_env.twin.ingest import Batch
from ebus_env.twin.store import SAMPLE_COLUMNS, Store, batches, buses, samples, service_days

MAX_GROUP = 512
"""Most batches in one transaction: a 10-s round of 500 buses (the writer's queue holds the
rest for the next group)."""

log = logging.getLogger("ebus_env.twin")


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


@dataclass
class _Item:
    bus: str
    bus_id: int
    batch: Batch
    future: Future


class GroupWriter:
    """The one writer thread of a twin process (started on the first batch).

    Parameters
    ----------
    store
        The twin's :class:`~ebus_env.twin.store.Store`.
    clock
        Wall clock [s] (``received_at``, ``seen_at``).
    after_commit
        Called in the writer thread with each committed group's receipts (the twin's jobs
        are told which buses got data).
    """

    def __init__(self, store: Store, clock: Callable[[], float],
                 after_commit: Callable[[list[Receipt]], None] | None = None,
                 max_group: int = MAX_GROUP):
        self.store, self.clock, self.after_commit = store, clock, after_commit
        self.max_group = max_group
        self.sql = Statements(store)
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        self._start_lock = threading.Lock()
        self.groups = 0  # commits made (groups), and the batches they held
        self.batches = 0

    def submit(self, bus: str, bus_id: int, batch: Batch) -> Future:
        """Queue ``batch`` of ``bus``; its future gives the :class:`Receipt` once durable."""
        future: Future = Future()
        self._start()
        self._queue.put(_Item(bus, bus_id, batch, future))
        return future

    @property
    def queued(self) -> int:
        """Batches waiting for the writer to take them (not those of the group it writes)."""
        return self._queue.qsize()

    def _start(self) -> None:
        if self._thread is not None and self._thread.is_alive():
            return
        with self._start_lock:
            if self._thread is None or not self._thread.is_alive():
                self._thread = threading.Thread(target=self._loop, name="twin-writer",
                                                daemon=True)
                self._thread.start()

    def close(self, timeout_s: float = 30.0) -> None:
        """Write what is queued, then stop the thread."""
        if self._thread is not None and self._thread.is_alive():
            self._queue.put(None)
            self._thread.join(timeout=timeout_s)

    def _loop(self) -> None:
        stop = False
        while not stop:
            item = self._queue.get()
            if item is None:
                return
            group = [item]
            while len(group) < self.max_group:
                try:
                    more = self._queue.get_nowait()
                except queue.Empty:
                    break
                if more is None:
                    stop = True
                    break
                group.append(more)
            try:
                self._commit(group)
            except BaseException as exc:  # never leave a sender waiting for ever
                for it in group:
                    if not it.future.done():
                        it.future.set_exception(exc)
                log.exception("the twin's writer failed a group of %d batches", len(group))

    def _commit(self, group: list[_Item]) -> None:
        ordered = sorted(group, key=lambda it: it.bus_id)  # stable: a bus's batches in order
        now = self.clock()
        try:
            with self.store.engine.begin() as conn:
                receipts = write_group(self.sql, conn, ordered, now)
        except Exception as exc:
            if len(ordered) == 1:
                ordered[0].future.set_exception(exc)
                return
            # one batch may be the cause: each on its own, so the others are stored
            for it in ordered:
                self._commit([it])
            return
        self.groups += 1
        self.batches += len(ordered)
        if self.after_commit is not None:
            try:
                self.after_commit(receipts)
            except Exception:  # the jobs' queue must not undo an acknowledgement
                log.exception("after-commit hook failed")
        for it, receipt in zip(ordered, receipts, strict=True):
            it.future.set_result(receipt)


class Statements:
    """The writer's statements, built once per store (a statement built per batch costs more
    CPU than its execution). Each is executed once per group with the rows of all its
    batches: a group costs the same few round trips to the database whatever its size."""

    def __init__(self, store: Store):
        bp = sa.bindparam
        self.add_batches = (store.insert(batches).on_conflict_do_nothing()
                            .returning(batches.c.bus_id, batches.c.batch_id))
        closed_end = (sa.select(sa.func.max(service_days.c.t_end))
                      .where(service_days.c.bus_id == buses.c.id).scalar_subquery())
        # the buses' rows locked (PostgreSQL), in the order of their ids: the batches of a
        # bus from two processes go one after the other, and never in a cycle
        self.bus_state = (sa.select(buses.c.id, buses.c.last_t, closed_end)
                          .where(buses.c.id.in_(bp("ids", expanding=True)))
                          .order_by(buses.c.id).with_for_update(of=buses))
        self.add_samples = (store.insert(samples).on_conflict_do_nothing()
                            .returning(samples.c.bus_id, samples.c.batch_id))
        self.batch_outcome = (batches.update()
                              .where(batches.c.bus_id == bp("bus"),
                                     batches.c.batch_id == bp("batch"))
                              .values(n_new=bp("n_new"), arrival=bp("arrival")))
        self.newest = (buses.update().where(buses.c.id == bp("bus"))
                       .values(last_t=bp("last_t"), last_soc_pct=bp("soc"),
                               last_speed_kmh=bp("speed"), seen_at=bp("now")))
        self.seen = buses.update().where(buses.c.id == bp("bus")).values(seen_at=bp("now"))


def write_group(sql: Statements, conn, group: list[_Item], now: float) -> list[Receipt]:
    """Write a group of checked batches (in the order given) in the open transaction
    ``conn``: five statements, each with the rows of every batch. Returns their receipts,
    in the same order; two batches of one bus in one group are said as if they had come one
    after the other."""
    receipts = [Receipt(it.bus, it.batch.batch_id, it.batch.n_rows, 0, "stored", "in order")
                for it in group]
    new = {tuple(r) for r in conn.execute(sql.add_batches, [{
        "bus_id": it.bus_id, "batch_id": it.batch.batch_id, "received_at": now,
        "n_rows": it.batch.n_rows, "n_new": 0, "t_first": float(it.batch.columns["t"][0]),
        "t_last": float(it.batch.columns["t"][-1]), "arrival": "in order"} for it in group])}
    fresh = []
    for it, receipt in zip(group, receipts, strict=True):
        key = (it.bus_id, it.batch.batch_id)
        if key in new:
            new.discard(key)  # a second of the same in this group is a duplicate
            fresh.append((it, receipt))
        else:
            receipt.status = "duplicate"
            receipt.notes.append("this batch is stored already (same bus and batch id): "
                                 "nothing stored again")
    if not fresh:
        conn.execute(sql.seen, [{"bus": b, "now": now} for b in {it.bus_id for it in group}])
        return receipts
    state = {row.id: [row.last_t, row[2]] for row in conn.execute(
        sql.bus_state, {"ids": sorted({it.bus_id for it, _ in fresh})})}
    rows = []
    for it, receipt in fresh:
        t = it.batch.columns["t"]
        last_t, closed = state[it.bus_id]
        if closed is not None and t[0] <= closed:
            receipt.arrival = "late"
            receipt.notes.append("late: it falls in a service day the twin has closed; "
                                 "stored, and that day is diagnosed again")
        elif last_t is not None and t[0] <= last_t:
            receipt.arrival = "out of order"
            receipt.notes.append(f"out of order: it starts {last_t - t[0]:.0f} s before "
                                 "the newest sample stored; stored in its place by time")
        state[it.bus_id][0] = float(t[-1]) if last_t is None else max(last_t, float(t[-1]))
        rows += sample_rows(it.batch.columns, it.bus_id, it.batch.batch_id)
    # samples at times the bus has already are kept as first stored (ON CONFLICT DO NOTHING,
    # the rows in the group's order); RETURNING says which each batch added
    added: dict[tuple, int] = {}
    for bus_id, batch_id in conn.execute(sql.add_samples, rows):
        added[bus_id, batch_id] = added.get((bus_id, batch_id), 0) + 1
    newest: dict[int, dict] = {}
    for it, receipt in fresh:
        receipt.stored = added.get((it.bus_id, it.batch.batch_id), 0)
        receipt.rows_already_stored = receipt.rows - receipt.stored
        if receipt.rows_already_stored:
            receipt.notes.append(f"{receipt.rows_already_stored} sample(s) at times the bus "
                                 "has samples for already: the first stored is kept")
        c = it.batch.columns
        if receipt.stored and c["t"][-1] >= state[it.bus_id][0]:
            soc = c.get("soc_pct")
            newest[it.bus_id] = {
                "bus": it.bus_id, "last_t": float(c["t"][-1]), "now": now,
                "soc": None if soc is None or np.isnan(soc[-1]) else float(soc[-1]),
                "speed": float(c["speed_kmh"][-1])}
    conn.execute(sql.batch_outcome, [
        {"bus": it.bus_id, "batch": it.batch.batch_id, "n_new": r.stored,
         "arrival": r.arrival} for it, r in fresh])
    if newest:
        conn.execute(sql.newest, list(newest.values()))
    seen = [{"bus": b, "now": now} for b in {it.bus_id for it in group} - set(newest)]
    if seen:
        conn.execute(sql.seen, seen)
    return receipts


def sample_rows(columns, bus_id: int, batch_id: str) -> list[dict]:
    """Sample rows for one executemany insert: every sample column present (None where the
    sample has none, NaN included), so all rows share one statement."""
    present = [(c, columns[c].tolist()) for c in SAMPLE_COLUMNS if c in columns]
    blank = dict.fromkeys(SAMPLE_COLUMNS)
    rows = []
    for i, t in enumerate(columns["t"].tolist()):
        row = dict(blank, bus_id=bus_id, batch_id=batch_id, t=t)
        for col, values in present:
            x = values[i]
            row[col] = None if x != x else x  # NaN: no value
        rows.append(row)
    return rows
