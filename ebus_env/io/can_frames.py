"""Raw CAN frames of a logger file: read and write ``.mf4``, ``.blf`` and ``.asc``.

- ``.mf4`` (ASAM MDF 4 bus logging, as CAN loggers such as CSS Electronics' CANedge or
  Vector's write it): read and written with asammdf, every ``CAN_DataFrame`` channel group
  at once (no frame-by-frame loop). The header's start time is in UTC, with the logger's
  UTC offset where it recorded one, or a local clock where the header says so.
- ``.blf`` (Vector binary logging) and ``.asc`` (Vector ASCII): read and written with
  python-can, frame by frame. Their start time is the logger's local clock, without a zone.

A :class:`Frames` holds the data frames as arrays; error and remote frames are counted, not
kept. The zone of a clock without one is the signal map's ``timezone``
(:mod:`ebus_env.io.can_log`).
"""

from __future__ import annotations

import datetime
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ebus_env.errors import ConfigError, LogError

SUFFIXES = (".mf4", ".mdf", ".blf", ".asc")
"""Logger files the loader reads as CAN frames (decoded through a signal map)."""
ID_MASK = 0x1FFFFFFF
EXTENDED_FLAG = 0x80000000  # set on extended ids by some MDF writers and in DBC files
UTC = datetime.UTC


def is_can_file(path: str | Path) -> bool:
    return Path(path).suffix.lower() in SUFFIXES


@dataclass
class Frames:
    """Data frames of one logger file (or of part of one).

    ``time_s`` counts from ``start`` (the logger's start time: zone-aware, or naive for a
    local clock of unknown zone); ``data`` holds the data bytes (zeros past ``length``)."""

    time_s: np.ndarray  # float64 [s]
    can_id: np.ndarray  # uint32, without the extended flag
    extended: np.ndarray  # bool
    length: np.ndarray  # uint8: data bytes in the frame
    data: np.ndarray  # uint8 (n, width)
    start: datetime.datetime
    other: dict[str, int] = field(default_factory=dict)  # error/remote frames, counted

    def __len__(self) -> int:
        return len(self.time_s)

    def take(self, rows) -> Frames:
        return Frames(self.time_s[rows], self.can_id[rows], self.extended[rows],
                      self.length[rows], self.data[rows], self.start, dict(self.other))


def _need(module: str, path):
    from ebus_env.io.can_map import need

    need(f"reading {Path(path).suffix} files")
    import importlib

    return importlib.import_module(module)


def read_frames(path: str | Path) -> Frames:
    """The data frames of a logger file (by suffix: ``.mf4``/``.mdf``, ``.blf``, ``.asc``)."""
    path = Path(path)
    suffix = path.suffix.lower()
    try:
        if suffix in (".mf4", ".mdf"):
            frames = _read_mdf(path)
        elif suffix == ".blf":
            frames = _read_python_can(path, "blf")
        elif suffix == ".asc":
            frames = _read_python_can(path, "asc")
        else:
            raise ConfigError(f"{path}: not a CAN logger file ({', '.join(SUFFIXES)}).")
    except (LogError, ConfigError):
        raise
    except Exception as exc:  # the readers raise their own errors on a damaged file
        raise LogError(f"The file cannot be read as a {suffix} CAN log ({type(exc).__name__}: "
                       f"{exc})", path=path, fix="copy it from the logger again; a file the "
                       "logger was still writing when it lost power may be cut short") from None
    if not len(frames):
        raise LogError("The logger file holds no CAN data frames", path=path,
                       fix="check that the logger recorded the bus (its channel, bit rate)")
    order = np.argsort(frames.time_s, kind="stable")
    return frames if np.all(order == np.arange(len(order))) else frames.take(order)


