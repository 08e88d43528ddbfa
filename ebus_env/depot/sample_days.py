"""Made-up logger files from the project's own days: the shipped CAN examples and a small
depot folder to try ``ebus depot`` on (and to test it with).

A day is one of the hidden-effect service days (:mod:`ebus_env.diagnostics.hidden`): the
12 m bus simulated at 10 Hz with the case's hidden effect, logged at 1 Hz with the pack's
current and voltage (their means over each second), SoC with BMS noise and 0.1 % steps,
date-times in the depot's time zone. :func:`~ebus_env.io.can_encode.encode_log` makes the CAN
frames a logger would record of it, and the logger rolls them into files by time.

``python -m ebus_env.depot.sample_days examples`` rewrites ``data/can/example_day.mf4`` and
``example_day.blf`` (seeded, reproducible); ``python -m ebus_env.depot.sample_days depot FOLDER``
writes a made-up depot folder and its ``loggers.csv`` (see :data:`DEPOT`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from ebus_env import paths
from ebus_env.io.can_encode import encode_log
from ebus_env.io.can_frames import Frames, write_frames

ZONE = "Europe/Berlin"
SIGNAL_MAP = "ebus_j1939"
DM1_ID = 0x18FECA00
"""J1939's active diagnostic trouble codes (DM1), which every controller on a real bus sends
once a second: an id the example DBC does not describe, so the loader counts its frames."""


def day_table(case: str = "control", *, date: str = "2026-01-14", start_h: float = 6.0,
              hours: float = 2.0, zone: str = ZONE, seed: int = 0) -> pd.DataFrame:
    """A canonical 1 Hz log (``timestamp`` with UTC offsets) of a hidden-effect case's service
    day, ``hours`` long from ``start_h`` local time on ``date``, with the pack's current and
    voltage."""
    from ebus_env.diagnostics import hidden
    from ebus_env.synthetic import synthetic_log

    c = replace(hidden.case(case), start_h=start_h, hours=hours)
    profile, _ = hidden.day_profile(c)
    model = hidden.true_bus(c).build(hidden.DT_S)
    frame = synthetic_log(model, profile, soc_start=c.soc_start, period_s=1.0,
                          soc_step_pct=0.1, soc_noise_pct=0.02, seed=seed)
    frame = frame.drop(columns=["grade_frac"], errors="ignore")
    start = pd.Timestamp(date).tz_localize(zone) + pd.Timedelta(hours=start_h)
    stamps = start.tz_convert("UTC") + pd.to_timedelta(frame["time_s"], unit="s")
    frame.insert(0, "timestamp", [s.tz_convert(zone).isoformat() for s in stamps])
    return frame.drop(columns="time_s")


def with_unknown_id(frames: Frames, can_id: int = DM1_ID, period_s: float = 1.0) -> Frames:
    """``frames`` and an 8-byte frame of ``can_id`` every ``period_s`` (an id the DBC lacks)."""
    t = np.arange(frames.time_s[0], frames.time_s[-1], period_s) + 0.0417
    n = len(t)
    data = np.zeros((n, frames.data.shape[1]), dtype=np.uint8)
    data[:, :8] = [0x00, 0xFF, 0x00, 0x00, 0x00, 0x00, 0xFF, 0xFF]  # DM1: no active fault
    time_s = np.concatenate([frames.time_s, t])
    order = np.argsort(time_s, kind="stable")
    return Frames(time_s[order],
                  np.concatenate([frames.can_id, np.full(n, can_id, np.uint32)])[order],
                  np.concatenate([frames.extended, np.ones(n, bool)])[order],
                  np.concatenate([frames.length, np.full(n, 8, np.uint8)])[order],
                  np.concatenate([frames.data, data])[order], frames.start, dict(frames.other))


def rolled(frames: Frames, every_s: float, first_s: float = 0.0) -> list[Frames]:
    """The files a logger that starts a new file every ``every_s`` seconds of its clock writes
    (the first roll ``first_s`` after the frames start): each with its own start time."""
    import datetime

    edges = np.arange(frames.time_s[0] + first_s, frames.time_s[-1], every_s)
    edges = edges[edges > frames.time_s[0]]
    bounds = np.searchsorted(frames.time_s, edges)
    out = []
    for a, b in zip(np.concatenate([[0], bounds]), np.concatenate([bounds, [len(frames)]]),
                    strict=True):
        if b <= a:
            continue
        part = frames.take(slice(a, b))
        shift = float(part.time_s[0])
        part.start = frames.start + datetime.timedelta(seconds=shift)
        part.time_s = part.time_s - shift
        out.append(part)
    return out


def write_examples(folder: str | Path | None = None) -> list[Path]:
    """The shipped examples: 2 h of the control day from 06:00 (a charging layover at 07:00)
    as ``example_day.mf4``, and its first 10 minutes as ``example_day.blf``; both with DM1
    frames the DBC does not describe."""
    folder = Path(folder) if folder else paths.data("can")
    frames = with_unknown_id(encode_log(day_table("control", hours=2.0), SIGNAL_MAP, seed=1))
    short = frames.take(np.flatnonzero(frames.time_s < 600.0))
    return [write_frames(frames, folder / "example_day.mf4"),
            write_frames(short, folder / "example_day.blf")]


@dataclass(frozen=True)
class LoggedDay:
    """A service day a logger recorded in a bus of the made-up depot."""

    logger: str
    bus: str
    case: str
    date: str
    start_h: float
    hours: float
    suffix: str = ".mf4"
    roll_min: float = 40.0


DEPOT = (
    LoggedDay("L01", "bus-101", "control", "2026-01-14", 6.0, 2.0),
    LoggedDay("L01", "bus-101", "control", "2026-01-15", 6.5, 2.0),
    LoggedDay("L02", "bus-102", "cold_battery", "2026-01-14", 6.0, 2.0),
    LoggedDay("L03", "bus-102", "cold_battery", "2026-01-15", 6.0, 2.0, ".blf", 30.0),
    LoggedDay("L02", "bus-103", "control", "2026-01-15", 7.0, 2.0),
    LoggedDay("L04", "bus-104", "control", "2026-01-14", 22.5, 2.5, ".mf4", 120.0),
)
"""The made-up depot: logger L02 moves from bus-102 to bus-103 at 20:00 on the 14th and L03
takes its place; files rolled every 40 min (bus-102's BLF files every 30 min) hold parts of a
day; bus-104's late service runs past midnight in one file."""

LOGGERS_CSV = """logger_id,bus_id,valid_from,valid_to
L01,bus-101,2026-01-01,
L02,bus-102,2026-01-01,2026-01-14T20:00
L02,bus-103,2026-01-14T20:00,
L03,bus-102,2026-01-14T20:00,
L04,bus-104,2026-01-01,
"""


def write_depot(folder: str | Path, days=DEPOT, seed: int = 0) -> Path:
    """Write the made-up depot: ``folder/<logger>/<file>`` for each day's rolled files, and
    the logger-to-bus map ``folder/loggers.csv``. Returns the map's path."""
    folder = Path(folder)
    counter: dict[str, int] = {}
    for k, day in enumerate(days):
        table = day_table(day.case, date=day.date, start_h=day.start_h, hours=day.hours,
                          seed=seed + k)
        frames = with_unknown_id(encode_log(table, SIGNAL_MAP, seed=seed + k))
        (folder / day.logger).mkdir(parents=True, exist_ok=True)
        for part in rolled(frames, day.roll_min * 60.0, first_s=day.roll_min * 60.0 * 0.6):
            counter[day.logger] = counter.get(day.logger, 0) + 1
            write_frames(part, folder / day.logger / f"{counter[day.logger]:08d}{day.suffix}")
    path = folder / "loggers.csv"
    path.write_text(LOGGERS_CSV)
    return path


def main(argv: list[str] | None = None) -> None:
    """``python -m ebus_env.depot.sample_days examples [FOLDER] | depot FOLDER``."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m ebus_env.depot.sample_days",
                                     description="Write the shipped CAN examples, or a "
                                                 "made-up depot folder.")
    parser.add_argument("what", choices=("examples", "depot"))
    parser.add_argument("folder", nargs="?", type=Path)
    args = parser.parse_args(argv)
    if args.what == "examples":
        for p in write_examples(args.folder):
            print(p)
    else:
        if args.folder is None:
            parser.error("depot needs a FOLDER")
        print(f"depot -> {args.folder}, logger map -> {write_depot(args.folder)}")


if __name__ == "__main__":  # pragma: no cover
    main()
