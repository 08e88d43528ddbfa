"""Ingest payloads: batches of 1 Hz samples as JSON or CSV lines, or a logger file, checked
and turned into one table of canonical columns before anything is stored.

A batch is refused whole (nothing of it stored) with an error that names the row and the field:
a sample without a time or a speed, a value that is not a number, a value outside its
physical range (``ebus_env.inputs``), a time that does not follow the row before it, an
unknown field, or more rows than :data:`MAX_ROWS`.

Times (``t``) are UTC: seconds since the epoch, or ISO 8601 date-times (with an offset, or
naive and then read as UTC).
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ebus_env.errors import EbusError
from ebus_env.inputs import RANGES
from ebus_env.twin.store import SAMPLE_COLUMNS

MAX_ROWS = 3600
"""Most samples in one batch: an hour at 1 Hz (a logger that was offline sends its backlog
in hour-long batches)."""
MAX_BATCH_BYTES = 2_000_000
"""Largest batch body [bytes]: an hour at 1 Hz of every column, as JSON, with room to spare."""
MAX_FILE_BYTES = 200_000_000
"""Largest uploaded logger file [bytes]."""
FLAGS = ("charging", "door_open")
RANGE_OF = {"speed_kmh": "log_speed_kmh", "soc_pct": "log_soc_pct",
            "ambient_degc": "ambient_degc", "charger_kw": "log_charger_kw",
            "passengers": "log_passengers", "grade_pct": "log_grade_pct",
            "altitude_m": "log_altitude_m", "battery_current_a": "log_current_a",
            "battery_voltage_v": "log_voltage_v", "logged_load_kw": "log_load_kw"}
"""Each sample column's declared range (``ebus_env.inputs.RANGES``)."""
EARLIEST_T = 946_684_800.0  # 2000-01-01: a time before it is a logger's clock not yet set
LATEST_AHEAD_S = 86_400.0  # a time more than a day ahead of the twin's clock is refused


class PayloadError(EbusError, ValueError):
    """A payload the twin refuses; ``field`` and ``row`` (1-based, data rows) say where."""

    def __init__(self, message: str, field: str | None = None, row: int | None = None,
                 status: int = 422):
        where = ", ".join(p for p in (f"row {row}" if row else "",
                                      f"field '{field}'" if field else "") if p)
        super().__init__(f"{where}: {message}" if where else message)
        self.field, self.row, self.status, self.reason = field, row, status, message

    def to_json(self) -> dict:
        return {"error": str(self), "field": self.field, "row": self.row}


Columns = dict[str, np.ndarray]
"""Checked samples: ``t`` and the canonical columns present, float arrays of one length."""


@dataclass
class Batch:
    """A checked batch: ``columns`` holds ``t`` and the canonical columns, one value per
    sample, in time order; ``batch_id`` is the logger's, or the content's hash."""

    columns: Columns
    batch_id: str

    @property
    def n_rows(self) -> int:
        return len(self.columns["t"])

    @property
    def frame(self) -> pd.DataFrame:
        return pd.DataFrame(self.columns)


def _number(value, field: str, row: int) -> float:
    if value is None or (isinstance(value, str) and value.strip() == ""):
        return math.nan
    if isinstance(value, bool):
        return float(value)
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise PayloadError(f"'{value}' is not a number", field, row) from None
    if math.isinf(x) or (math.isnan(x) and field == "speed_kmh"):
        raise PayloadError(f"'{value}' is not a finite number", field, row)
    return x


def parse_time(value, row: int) -> float:
    """``t`` as UTC epoch seconds: a number, or an ISO 8601 date-time."""
    if value is None or (isinstance(value, str) and not value.strip()):
        raise PayloadError("every sample needs its time", "t", row)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        x = float(value)
    else:
        text = str(value).strip()
        try:
            x = float(text)
        except ValueError:
            try:
                stamp = pd.Timestamp(text)
            except (ValueError, TypeError):
                raise PayloadError(f"'{value}' is neither epoch seconds nor an ISO 8601 "
                                   "date-time", "t", row) from None
            if stamp.tzinfo is None:
                stamp = stamp.tz_localize("UTC")
            x = stamp.timestamp()
    if not math.isfinite(x):
        raise PayloadError(f"'{value}' is not a time", "t", row)
    return x


