"""Which bus each CAN logger was in, and when: the depot's logger-to-bus map.

A small CSV, one row per installation::

    logger_id,bus_id,valid_from,valid_to
    L01,bus-101,2026-01-01,
    L02,bus-102,2026-01-01,2026-01-15T12:00
    L02,bus-103,2026-01-15T12:00,

``valid_from`` and ``valid_to`` are ISO dates or date-times; one without a UTC offset is read
in the depot's time zone (the signal map's ``timezone``, else UTC); a date alone means its
00:00. An installation holds from ``valid_from`` up to, not including, ``valid_to``; an empty
``valid_to`` means the logger is still in that bus. A logger in two buses at once, or a bus
with two loggers at once, is refused naming both rows: their frames would be given to the
wrong bus, or counted twice. A logger's frames outside every installation of it (in the
workshop, between two buses) are counted and reported, not given to a bus.

A file belongs to the logger whose id is its first folder under the depot folder
(``L01/00000012.MF4``, as loggers such as CANedge write them), or, for a file directly in the
depot folder, the part of its name before the first ``_`` (``L01_20260114_0600.mf4``).
"""

from __future__ import annotations

import datetime
import math
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from ebus_env.errors import LogError, did_you_mean

COLUMNS = ("logger_id", "bus_id", "valid_from", "valid_to")


@dataclass(frozen=True)
class Installation:
    """A logger in a bus from ``start_s`` to ``end_s`` [s UTC; inf: still there]."""

    logger: str
    bus: str
    start_s: float
    end_s: float
    row: int  # data row of the map (0-based)


@dataclass(frozen=True)
class LoggerMap:
    path: Path
    installations: tuple[Installation, ...]

    @property
    def loggers(self) -> list[str]:
        return sorted({i.logger for i in self.installations})

    @property
    def buses(self) -> list[str]:
        return sorted({i.bus for i in self.installations})

    def of(self, logger: str) -> list[Installation]:
        return sorted((i for i in self.installations if i.logger == logger),
                      key=lambda i: i.start_s)


def logger_of(path: Path, folder: Path) -> str:
    """The logger a file belongs to (see the module docstring)."""
    parts = path.relative_to(folder).parts
    return parts[0] if len(parts) > 1 else parts[0].split("_", 1)[0]


def _time(text: str, zone: datetime.tzinfo, path: Path, column: str, row: int) -> float:
    """ISO 8601 only: a day-first or month-first date would be read one way in silence."""
    try:
        stamp = datetime.datetime.fromisoformat(text)
    except ValueError:
        raise LogError(f"'{text}' is not a date or date-time", path=path, column=column,
                       rows=[row], fix="write ISO 8601: 2026-01-15 or 2026-01-15T12:00 "
                                       "(+01:00)") from None
    if stamp.tzinfo is None:
        stamp = stamp.replace(tzinfo=zone)
    return stamp.timestamp()


def read_logger_map(path: str | Path, zone: datetime.tzinfo | None = None) -> LoggerMap:
    """Read and check the map (see the module docstring); ``zone``: the time zone of the
    date-times written without an offset (default UTC)."""
    path = Path(path)
    zone = zone or datetime.UTC
    if not path.is_file():
        raise LogError("The logger map does not exist", path=path,
                       fix="give a CSV with columns " + ", ".join(COLUMNS))
    try:
        table = pd.read_csv(path, dtype=str, keep_default_na=False)
    except (ValueError, OSError) as exc:
        raise LogError(f"The logger map cannot be read as CSV ({exc})", path=path,
                       fix="give a CSV with columns " + ", ".join(COLUMNS)) from None
    table.columns = [c.strip() for c in table.columns]
    for column in COLUMNS:
        if column not in table.columns:
            raise LogError(f"The logger map has no column '{column}'."
                           f"{did_you_mean(column, table.columns)}", path=path,
                           fix=f"its columns are {', '.join(COLUMNS)} (valid_to may be empty)")
    if table.empty:
        raise LogError("The logger map has no rows", path=path, fix="add a row per logger")
    rows = []
    for i, r in table.iterrows():
        logger, bus = r["logger_id"].strip(), r["bus_id"].strip()
        for column, value in (("logger_id", logger), ("bus_id", bus)):
            if not value:
                raise LogError("Empty cell", path=path, column=column, rows=[i],
                               fix="give every installation its logger and bus")
        if not r["valid_from"].strip():
            raise LogError("Empty cell", path=path, column="valid_from", rows=[i],
                           fix="give the date (or date-time) the logger went into the bus")
        start = _time(r["valid_from"].strip(), zone, path, "valid_from", i)
        end = math.inf if not r["valid_to"].strip() else \
            _time(r["valid_to"].strip(), zone, path, "valid_to", i)
        if end <= start:
            raise LogError(f"valid_to ({r['valid_to']}) is not after valid_from "
                           f"({r['valid_from']})", path=path, column="valid_to", rows=[i],
                           fix="an installation ends after it starts")
        rows.append(Installation(logger, bus, start, end, int(i)))
    _refuse_overlaps(rows, path)
    return LoggerMap(path, tuple(rows))


def _refuse_overlaps(rows: list[Installation], path: Path) -> None:
    for key, what, fix in (
            ("logger", "the logger is in two buses at once",
             "end the first installation (valid_to) where the second starts"),
            ("bus", "the bus has two loggers at once",
             "end the first logger's installation where the second's starts; a bus with two "
             "loggers is diagnosed from one")):
        for a in rows:
            for b in rows:
                if a.row < b.row and getattr(a, key) == getattr(b, key) and \
                        a.start_s < b.end_s and b.start_s < a.end_s:
                    raise LogError(f"Rows {a.row} and {b.row} overlap in time: {what} "
                                   f"({getattr(a, key)})", path=path,
                                   column="valid_from", rows=[a.row, b.row], fix=fix)
