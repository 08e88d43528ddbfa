"""CAN logger files as canonical logs: decode the frames through a signal map, count what
cannot be used, and sample the signals onto regular rows.

:func:`read_can_log` is what :func:`ebus_env.io.measured.load_log` calls for a ``.mf4``,
``.blf`` or ``.asc`` file; the table it returns then passes every check a CSV log passes.
The steps, each a function the depot workflow (:mod:`ebus_env.depot`) also calls on its own:

1. :func:`~ebus_env.io.can_frames.read_frames`: the file's data frames and start time.
2. :func:`decode`: each frame of a message the signal map uses is decoded with the DBC
   (:mod:`ebus_env.io.can_codec`), its values converted to the column's unit. Frames with an
   id the DBC lacks, frames of DBC messages the map does not use, frames whose length is not
   the message's (a wrong DLC) and values outside the signal's DBC range (J1939's error and
   "not available" codes among them) or outside a state map are counted, by id and by
   signal, and left out; nothing is dropped without a count in the loader's report.
3. :func:`to_table`: rows every ``1 / rate_hz`` seconds of UTC (so that files of one bus,
   rolled mid-day, fall onto one grid), a row covering ``[t, t + 1/rate_hz)``, each column
   sampled as its entry says (``mean``, ``last``, ``max``, ``min``); a row only where frames of
   the mapped messages arrived (a time the logger was off stays a gap, which the loader then
   reports or splits at); ``timestamp`` as ISO date-times with the UTC offset of the map's
   ``timezone`` (else of the file's header).
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ebus_env.errors import LogError
from ebus_env.io import can_codec
from ebus_env.io.can_frames import Frames, read_frames
from ebus_env.io.can_map import SignalMap, load_signal_map

UTC = datetime.UTC
TRIM_LIMIT_S = 60.0
"""Rows at the start (end) of a file before (after) a column's first (last) value are left
out, with a note, where that cuts at most this long; a column that starts later is left
missing for the loader's fill policy."""
SAMPLING_WORDS = {"mean": "mean of the values in each row", "last": "last value, held",
                  "max": "largest value in each row", "min": "smallest value in each row"}


@dataclass
class SignalCount:
    """What became of one column's signal."""

    source: str  # Message.Signal
    frames: int = 0  # frames of its message
    values: int = 0  # valid values decoded
    bad_length: int = 0  # frames of another length than the DBC's (not decoded)
    lengths: dict = field(default_factory=dict)  # those lengths -> frames
    out_of_range: int = 0  # values outside the DBC's range or the state map (left out)
    example: str = ""  # the first such value, with its time
    filled: int = 0  # rows set to the entry's default

    def add(self, other: SignalCount) -> None:
        for key in ("frames", "values", "bad_length", "out_of_range", "filled"):
            setattr(self, key, getattr(self, key) + getattr(other, key))
        for n, k in other.lengths.items():
            self.lengths[n] = self.lengths.get(n, 0) + k
        self.example = self.example or other.example


@dataclass
class Counts:
    """Frames of a file (or of a bus's files) by what became of them."""

    frames: int = 0
    unknown_ids: dict = field(default_factory=dict)  # "0x18FEE900" -> frames
    unused: dict = field(default_factory=dict)  # DBC message the map does not use -> frames
    other: dict = field(default_factory=dict)  # error and remote frames
    signals: dict = field(default_factory=dict)  # column -> SignalCount

    def add(self, other: Counts) -> None:
        self.frames += other.frames
        for mine, theirs in ((self.unknown_ids, other.unknown_ids), (self.unused, other.unused),
                             (self.other, other.other)):
            for key, n in theirs.items():
                mine[key] = mine.get(key, 0) + n
        for column, count in other.signals.items():
            if column in self.signals:
                self.signals[column].add(count)
            else:
                self.signals[column] = SignalCount(**{**count.__dict__,
                                                      "lengths": dict(count.lengths)})

    def to_json(self) -> dict:
        return {"frames": self.frames, "unknown_ids": dict(self.unknown_ids),
                "unused_messages": dict(self.unused), "error_or_remote": dict(self.other),
                "signals": {c: dict(s.__dict__) for c, s in self.signals.items()}}


