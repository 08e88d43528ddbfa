"""``ebus twin replay``: stands in for a bus's logger by streaming logs to a twin.

The samples go in batches of ``batch_s`` seconds of log time, one batch every
``batch_s / speed`` seconds of wall time (``--speed 60x``: an hour of log in a minute); the
night between two logs is skipped. A batch is sent until the twin acknowledges it (a logger's
way: a batch id of its own, so a batch re-sent after a lost answer is a duplicate, stored
once). A log's block (``<log>.block.json`` beside it, for the day its name gives) is sent before
its samples.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from ebus_env.errors import ConfigError

RETRY_S = (0.2, 0.5, 1.0, 2.0, 5.0)


def parse_speed(text: str | float) -> float:
    """``60x``, ``60`` or ``1x`` as a factor of real time."""
    value = str(text).strip().lower().removesuffix("x")
    try:
        speed = float(value)
    except ValueError:
        raise ConfigError(f"--speed {text}: give a factor of real time, e.g. 60x") from None
    if not 0 < speed <= 100_000:
        raise ConfigError(f"--speed {text}: must be in (0, 100000]x")
    return speed


def block_file(log: Path) -> Path:
    name = log.name
    for suffix in (".csv.gz", ".csv", ".parquet"):
        if name.endswith(suffix):
            name = name[: -len(suffix)]
    return log.with_name(name + ".block.json")


def block_day(block: Path, t0: float) -> str:
    """The day a block file is for: its name (``2025-05-05.block.json``), else the UTC date
    of its log's first sample."""
    name = block.name.removesuffix(".block.json")
    try:
        return str(pd.Timestamp(name).date()) if len(name) == 10 else \
            str(pd.Timestamp(t0, unit="s").date())
    except ValueError:
        return str(pd.Timestamp(t0, unit="s").date())


def log_samples(log: Path) -> pd.DataFrame:
    """A logger file's samples with UTC epoch times, read by the project's log reader."""
    from ebus_env.twin.ingest import from_log_file

    return from_log_file(log)


def batches_of(frame: pd.DataFrame, batch_s: float) -> list[pd.DataFrame]:
    t = frame["t"].to_numpy(float)
    edges = np.flatnonzero(np.diff(np.floor((t - t[0]) / batch_s)) > 0) + 1
    return [frame.iloc[a:b] for a, b in zip(np.r_[0, edges], np.r_[edges, len(t)],
                                            strict=True)]


def records(part: pd.DataFrame) -> list[dict]:
    out = []
    for rec in part.to_dict("records"):
        out.append({k: v for k, v in rec.items() if not (isinstance(v, float) and np.isnan(v))})
    return out


class Sender:
    """Posts batches to one bus's endpoint, retrying until each is acknowledged."""

    def __init__(self, url: str, bus: str, token: str, timeout_s: float = 30.0,
                 give_up_s: float = 600.0):
        import httpx

        self.client = httpx.Client(base_url=url.rstrip("/"), timeout=timeout_s,
                                   headers={"Authorization": f"Bearer {token}"})
        self.bus, self.give_up_s = bus, give_up_s
        self.retries = 0  # answers lost (the twin away, a 5xx): each batch re-sent

    def _send(self, method: str, path: str, **kwargs) -> dict:
        import httpx

        t0 = time.monotonic()
        attempt = 0
        while True:
            try:
                answer = self.client.request(method, path, **kwargs)
            except httpx.TransportError:
                answer = None
            if answer is not None and answer.status_code < 500:
                if answer.status_code >= 400:
                    raise ConfigError(f"the twin refused {path}: {answer.status_code} "
                                      f"{answer.text[:500]}")
                return answer.json()
            if time.monotonic() - t0 > self.give_up_s:
                raise ConfigError(f"the twin at {self.client.base_url} did not answer for "
                                  f"{self.give_up_s:.0f} s")
            time.sleep(RETRY_S[min(attempt, len(RETRY_S) - 1)])
            attempt += 1
            self.retries += 1

    def batch(self, batch_id: str, part: pd.DataFrame) -> dict:
        return self._send("POST", f"/v1/buses/{self.bus}/samples",
                          json={"batch_id": batch_id, "samples": records(part)})

    def schedule(self, day: str, block: dict) -> dict:
        return self._send("PUT", f"/v1/buses/{self.bus}/schedules/{day}",
                          content=json.dumps(block))

    def close(self) -> None:
        self.client.close()


def replay(logs: list[Path], bus: str, url: str, token: str, speed: float = 60.0,
           batch_s: float = 10.0, on_ack: Callable[[str, dict], None] | None = None,
           sleep=time.sleep, clock=time.monotonic, limit_s: float | None = None) -> dict:
    """Stream ``logs`` (in the order given) as ``bus``'s logger would; returns counts.
    ``limit_s``: stop after this much wall time."""
    sender = Sender(url, bus, token)
    counts = {"batches": 0, "samples": 0, "duplicates": 0, "schedules": 0}
    start = None
    sent_log_s = 0.0
    try:
        for log in map(Path, logs):
            frame = log_samples(log)
            t0 = float(frame["t"].iloc[0])
            blk = block_file(log)
            if blk.exists():
                sender.schedule(block_day(blk, t0), json.loads(blk.read_text()))
                counts["schedules"] += 1
            if start is None:  # the clock starts with the first sample, not the file's read
                start = clock()
            for part in batches_of(frame, batch_s):
                due = start + (sent_log_s + float(part["t"].iloc[-1]) - t0) / speed
                wait = due - clock()
                if wait > 0:
                    sleep(wait)
                if limit_s is not None and clock() - start > limit_s:
                    return counts
                batch_id = f"{bus}:{float(part['t'].iloc[0]):.3f}"
                answer = sender.batch(batch_id, part)
                counts["batches"] += 1
                counts["samples"] += answer.get("stored", 0)
                counts["duplicates"] += answer.get("status") == "duplicate"
                if on_ack:
                    on_ack(batch_id, answer)
            sent_log_s += float(frame["t"].iloc[-1]) - t0
    finally:
        sender.close()
    return counts
