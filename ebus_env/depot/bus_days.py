"""A depot's folder of logger files as one canonical log per bus and service day.

1. Every ``.mf4``, ``.blf`` and ``.asc`` file under the folder is read and decoded through the
   signal map (:mod:`ebus_env.io.can_log`); a file that cannot be read is listed with the
   reason, and the run goes on.
2. Its logger (:func:`~ebus_env.depot.loggers.logger_of`) and the logger-to-bus map give the
   bus of each of its samples, by time: a file that spans the moment a logger moved is cut
   there; samples outside every installation of the logger are counted, not given to a bus.
3. A bus's samples from all its files are merged in time (files rolled by size or time, a day
   spread over several files, a file spanning midnight) and cut into service days
   (:mod:`~ebus_env.depot.service_days`).
4. Each service day is sampled onto the map's rows and written as a canonical log,
   ``days/<bus>/<bus>_<local start>.csv.gz`` (timestamp with UTC offset and the mapped
   columns), which :func:`~ebus_env.io.measured.load_log` then reads like any log.
"""

from __future__ import annotations

import re
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ebus_env.depot.loggers import LoggerMap, logger_of
from ebus_env.depot.service_days import DEFAULT_RULE, DayRule, service_days
from ebus_env.errors import ConfigError, EbusError, LogError
from ebus_env.io.can_frames import SUFFIXES, is_can_file, read_frames
from ebus_env.io.can_log import Counts, Decoded, decode, describe, require, to_table
from ebus_env.io.can_map import SignalMap
from ebus_env.outputs import atomic


@dataclass
class LoggerFile:
    """One logger file and what became of it."""

    path: Path
    logger: str
    buses: list[str] = field(default_factory=list)
    counts: Counts | None = None
    unassigned: int = 0  # frames of the mapped messages outside every installation
    problem: str = ""  # why it gave nothing, or ""

    def row(self, folder: Path, smap: SignalMap) -> dict:
        c = self.counts or Counts()
        lines = describe(c, smap)[1] if self.counts else []
        return {"file": self.path.relative_to(folder).as_posix(), "logger": self.logger,
                "buses": " ".join(self.buses), "frames": c.frames,
                "unknown_id_frames": sum(c.unknown_ids.values()),
                "bad_length_frames": sum(s.bad_length for s in c.signals.values()),
                "out_of_range_values": sum(s.out_of_range for s in c.signals.values()),
                "unassigned_frames": self.unassigned,
                "problem": self.problem or "; ".join(lines)}


@dataclass
class BusDay:
    """One service day of one bus, written as a canonical log (``path``) or not (``problem``)."""

    bus: str
    start_s: float
    end_s: float
    path: Path | None = None
    first: str = ""  # the first row's date-time (local, with its offset)
    hours: float = 0.0  # rows x the row period: the hours the day has data for
    rows: int = 0
    notes: list[str] = field(default_factory=list)
    problem: str = ""

    def usable(self, rule: DayRule) -> bool:
        return self.path is not None and not self.problem and self.hours >= rule.min_day_h


@dataclass
class DepotDays:
    files: list[LoggerFile]
    days: list[BusDay]

    def of(self, bus: str) -> list[BusDay]:
        return [d for d in self.days if d.bus == bus]

    @property
    def buses(self) -> list[str]:
        return list(dict.fromkeys(d.bus for d in self.days))


def safe_name(text: str) -> str:
    """``text`` as a file name: letters, digits, ``.``, ``-`` and ``_``."""
    return re.sub(r"[^\w.-]", "_", text)


def logger_files(folder: Path) -> list[Path]:
    files = sorted(p for p in Path(folder).rglob("*") if p.is_file() and is_can_file(p))
    if not files:
        raise LogError(f"No logger files ({', '.join(SUFFIXES)}) in the folder", path=folder,
                       fix="give the folder the loggers' files were copied to")
    return files


def _assign(decoded: Decoded, item: LoggerFile, loggers: LoggerMap, parts) -> None:
    """Give each installation of the file's logger the samples of its time."""
    covered = 0
    for inst in loggers.of(item.logger):
        part = decoded.between(inst.start_s, inst.end_s)
        if part.activity_s.size:
            parts[inst.bus].append(part)
            item.buses.append(inst.bus)
            covered += part.activity_s.size
    item.unassigned = int(decoded.activity_s.size - covered)
    if item.unassigned:
        item.problem = (f"{item.unassigned:,} frames outside every installation of logger "
                        f"{item.logger} in the map: given to no bus")


def split_depot(folder: str | Path, loggers: LoggerMap, smap: SignalMap, out: str | Path,
                rule: DayRule = DEFAULT_RULE, progress=None) -> DepotDays:
    """Read the depot's folder and write each bus's service days into ``out/days`` (see the
    module docstring)."""
    folder, out = Path(folder), Path(out)
    say = progress or (lambda text: None)
    columns = {e.column for e in smap.entries}
    if "speed_kmh" not in columns:
        raise ConfigError(f"The signal map {smap.name} maps no speed_kmh: the service days are "
                          "cut at the bus's depot stays, which its speed shows. Fix: map the "
                          "vehicle speed onto speed_kmh.")
    files, parts = [], defaultdict(list)
    known = set(loggers.loggers)
    found = logger_files(folder)
    for k, path in enumerate(found):
        item = LoggerFile(path, logger_of(path, folder))
        files.append(item)
        if item.logger not in known:
            item.problem = (f"logger '{item.logger}' is not in the logger map "
                            f"{loggers.path.name}: not read")
            continue
        say(f"reading {k + 1}/{len(found)}: {path.relative_to(folder).as_posix()}")
        try:
            decoded = decode(read_frames(path), smap)
        except EbusError as exc:
            item.problem = str(exc)
            continue
        item.counts = decoded.counts
        _assign(decoded, item, loggers, parts)
    days = []
    for bus in sorted(parts):
        merged = Decoded.merge(parts[bus])
        t, v = merged.samples.get("speed_kmh", (np.zeros(0), np.zeros(0)))
        for start, end in service_days(t, v, rule):
            days.append(_write_day(bus, merged.between(start, end), smap, out, start, end))
    return DepotDays(files, days)


def _write_day(bus: str, part: Decoded, smap: SignalMap, out: Path, start: float,
               end: float) -> BusDay:
    day = BusDay(bus, start, end)
    try:
        require(part, smap)
    except LogError as exc:
        day.problem = str(exc)
        return day
    table, notes = to_table(part, smap)
    day.notes = part.notes + notes
    if len(table) < 2:
        day.problem = "fewer than two rows"
        return day
    day.first, day.rows = table["timestamp"].iloc[0], len(table)
    day.hours = len(table) * smap.period_s / 3600.0  # hours with data (gaps left out)
    stamp = day.first[:16].replace(":", "")
    path = out / "days" / safe_name(bus) / f"{safe_name(bus)}_{stamp}.csv.gz"
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic(path) as tmp:
        table.to_csv(tmp, index=False, float_format="%.7g",
                     compression={"method": "gzip", "mtime": 0})
    day.path = path
    return day
