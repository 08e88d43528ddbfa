"""Encode a canonical log as the CAN frames a bus's logger would record: the inverse of
:mod:`ebus_env.io.can_log`, for the shipped example files and the tests' round trips.

Each DBC message whose signals the signal map maps onto columns of the log is sent at its
cycle time (the DBC's ``GenMsgCycleTime``, else 1 s), with a small fixed phase per message and
a seeded jitter of at most ``jitter_s``, as on a real bus where the controllers' clocks are
not aligned. A frame carries the log's row that covers its time (``[t, t + period)``), so
that decoding with the map's sampling gives the log's values back to the DBC's resolution
(half a scale step); a signal the log does not have is sent as J1939's "not available"
(all ones), which decoding counts as out of range.

``python -m ebus_env.io.can_encode LOG.csv OUT.mf4 --columns ebus_j1939`` encodes a log file.
"""

from __future__ import annotations

import datetime
from pathlib import Path

import numpy as np
import pandas as pd

from ebus_env.errors import ConfigError
from ebus_env.io import can_codec
from ebus_env.io.can_frames import Frames, write_frames
from ebus_env.io.can_map import SignalMap, load_signal_map

PHASE_S = 0.0031
"""Phase step between messages [s]: message k is sent 5 ms + k x this after each period
starts (clear of the row's start, which a file format that keeps its start time to the
millisecond, as BLF and ASC do, may shift by up to 1 ms)."""


def _times(table: pd.DataFrame) -> tuple[np.ndarray, datetime.datetime]:
    """Row times [s UTC] and the first row's date-time (with its offset)."""
    if "timestamp" not in table.columns:
        raise ConfigError("encode: the log needs a 'timestamp' column of date-times with a UTC "
                          "offset (the logger's clock).")
    stamps = pd.to_datetime(table["timestamp"].astype(str))
    if stamps.dt.tz is None:
        raise ConfigError("encode: the log's timestamps need a UTC offset (+01:00).")
    utc = stamps.dt.tz_convert("UTC")
    t = (utc - pd.Timestamp(0, tz="UTC")).dt.total_seconds().to_numpy(float)
    return t, stamps.iloc[0].to_pydatetime()


def encode_log(table: pd.DataFrame, smap: SignalMap | dict | str | Path, *, seed: int = 0,
               jitter_s: float = 0.002) -> Frames:
    """The CAN frames of the canonical log ``table`` (``timestamp`` with offsets, regular
    rows) through the signal map ``smap`` (see the module docstring)."""
    smap = load_signal_map(smap)
    t_row, first = _times(table)
    period = float(np.median(np.diff(t_row))) if len(t_row) > 1 else smap.period_s
    rng = np.random.default_rng(seed)
    rel = t_row - t_row[0]
    parts = []
    present = [e for e in smap.entries if e.column in table.columns]
    messages = list(dict.fromkeys(e.message for e in present))
    for k, name in enumerate(messages):
        message = smap.message(name)
        cycle = (message.cycle_time or 1000) / 1000.0
        # times from the first row (an arange over epoch seconds would drift: its step is
        # rounded at the magnitude of its start)
        n = int(np.floor((rel[-1] + period) / cycle + 1e-9))
        t = np.arange(n) * cycle + 0.005 + k * PHASE_S + rng.uniform(0.0, jitter_s, n)
        row = np.clip(np.searchsorted(rel, t, "right") - 1, 0, len(rel) - 1)
        inside = t < rel[row] + period  # no frame in a gap of the log
        t, row = t[inside], row[inside]
        raw = {}
        for e in (e for e in present if e.message == name):
            signal = message.get_signal_by_name(e.signal)
            values = table[e.column].to_numpy(float)[row]
            if e.values is not None:
                inverse = {}
                for r, v in e.values.items():
                    inverse.setdefault(v, r)
                missing = sorted(set(np.unique(values)) - set(inverse))
                if missing:
                    raise ConfigError(f"encode: {e.column} takes {missing[0]:g}, which the "
                                      f"state map of {e.source} does not give.")
                raw[e.signal] = np.array([inverse[v] for v in values], dtype=np.int64)
            else:
                raw[e.signal] = can_codec.to_raw((values - e.offset) / e.scale, signal)
        data = can_codec.encode(message, raw, len(t))
        parts.append((t, np.full(len(t), message.frame_id, np.uint32),
                      np.full(len(t), message.is_extended_frame),
                      np.full(len(t), message.length, np.uint8), data))
    t = np.concatenate([p[0] for p in parts])
    order = np.argsort(t, kind="stable")
    width = max(p[4].shape[1] for p in parts)
    data = np.concatenate([np.pad(p[4], ((0, 0), (0, width - p[4].shape[1]))) for p in parts])
    start = first  # the logger's clock: the first row's date-time, with its offset
    return Frames(t[order], *(np.concatenate([p[i] for p in parts])[order]
                                   for i in (1, 2, 3)), data[order], start)


def main(argv: list[str] | None = None) -> None:
    """``python -m ebus_env.io.can_encode LOG OUT --columns MAP [--seed N]``."""
    import argparse

    from ebus_env.outputs import atomic

    parser = argparse.ArgumentParser(prog="python -m ebus_env.io.can_encode",
                                     description="Encode a canonical log (CSV with date-times) "
                                                 "as a CAN logger file (.mf4, .blf, .asc).")
    parser.add_argument("log", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--columns", default="ebus_j1939", help="signal map (configs/logs)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    frames = encode_log(pd.read_csv(args.log, dtype={"timestamp": str}), args.columns,
                        seed=args.seed)
    with atomic(args.out) as tmp:
        write_frames(frames, tmp)
    print(f"{len(frames):,} frames -> {args.out}")


if __name__ == "__main__":  # pragma: no cover
    main()