def _check(columns: Columns, now_s: float | None) -> Columns:
    t = columns["t"]
    if len(t) == 0:
        raise PayloadError("the batch has no samples", "samples")
    early = np.flatnonzero(t < EARLIEST_T)
    if early.size:
        raise PayloadError(f"time {t[early[0]]:g} s is before 2000-01-01: the logger's clock "
                           "is not set (give UTC epoch seconds or ISO 8601)", "t",
                           int(early[0]) + 1)
    if now_s is not None:
        ahead = np.flatnonzero(t > now_s + LATEST_AHEAD_S)
        if ahead.size:
            raise PayloadError("time more than a day ahead of the twin's clock: check the "
                               "logger's clock and time zone", "t", int(ahead[0]) + 1)
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        r = int(back[0]) + 2
        raise PayloadError(f"time {t[r - 1]:.3f} does not follow row {r - 1}'s "
                           f"({t[r - 2]:.3f}): samples of a batch go in time order, each "
                           "once", "t", r)
    for col, values in columns.items():
        if col == "t":
            continue
        if col == "speed_kmh" and np.isnan(values).any():
            raise PayloadError("every sample needs a speed", col,
                               int(np.flatnonzero(np.isnan(values))[0]) + 1)
        if col in FLAGS:
            bad = np.flatnonzero(~np.isnan(values) & (values != 0) & (values != 1))
            if bad.size:
                raise PayloadError(f"{values[bad[0]]:g} is not a flag (0 or 1)", col,
                                   int(bad[0]) + 1)
            continue
        rng = RANGES[RANGE_OF[col]]
        low_bad = values <= rng.low if rng.open_low else values < rng.low
        bad = np.flatnonzero(~np.isnan(values) & (low_bad | (values > rng.high)))
        if bad.size:
            raise PayloadError(f"{values[bad[0]]:g} {rng.unit} is outside {rng.text()}: "
                               f"{rng.why}", col, int(bad[0]) + 1)
    return columns


def _known(field: str, row: int | None) -> None:
    if field != "t" and field not in SAMPLE_COLUMNS:
        from ebus_env.errors import did_you_mean

        raise PayloadError(f"unknown field{did_you_mean(field, ('t', *SAMPLE_COLUMNS))} "
                           f"Known: t, {', '.join(SAMPLE_COLUMNS)}", field, row)


def from_records(records: list, now_s: float | None = None) -> pd.DataFrame:
    """Samples as a list of ``{"t": ..., "speed_kmh": ..., ...}`` objects, checked."""
    return pd.DataFrame(records_columns(records, now_s))


def records_columns(records: list, now_s: float | None = None) -> Columns:
    """:func:`from_records` as :data:`Columns` (no DataFrame: the ingest's hot path)."""
    if not isinstance(records, list):
        raise PayloadError("give the samples as a list of objects", "samples")
    if len(records) > MAX_ROWS:
        raise PayloadError(f"{len(records)} samples in one batch; at most {MAX_ROWS}: split "
                           "the batch", "samples", status=413)
    columns: dict[str, list] = {"t": []}
    for i, rec in enumerate(records, start=1):
        if not isinstance(rec, dict):
            raise PayloadError("a sample is an object of fields", "samples", i)
        for key in rec:
            _known(key, i)
        columns["t"].append(parse_time(rec.get("t"), i))
        if "speed_kmh" not in rec:
            raise PayloadError("every sample needs a speed", "speed_kmh", i)
        for key, value in rec.items():
            if key != "t":
                columns.setdefault(key, [math.nan] * (i - 1)).append(_number(value, key, i))
        for values in columns.values():
            if len(values) < i:
                values.append(math.nan)
    return _check({k: np.asarray(v, float) for k, v in columns.items()}, now_s)


def csv_columns(text: str, now_s: float | None = None) -> Columns:
    """Samples as CSV lines with a header (``t,speed_kmh,soc_pct,...``), checked."""
    reader = csv.reader(io.StringIO(text))
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise PayloadError("the batch is empty: give a header line and samples") from None
    for h in header:
        _known(h, None)
    if "t" not in header or "speed_kmh" not in header:
        raise PayloadError("the header needs 't' and 'speed_kmh'",
                           "t" if "t" not in header else "speed_kmh")
    if len(set(header)) != len(header):
        raise PayloadError("a column is named twice in the header",
                           next(h for h in header if header.count(h) > 1))
    records = []
    for i, line in enumerate(reader, start=1):
        if not line:
            continue
        if len(line) != len(header):
            raise PayloadError(f"{len(line)} values for {len(header)} columns", None, i)
        records.append(dict(zip(header, line, strict=True)))
        if len(records) > MAX_ROWS:
            raise PayloadError(f"more than {MAX_ROWS} samples in one batch: split the batch",
                               "samples", status=413)
    return records_columns(records, now_s)