def _read_mdf(path: Path) -> Frames:
    asammdf = _need("asammdf", path)
    parts, other = [], {}
    with asammdf.MDF(str(path)) as mdf:
        start = mdf.header.start_time
        for index, group in enumerate(mdf.groups):
            names = {ch.name for ch in group.channels}
            for kind in ("CAN_ErrorFrame", "CAN_RemoteFrame"):
                if f"{kind}.ID" in names or kind in names:
                    rows = int(group.channel_group.cycles_nr)
                    if rows:
                        other[kind] = other.get(kind, 0) + rows
            if "CAN_DataFrame.ID" not in names or not group.channel_group.cycles_nr:
                continue

            def get(name, index=index):
                return mdf.get(name, group=index, raw=True)

            ids = get("CAN_DataFrame.ID")
            data = get("CAN_DataFrame.DataBytes").samples
            if data.dtype == object:  # variable-length payloads
                width = max(len(row) for row in data)
                block = np.zeros((len(data), width), dtype=np.uint8)
                for i, row in enumerate(data):
                    block[i, :len(row)] = np.frombuffer(bytes(row), dtype=np.uint8)
                data = block
            n = len(ids.samples)
            length = get("CAN_DataFrame.DataLength").samples if \
                "CAN_DataFrame.DataLength" in names else get("CAN_DataFrame.DLC").samples
            raw_id = ids.samples.astype(np.uint64)
            ide = get("CAN_DataFrame.IDE").samples.astype(bool) if "CAN_DataFrame.IDE" in names \
                else ((raw_id & EXTENDED_FLAG) > 0) | ((raw_id & ID_MASK) > 0x7FF)
            parts.append((ids.timestamps.astype(float), (raw_id & ID_MASK).astype(np.uint32),
                          ide, np.asarray(length, dtype=np.uint8),
                          np.asarray(data, dtype=np.uint8).reshape(n, -1)))
    return _joined(parts, start, other)


def _joined(parts, start, other) -> Frames:
    if not parts:
        return Frames(np.zeros(0), np.zeros(0, np.uint32), np.zeros(0, bool),
                      np.zeros(0, np.uint8), np.zeros((0, 8), np.uint8), start, other)
    width = max(p[4].shape[1] for p in parts)
    data = np.concatenate([np.pad(p[4], ((0, 0), (0, width - p[4].shape[1]))) for p in parts])
    return Frames(*(np.concatenate([p[i] for p in parts]) for i in range(4)), data, start, other)


def _read_python_can(path: Path, kind: str) -> Frames:
    can = _need("can", path)
    if kind == "blf":
        reader = can.BLFReader(str(path))
        # python-can reads the header's SYSTEMTIME as UTC; it is the logger's local clock
        start = datetime.datetime.fromtimestamp(reader.start_timestamp, UTC).replace(tzinfo=None)
        origin = reader.start_timestamp
    else:
        reader = can.ASCReader(str(path), relative_timestamp=True)
        start = _asc_start(path)
        origin = 0.0
    t, ids, ext, lengths, rows, other = [], [], [], [], [], {}
    with reader:
        for msg in reader:
            if msg.is_error_frame or msg.is_remote_frame:
                kind_ = "CAN_ErrorFrame" if msg.is_error_frame else "CAN_RemoteFrame"
                other[kind_] = other.get(kind_, 0) + 1
                continue
            t.append(msg.timestamp - origin)
            ids.append(msg.arbitration_id)
            ext.append(msg.is_extended_id)
            lengths.append(len(msg.data))
            rows.append(bytes(msg.data))
    width = max((len(r) for r in rows), default=8)
    data = np.zeros((len(rows), max(width, 8)), dtype=np.uint8)
    for i, r in enumerate(rows):
        data[i, :len(r)] = np.frombuffer(r, dtype=np.uint8)
    return Frames(np.asarray(t, dtype=float), np.asarray(ids, dtype=np.uint32),
                  np.asarray(ext, dtype=bool), np.asarray(lengths, dtype=np.uint8), data, start,
                  other)


_MONTHS = {m: i + 1 for i, m in enumerate(
    ("jan", "feb", "mar", "apr", "may", "jun", "jul", "aug", "sep", "oct", "nov", "dec"))}
_MONTHS.update({"mär": 3, "mai": 5, "okt": 10, "dez": 12})
_ASC_DATE = re.compile(r"(?:date|begin\s+triggerblock)\s+\w+\s+(\w+)\s+(\d+)\s+(\d+):(\d+):(\d+)"
                       r"(?:\.(\d+))?\s*(am|pm)?\s+(\d{4})", re.IGNORECASE)