@dataclass
class Decoded:
    """A file's (or several files') decoded signals, in UTC seconds."""

    samples: dict[str, tuple[np.ndarray, np.ndarray]]  # column -> (t [s UTC], value)
    activity_s: np.ndarray  # arrival times of the mapped messages' frames [s UTC]
    zone: datetime.tzinfo  # the clock the date-times are written in
    counts: Counts
    notes: list[str] = field(default_factory=list)

    @property
    def span_s(self) -> tuple[float, float]:
        return float(self.activity_s[0]), float(self.activity_s[-1])

    def between(self, t0: float, t1: float) -> Decoded:
        """The samples in ``[t0, t1)`` (UTC seconds); counts stay the whole's."""
        def cut(t):
            return slice(np.searchsorted(t, t0, "left"), np.searchsorted(t, t1, "left"))

        return Decoded({c: (t[cut(t)], v[cut(t)]) for c, (t, v) in self.samples.items()},
                       self.activity_s[cut(self.activity_s)], self.zone, self.counts,
                       list(self.notes))

    @classmethod
    def merge(cls, parts: list[Decoded]) -> Decoded:
        """One time-ordered whole of several files' samples (a sample repeated at the same
        time, as two copies of a file give, is kept once, with a note)."""
        counts, notes, samples = Counts(), [], {}
        for p in parts:
            counts.add(p.counts)
            notes += [n for n in p.notes if n not in notes]
        repeated = 0
        for column in dict.fromkeys(c for p in parts for c in p.samples):
            t = np.concatenate([p.samples[column][0] for p in parts if column in p.samples])
            v = np.concatenate([p.samples[column][1] for p in parts if column in p.samples])
            order = np.argsort(t, kind="stable")
            t, v = t[order], v[order]
            keep = np.ones(len(t), dtype=bool)
            keep[1:] = np.diff(t) > 0
            repeated = max(repeated, int((~keep).sum()))
            samples[column] = (t[keep], v[keep])
        activity = np.unique(np.concatenate([p.activity_s for p in parts]))
        if repeated:
            notes.append(f"{repeated} samples came twice (two files of the same time, such as "
                         "a copy): each counted once")
        return cls(samples, activity, parts[0].zone, counts, notes)


def _clock(start: datetime.datetime, smap: SignalMap) -> tuple[float, datetime.tzinfo, str]:
    """The start in UTC seconds, the zone to write date-times in, and a note."""
    if start.tzinfo is not None:
        zone = smap.timezone or start.tzinfo
        return start.timestamp(), zone, ""
    if smap.timezone is not None:
        return start.replace(tzinfo=smap.timezone).timestamp(), smap.timezone, ""
    return start.replace(tzinfo=UTC).timestamp(), UTC, (
        f"the logger's start time ({start.isoformat()}) has no UTC offset and the signal map "
        "names no timezone: taken as UTC (set timezone: in the preset, e.g. Europe/Berlin)")


def _stamp(t_s: float, zone) -> str:
    return datetime.datetime.fromtimestamp(t_s, zone).isoformat(timespec="milliseconds")


def _in_range(values: np.ndarray, raw: np.ndarray, signal, entry) -> np.ndarray:
    """Whether each value lies in the signal's DBC range (and, for a state, its map)."""
    if entry.values is not None:
        return np.isin(raw, list(entry.values))
    low, high = signal.minimum, signal.maximum
    ok = np.isfinite(values)
    if low is None and high is None or (low == 0 and high == 0):  # [0|0]: no range given
        return ok
    tol = 0.5 * abs(signal.scale)  # the range as written may round the top raw value
    if low is not None:
        ok &= values >= low - tol
    if high is not None:
        ok &= values <= high + tol
    return ok