def json_columns(body: bytes | str | dict, now_s: float | None = None) -> tuple[Columns,
                                                                              str | None]:
    """``{"batch_id": ..., "samples": [...]}`` (or a bare list of samples): the checked
    samples and the logger's batch id (None when it gives none)."""
    if isinstance(body, (bytes, str)):
        try:
            body = json.loads(body)
        except (ValueError, UnicodeDecodeError) as exc:
            raise PayloadError(f"not JSON ({exc})") from None
    if isinstance(body, list):
        return records_columns(body, now_s), None
    if not isinstance(body, dict):
        raise PayloadError("give an object {\"batch_id\": ..., \"samples\": [...]}")
    extra = set(body) - {"batch_id", "samples"}
    if extra:
        raise PayloadError("unknown field; a batch has 'batch_id' and 'samples'",
                           sorted(extra)[0])
    batch_id = body.get("batch_id")
    if batch_id is not None and (not isinstance(batch_id, (str, int)) or
                                 not 0 < len(str(batch_id)) <= 128):
        raise PayloadError("a batch id is a string of 1 to 128 characters", "batch_id")
    return records_columns(body.get("samples"), now_s), \
        None if batch_id is None else str(batch_id)


def parse_body(body: bytes, content_type: str, now_s: float | None = None) -> tuple[
        Columns, str | None]:
    """A batch's body (``application/json`` or ``text/csv``), checked, and the batch id the
    JSON gives (None: none given)."""
    if content_type == "text/csv":
        return csv_columns(body.decode("utf-8", errors="replace"), now_s), None
    return json_columns(body, now_s)


def content_id(columns: Columns) -> str:
    """A batch id from the samples themselves: the same samples sent twice get the same id."""
    digest = hashlib.sha256(",".join(sorted(columns)).encode())
    for name in sorted(columns):
        digest.update(np.ascontiguousarray(columns[name], float).tobytes())
    return "sha256:" + digest.hexdigest()[:40]


def batch(samples: pd.DataFrame | Columns, batch_id: str | None) -> Batch:
    """A :class:`Batch` of checked samples (a DataFrame or :data:`Columns`)."""
    if isinstance(samples, pd.DataFrame):
        samples = {c: samples[c].to_numpy(float) for c in samples.columns}
    return Batch(samples, batch_id or content_id(samples))


def from_frame(frame: pd.DataFrame, now_s: float | None = None) -> pd.DataFrame:
    """A DataFrame of samples (``t`` as epoch seconds or date-times; the canonical columns),
    checked: the Python API's way in. A ``timestamp`` column stands for ``t``."""
    frame = frame.rename(columns={"timestamp": "t"}) if "t" not in frame.columns else frame
    if "t" not in frame.columns:
        raise PayloadError("the frame needs a time column 't' (or 'timestamp')", "t")
    if len(frame) > MAX_ROWS:
        out = pd.concat([from_frame(frame.iloc[i:i + MAX_ROWS], now_s)
                         for i in range(0, len(frame), MAX_ROWS)], ignore_index=True)
        back = np.flatnonzero(np.diff(out["t"].to_numpy(float)) <= 0)
        if back.size:
            raise PayloadError("time does not follow the row before it: samples go in time "
                               "order, each once", "t", int(back[0]) + 2)
        return out
    records = frame.to_dict("records")
    if pd.api.types.is_datetime64_any_dtype(frame["t"]):
        for rec in records:
            rec["t"] = rec["t"].isoformat()
    return from_records(records, now_s)


def from_log_file(path, name: str | None = None) -> pd.DataFrame:
    """A logger file (``.csv``, ``.csv.gz``, ``.parquet``; and every format
    :func:`ebus_env.io.measured.open_log` reads) as samples with UTC times. The file is read
    by the project's log reader (the same that ``ebus simulate --measured`` uses); its
    ``timestamp`` column gives the times (read as UTC where it has no offset)."""
    from ebus_env.io.measured import open_log

    _, _, table = open_log(path, None)
    if "timestamp" not in table.columns:
        raise PayloadError("a logger file for the twin needs date-times ('timestamp'): a "
                           "'time_s' log has no clock", "timestamp")
    frame = table.rename(columns={"timestamp": "t"})
    keep = ["t", *[c for c in SAMPLE_COLUMNS if c in frame.columns]]
    return from_frame(frame[keep])
