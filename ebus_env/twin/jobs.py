"""The twin's jobs: after new data, each bus's service days are tracked, its model re-fitted
(:mod:`ebus_env.twin.bus_refit`), a finished day diagnosed (:mod:`ebus_env.twin.closed_days`)
and its block's SoC predicted (:mod:`ebus_env.twin.forecast`).

They run in a thread of the twin's process, or on Ray (``--ray [--address]``): the heavy
pieces (a re-fit, a cross-day fit with the day's diagnosis) are then Ray tasks, each reading
the samples it needs from the store itself (PostgreSQL, when the cluster spans machines), so
nothing large travels. The jobs are idempotent: what a job wrote (a fit, a diagnosis) is
keyed by bus and day or window, and a bus is looked at again whenever it gets data, so a job
lost with a crashed process is done again by the next.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass

log = logging.getLogger("ebus_env.twin")


@dataclass
class JobSettings:
    bus_config: str = "12m"
    dt_s: float = 0.2
    """The models' time step [s]: 1 Hz data hold nothing finer than 0.2 s steps need."""
    day_end_idle_min: float = 30.0
    """A service day is finished when the bus has stood this long (layovers are shorter)."""
    refit_every_min: float = 60.0
    """New data [min of the bus's time] that start a windowed re-fit."""
    predict_every_s: float = 300.0
    """Data time [s] between two predictions of a bus while it drives."""
    cross_days: int = 3
    """Days the cross-day fit of the bus-to-bus parameters spans."""
    keep_raw_days: float = 30.0
    diagnose: bool = True


class Jobs:
    """Runs the jobs of buses that got data, one bus at a time per worker thread. On Ray the
    heavy parts are Ray tasks and there are as many workers as the cluster has CPUs (each
    waits on its task), unless ``workers`` asks for more."""

    def __init__(self, twin, settings: JobSettings | None = None, ray: bool = False,
                 address: str | None = None, workers: int = 1):
        self.twin, self.settings = twin, settings or JobSettings()
        self.use_ray, self.address, self.workers = ray, address, workers
        self._queue: queue.Queue = queue.Queue()
        self._pending: set[str] = set()  # buses queued
        self._running: set[str] = set()  # buses a worker is on (one worker a bus)
        self._again: set[str] = set()  # buses that got data while a worker was on them
        self._lock = threading.Lock()
        self._threads: list[threading.Thread] = []
        self._stop = threading.Event()
        self.errors: list[str] = []
        self.done = 0
        self.remote_tasks = 0  # heavy jobs run as Ray tasks

    def notify(self, bus: str, late: bool = False) -> None:
        """``bus`` has new data: look at it once the jobs before it are done."""
        with self._lock:
            if bus in self._pending:
                return
            self._pending.add(bus)
        self._queue.put(bus)

    def start(self) -> None:
        if self.use_ray:
            import ray

            from ebus_env.twin.ray_jobs import connect

            connect(self.address)
            self.workers = max(self.workers, int(ray.cluster_resources().get("CPU", 1)))
        for i in range(self.workers):
            th = threading.Thread(target=self._loop, name=f"twin-jobs-{i}", daemon=True)
            th.start()
            self._threads.append(th)

    def stop(self) -> None:
        self._stop.set()
        for _ in self._threads:
            self._queue.put(None)
        for th in self._threads:
            th.join(timeout=30)

    def status(self) -> dict:
        """What the jobs are doing: buses waiting, jobs done, failures, the Ray cluster."""
        with self._lock:
            busy = len(self._pending | self._running | self._again)
        out = {"waiting": busy, "done": self.done, "failed": len(self.errors),
               "last_failure": self.errors[-1] if self.errors else None,
               "workers": self.workers, "ray": None}
        if self.use_ray:
            import ray

            out["ray"] = {"nodes": sum(n["Alive"] for n in ray.nodes()),
                          "cpus": ray.cluster_resources().get("CPU", 0.0),
                          "tasks": self.remote_tasks}
        return out

    def idle(self) -> bool:
        with self._lock:
            return not (self._pending or self._running or self._again)

    def wait(self, timeout_s: float = 600.0) -> None:
        """Block until every bus notified so far has been looked at (tests, benchmarks)."""
        t0 = time.monotonic()
        while not self.idle():
            if time.monotonic() - t0 > timeout_s:
                raise TimeoutError("the twin's jobs did not finish")
            time.sleep(0.05)

    def _loop(self) -> None:
        while not self._stop.is_set():
            bus = self._queue.get()
            if bus is None:
                return
            with self._lock:
                self._pending.discard(bus)
                if bus in self._running:  # another worker is on it: once more after it
                    self._again.add(bus)
                    continue
                self._running.add(bus)
            try:
                self.run_bus(bus)
            except Exception as exc:  # a job's failure must not stop the others
                log.exception("twin job of %s failed", bus)
                self.errors.append(f"{bus}: {type(exc).__name__}: {exc}")
            with self._lock:
                self.done += 1
                self._running.discard(bus)
                again = bus in self._again
                self._again.discard(bus)
            if again:
                self.notify(bus)

    def run_bus(self, bus: str) -> None:
        """Everything due for ``bus``: close finished days (and fit and diagnose them), re-fit
        its window, predict its block."""
        from ebus_env.twin import bus_refit, closed_days, forecast

        closed = closed_days.close_days(self.twin, bus, self.settings)
        for day in closed:
            self._day_job(bus, day)
        bus_refit.maybe_refit(self.twin, bus, self.settings, runner=self.remote)
        forecast.maybe_predict(self.twin, bus, self.settings)

    def _day_job(self, bus: str, day: str) -> None:
        from ebus_env.twin import bus_refit, closed_days

        bus_refit.cross_day_fit(self.twin, bus, day, self.settings, runner=self.remote)
        if self.settings.diagnose:
            closed_days.diagnose_day(self.twin, bus, day, self.settings, runner=self.remote)

    def remote(self, fn, *args):
        """``fn(*args)`` here, or as a Ray task (its result returned either way)."""
        if not self.use_ray:
            return fn(*args)
        from ebus_env.twin.ray_jobs import run_remote

        result = run_remote(fn, *args)
        self.remote_tasks += 1
        return result