def decode(frames: Frames, smap: SignalMap | dict | str | Path) -> Decoded:
    """Decode ``frames`` through the signal map (see the module docstring)."""
    smap = load_signal_map(smap)
    t0, zone, note = _clock(frames.start, smap)
    t_abs = t0 + frames.time_s
    counts = Counts(frames=len(frames), other=dict(frames.other))
    key = frames.can_id.astype(np.int64) | (frames.extended.astype(np.int64) << 32)
    by_key = {m.frame_id | (int(m.is_extended_frame) << 32): m for m in smap.database.messages}
    known = np.isin(key, list(by_key))
    ids, n = np.unique(key[~known], return_counts=True)
    for k, c in zip(ids, n, strict=True):
        width = 8 if k >> 32 else 3
        counts.unknown_ids[f"0x{int(k) & 0x1FFFFFFF:0{width}X}"] = int(c)
    used = {e.message for e in smap.entries}
    samples, activity = {}, []
    for k, message in by_key.items():
        rows = np.flatnonzero(key == k)
        if message.name not in used:
            if rows.size:
                counts.unused[message.name] = int(rows.size)
            continue
        entries = [e for e in smap.entries if e.message == message.name]
        activity.append(t_abs[rows])
        good = rows[frames.length[rows] == message.length]
        bad = rows[frames.length[rows] != message.length]
        lengths = dict(zip(*np.unique(frames.length[bad], return_counts=True), strict=True))
        data = frames.data[good]
        decoded = None if can_codec.fast(message) else \
            can_codec.decode_slow(data, frames.length[good], message)
        for e in entries:
            signal = message.get_signal_by_name(e.signal)
            count = SignalCount(e.source, frames=int(rows.size), bad_length=int(bad.size),
                                lengths={int(a): int(b) for a, b in lengths.items()})
            if decoded is None:
                raw = can_codec.raw_values(data, signal)
                value = can_codec.physical(raw, signal)
            else:
                value = decoded[e.signal]
                raw = np.where(np.isfinite(value), np.rint((value - signal.offset)
                                                           / signal.scale), -1).astype(np.int64)
            carried = np.isfinite(value)  # a multiplexed signal is not in every frame
            ok = _in_range(value, raw, signal, e) & carried
            wrong = np.flatnonzero(~ok & carried)
            if wrong.size:
                count.out_of_range = int(wrong.size)
                count.example = f"{value[wrong[0]]:g} at {_stamp(t_abs[good][wrong[0]], zone)}"
            if e.values is not None:
                column = np.array([e.values.get(int(r), np.nan) for r in raw[ok]]) \
                    if ok.any() else np.zeros(0)
            else:
                column = e.offset + e.scale * value[ok]
            count.values = int(ok.sum())
            counts.signals[e.column] = count
            samples[e.column] = (t_abs[good][ok], column)
    activity_s = np.unique(np.concatenate(activity)) if activity else np.zeros(0)
    return Decoded(samples, activity_s, zone, counts, [note] if note else [])


def require(decoded: Decoded, smap: SignalMap, path=None) -> None:
    """A required signal without a valid value is an error naming it, its message and id."""
    for e in smap.entries:
        if not e.required or decoded.samples.get(e.column, (np.zeros(0),))[0].size:
            continue
        message = smap.message(e.message)
        count = decoded.counts.signals.get(e.column)
        ident = f"0x{message.frame_id:0{8 if message.is_extended_frame else 3}X}"
        if count is None or count.frames == 0:
            why = f"no frame of {e.message} (id {ident}) in the file"
            fix = (f"check that the logger records the CAN bus that carries {e.message} and "
                   f"that {smap.dbc_path.name} is this bus's DBC; or set required: false for "
                   f"{e.column} in the signal map {smap.name}")
        else:
            why = (f"its {count.frames} frame(s) of {e.message} hold no valid value "
                   f"({count.bad_length} of another length than {message.length} bytes, "
                   f"{count.out_of_range} out of range" +
                   (f", e.g. {count.example}" if count.example else "") + ")")
            fix = (f"check the DBC's layout of {e.source} against the logger's frames, or set "
                   f"required: false for {e.column} in the signal map {smap.name}")
        raise LogError(f"The required signal {e.source} ({e.column}) is missing: {why}",
                       path=path, column=e.column, fix=fix)