def _asc_start(path: Path) -> datetime.datetime:
    """The local clock of an ASC file's trigger block (else its ``date`` line), naive: the
    file's relative times count from it."""
    found = None
    with open(path, encoding="latin-1") as f:
        for _, line in zip(range(50), f, strict=False):
            match = _ASC_DATE.match(line.strip())
            if match:
                found = match  # the trigger block's date comes after the header's
                if line.strip().lower().startswith("begin"):
                    break
    if found is None:
        raise LogError("The ASC file has no 'date' or 'Begin Triggerblock' line with its start "
                       "time", path=path, fix="export it again with its header")
    month, day, hour, minute, second, frac, half, year = found.groups()
    if month.lower()[:3] not in _MONTHS and month.lower() not in _MONTHS:
        raise LogError(f"The ASC file's start date has an unknown month '{month}'", path=path,
                       fix="write the date in English (Jan, Feb, ...)")
    hour = int(hour) % 12 + (12 if half and half.lower() == "pm" else 0) if half else int(hour)
    micro = int((frac or "0").ljust(6, "0")[:6])
    return datetime.datetime(int(year), _MONTHS.get(month.lower()[:3], _MONTHS.get(
        month.lower())), int(day), hour, int(minute), int(second), micro)


def write_frames(frames: Frames, path: str | Path) -> Path:
    """Write ``frames`` as a logger file (by suffix). For ``.blf`` and ``.asc`` the start time
    is written as the local clock (a zone-aware start in its own zone)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in (".mf4", ".mdf"):
        _write_mdf(frames, path)
    elif suffix in (".blf", ".asc"):
        _write_python_can(frames, path, suffix)
    else:
        raise ConfigError(f"{path}: write .mf4, .blf or .asc.")
    return path


def _write_mdf(frames: Frames, path: Path) -> None:
    asammdf = _need("asammdf", path)
    from asammdf.blocks.source_utils import Source

    width = max(8, int(frames.length.max()) if len(frames) else 8)
    dtype = np.dtype([("CAN_DataFrame.BusChannel", "<u1"), ("CAN_DataFrame.ID", "<u4"),
                      ("CAN_DataFrame.IDE", "<u1"), ("CAN_DataFrame.DLC", "<u1"),
                      ("CAN_DataFrame.DataLength", "<u1"),
                      ("CAN_DataFrame.DataBytes", f"({width},)u1"),
                      ("CAN_DataFrame.Dir", "<u1")])
    samples = np.zeros(len(frames), dtype=dtype)
    samples["CAN_DataFrame.BusChannel"] = 1
    samples["CAN_DataFrame.ID"] = frames.can_id | np.where(frames.extended, EXTENDED_FLAG, 0
                                                           ).astype(np.uint32)
    samples["CAN_DataFrame.IDE"] = frames.extended
    samples["CAN_DataFrame.DLC"] = frames.length
    samples["CAN_DataFrame.DataLength"] = frames.length
    samples["CAN_DataFrame.DataBytes"] = frames.data[:, :width]
    mdf = asammdf.MDF(version="4.10")
    mdf.header.start_time = frames.start
    mdf.append(asammdf.Signal(samples=samples, timestamps=frames.time_s, name="CAN_DataFrame",
                              source=Source(name="CAN1", path="CAN1", comment="",
                                            source_type=Source.SOURCE_BUS,
                                            bus_type=Source.BUS_TYPE_CAN)),
               common_timebase=True)
    mdf.save(str(path), overwrite=True, compression=2)
    mdf.close()


def _write_python_can(frames: Frames, path: Path, suffix: str) -> None:
    can = _need("can", path)
    clock = frames.start if frames.start.tzinfo is None else frames.start.replace(tzinfo=None)
    origin = clock.replace(tzinfo=UTC).timestamp()  # the local clock as python-can's "UTC"
    if suffix == ".blf":
        writer = can.BLFWriter(str(path))
    else:
        first = clock + datetime.timedelta(seconds=float(frames.time_s[0]))

        class Writer(can.ASCWriter):  # the header's dates: the log's clock, not now(), and
            # its milliseconds in 3 digits (python-can 4.6 writes 06:00:00.1 for .001)
            def _format_header_datetime(self, dt):
                return (first.strftime("%a %b %d %I:%M:%S") + f".{first.microsecond // 1000:03d}"
                        + first.strftime(" %p %Y"))

        writer = Writer(str(path))
    with writer:
        for t, cid, ext, n, row in zip(frames.time_s, frames.can_id, frames.extended,
                                       frames.length, frames.data, strict=True):
            writer.on_message_received(can.Message(
                timestamp=origin + float(t), arbitration_id=int(cid), is_extended_id=bool(ext),
                dlc=int(n), data=bytes(row[:n]), channel=0))