def to_table(decoded: Decoded, smap: SignalMap) -> tuple[pd.DataFrame, list[str]]:
    """The canonical table (``timestamp`` and one column per entry with values) and the notes
    of what was done (see the module docstring)."""
    period = smap.period_s
    notes: list[str] = []
    bins = np.unique(np.floor(decoded.activity_s / period).astype(np.int64))
    start_s = bins * period
    columns: dict[str, np.ndarray] = {}
    for e in smap.entries:
        t, v = decoded.samples.get(e.column, (np.zeros(0), np.zeros(0)))
        if not t.size and e.default is None:
            notes.append(f"'{e.column}' ({e.source}) has no valid value: left out")
            continue
        values = _sample(t, v, bins, start_s, period, e)
        empty = np.isnan(values)
        if e.default is not None and empty.any():
            values[empty] = e.default
            decoded.counts.signals.setdefault(e.column, SignalCount(e.source)).filled += \
                int(empty.sum())
        columns[e.column] = values
    if not columns or not bins.size:
        return pd.DataFrame({"timestamp": []}), notes
    keep = _trimmed(columns, start_s, notes)
    rows = start_s[keep]
    stamps = pd.to_datetime(rows, unit="s", utc=True).tz_convert(decoded.zone)
    timespec = "seconds" if np.allclose(rows, np.round(rows)) else "milliseconds"
    table = pd.DataFrame({"timestamp": [s.isoformat(timespec=timespec) for s in stamps]})
    for column, values in columns.items():
        table[column] = values[keep]
    return table, notes


def _sample(t, v, bins, start_s, period, e) -> np.ndarray:
    """One value per row (NaN where none) as the entry's ``sample`` says."""
    out = np.full(len(bins), np.nan)
    if not t.size:
        return out
    if e.sample == "last":
        end = start_s + period
        j = np.searchsorted(t, end, "left") - 1
        ok = (j >= 0) & (t[np.maximum(j, 0)] >= start_s - e.hold_s)
        out[ok] = v[j[ok]]
        return out
    row = np.searchsorted(bins, np.floor(t / period).astype(np.int64))
    if e.sample == "mean":
        n = np.bincount(row, minlength=len(bins))
        total = np.bincount(row, weights=v, minlength=len(bins))
        has = n > 0
        out[has] = total[has] / n[has]
    else:
        ufunc = np.fmax if e.sample == "max" else np.fmin
        ufunc.at(out, row, v)
    return out


def _trimmed(columns: dict[str, np.ndarray], start_s: np.ndarray, notes: list[str]) -> slice:
    """The rows from where every column has a value to where the last one still has,
    cutting at most :data:`TRIM_LIMIT_S` at either end (with a note)."""
    n = len(start_s)
    first, last = 0, n - 1
    for values in columns.values():
        ok = np.flatnonzero(~np.isnan(values))
        if not ok.size:
            continue
        if start_s[ok[0]] - start_s[0] <= TRIM_LIMIT_S:
            first = max(first, int(ok[0]))
        if start_s[-1] - start_s[ok[-1]] <= TRIM_LIMIT_S:
            last = min(last, int(ok[-1]))
    if first > 0:
        notes.append(f"the first {start_s[first] - start_s[0]:g} s left out, before every "
                     "signal had its first value")
    if last < n - 1:
        notes.append(f"the last {start_s[-1] - start_s[last]:g} s left out, after a signal's "
                     "last value")
    return slice(first, last + 1)


def describe(counts: Counts, smap: SignalMap) -> tuple[list[str], list[str], list[str]]:
    """The counts as the loader's report lines: ``(changes, warnings, ignored)``."""
    changes, warnings, ignored = [], [], []
    sampled = []
    for e in smap.entries:
        c = counts.signals.get(e.column)
        if c is None:
            continue
        how = SAMPLING_WORDS[e.sample] + (f" up to {e.hold_s:g} s" if e.sample == "last" else "")
        conv = f"; {e.how}" if e.how else ""
        sampled.append(f"{e.column} <- {e.source} ({how}; {c.values:,} values{conv})")
        problems = []
        if c.bad_length:
            lengths = ", ".join(f"{n} bytes" for n in sorted(c.lengths))
            problems.append(f"{c.bad_length:,} frames of another length ({lengths}) than "
                            f"the DBC's {smap.message(e.message).length}: not decoded")
        if c.out_of_range:
            problems.append(f"{c.out_of_range:,} values outside its range"
                            + (" or state map" if e.values else "") + f" (e.g. {c.example}): "
                            "left out")
        if problems:
            warnings.append(f"{e.column} ({e.source}): " + "; ".join(problems))
        if c.filled:
            changes.append(f"{e.column}: {c.filled:,} rows without a {e.source} value set to "
                           f"{e.default:g} (the signal map's default)")
    changes.insert(0, f"decoded {counts.frames:,} CAN frames with {smap.dbc_path.name} "
                      f"(signal map {smap.name}) into rows of {smap.period_s:g} s: "
                   + "; ".join(sampled))
    if counts.unknown_ids:
        ids = sorted(counts.unknown_ids.items(), key=lambda kv: -kv[1])
        listing = ", ".join(f"{k} ({n:,})" for k, n in ids[:8])
        more = f" and {len(ids) - 8} more ids" if len(ids) > 8 else ""
        ignored.append(f"{sum(counts.unknown_ids.values()):,} frames with ids the DBC does not "
                       f"have: {listing}{more}")
    if counts.unused:
        ignored.append(f"{sum(counts.unused.values()):,} frames of DBC messages the signal map "
                       "does not use: " + ", ".join(f"{k} ({n:,})"
                                                    for k, n in counts.unused.items()))
    if counts.other:
        ignored.append("not data frames: " + ", ".join(f"{n:,} {k.split('_')[1]}s"
                                                      for k, n in counts.other.items()))
    return changes, warnings, ignored


def read_can_log(path: str | Path, columns, report) -> pd.DataFrame:
    """A logger file as the loader's table (canonical names, ``timestamp`` with UTC offsets),
    with what was done and counted added to ``report`` (a
    :class:`~ebus_env.io.measured.LoadReport`)."""
    if columns is None:
        raise LogError("A CAN logger file is decoded through a signal map (a DBC and which "
                       "signal feeds which column)", path=path,
                       fix="give one: --columns ebus_j1939 (columns='ebus_j1939' from Python) "
                           "for the shipped example DBC, or a preset of your own in "
                           "configs/logs with dbc: and signals: (docs/inputs.md)")
    smap = load_signal_map(columns)
    decoded = decode(read_frames(path), smap)
    require(decoded, smap, path)
    table, notes = to_table(decoded, smap)
    changes, warnings, ignored = describe(decoded.counts, smap)
    report.changes += changes + decoded.notes + notes
    report.warnings += warnings
    report.ignored += ignored
    report.frames = decoded.counts.to_json()
    for e in smap.entries:
        if e.column in table.columns:
            report.columns[e.column] = e.source
    if len(table) < 2:
        raise LogError(f"The logger file gives {len(table)} row(s) of {smap.period_s:g} s",
                       path=path, fix="give a longer file")
    return table
