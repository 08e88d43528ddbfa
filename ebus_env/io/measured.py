"""Measured logs: read, check, and bring onto the simulation grid.

A log has one row per sample and canonical columns with units in their names:

=====================  ========  ====================================================
column                 required  meaning
=====================  ========  ====================================================
``time_s``             yes*      seconds (or ``timestamp``: date-time or seconds)
``speed_kmh``          yes*      vehicle speed (or ``speed_mps``)
``soc_pct``                      battery state of charge (or ``soc_frac``)
``ambient_degc``                 ambient temperature
``grade_pct``                    road grade in % (or ``grade_frac``)
``altitude_m``                   altitude; smoothed over distance into grade
``charging``                     1 while on a charger, else 0
``charger_kw``                   rated power of that charger
``passengers``                   passengers on board
``door_open``                    1 while doors are open
``battery_current_a``            pack current, > 0 discharging
``battery_voltage_v``            pack voltage
``cabin_temp_degc``              cabin air temperature (the model's cabin starts at the
                                 first value)
``logged_load_kw``               a load measured on the bus that the model does not
                                 compute (an HVAC or compressor submeter), > 0 drawing
                                 from the DC bus; the ``replayed_load`` effect replays it
=====================  ========  ====================================================

Files named otherwise are mapped with ``columns`` (``{"Velocity [km/h]": "speed_kmh"}`` or
``{"I [A]": {"column": "battery_current_a", "scale": -1}}``) or a preset in ``configs/logs``.
Other numeric columns are kept, resampled, as measured signals. A CAN logger file (``.mf4``,
``.blf``, ``.asc``) is decoded through a signal map (a DBC and which signal feeds which column,
:mod:`ebus_env.io.can_log`) into the same table, which then passes the same checks.

Two columns of one quantity (``time_s`` and ``timestamp``, ``speed_kmh`` and ``speed_mps``,
``soc_pct`` and ``soc_frac``, ``grade_pct`` and ``grade_frac``) are used only when they agree
within the rounding they are written to: then the finer is used (``timestamp`` always gives
the clock), else the log is refused. A grade column is used over ``altitude_m``.

Nothing is silently dropped or repaired: a problem raises :class:`~ebus_env.errors.LogError`
with the file, column, rows and the fix, and every change the loader makes (resampling,
smoothing, filling, splitting) is listed in :attr:`LoadReport.changes`.
"""

from __future__ import annotations

import datetime
import lzma
import re
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ebus_env import paths
from ebus_env.config import find_config, read_yaml
from ebus_env.errors import ConfigError, LogError, did_you_mean, format_rows
from ebus_env.grade import DEFAULT_WINDOW_M, grade_from_altitude
from ebus_env.inputs import MAX_STEPS, RANGES, check
from ebus_env.io.can_frames import SUFFIXES as CAN_SUFFIXES
from ebus_env.io.can_frames import is_can_file
from ebus_env.io.can_map import is_signal_map
from ebus_env.profile import Profile
from ebus_env.resample import grid, resample

CANONICAL = {
    "time_s", "timestamp", "speed_kmh", "speed_mps", "soc_pct", "soc_frac", "ambient_degc",
    "grade_pct", "grade_frac", "altitude_m", "charging", "charger_kw", "passengers", "door_open",
    "solar_w_per_m2", "battery_current_a", "battery_voltage_v", "cabin_temp_degc",
    "logged_load_kw",
}
FLAGS = ("charging", "door_open")
GAP_POLICIES = ("error", "split", "hold", "interpolate")
FILL_POLICIES = ("error", "interpolate")
SPREADSHEETS = (".xlsx", ".xlsm", ".xls", ".ods", ".numbers")
COMPRESSED = {".gz": "gzip", ".bz2": "bzip2", ".xz": "xz", ".zip": "zip", ".zst": "zstd"}
SAME_QUANTITY = (("speed_kmh", "speed_mps", 3.6, "speed"), ("soc_pct", "soc_frac", 100.0, "SoC"),
                 ("grade_pct", "grade_frac", 100.0, "grade"))
"""Column pairs that give one quantity (``first = factor * second``)."""


@dataclass
class LoadReport:
    """What the loader found and did."""

    path: str
    rows: int = 0
    sample_period_s: float = float("nan")
    columns: dict[str, str] = field(default_factory=dict)  # canonical <- source column
    changes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    ignored: list[str] = field(default_factory=list)
    frames: dict = field(default_factory=dict)  # a CAN logger file's frames by what became of
    # them, by signal (ebus_env.io.can_log.Counts.to_json); empty for a table


@dataclass
class MeasuredLog:
    """A loaded log: one profile per segment (several only when gaps were split)."""

    profiles: list[Profile]
    report: LoadReport

    @property
    def profile(self) -> Profile:
        if len(self.profiles) != 1:
            raise LogError(f"The log was split into {len(self.profiles)} segments at its gaps; "
                           "use .profiles", path=self.report.path)
        return self.profiles[0]


def column_preset(name: str | Path) -> dict:
    """Column map from a preset in ``configs/logs`` (by name or path)."""
    data = read_yaml(find_config(name, kind="logs"))
    if is_signal_map(data):
        raise ConfigError(f"The preset {name} is a CAN signal map (dbc:, signals:) for logger "
                          f"files ({', '.join(CAN_SUFFIXES)}), not a column map for a table. "
                          "Fix: give a preset with columns: (or none) for a CSV or Parquet log.")
    if "columns" not in data:
        raise ConfigError(f"Column preset {name} needs a 'columns' mapping.")
    return dict(data["columns"])


def _column_presets() -> list[str]:
    """The shipped presets that map a table's columns (not the CAN signal maps)."""
    return [name for name in paths.config_names("logs")
            if not is_signal_map(read_yaml(paths.configs("logs") / f"{name}.yaml"))]


COLUMN_RANGES = {
    "soc_pct": "log_soc_pct", "ambient_degc": "ambient_degc", "logged_load_kw": "log_load_kw",
    "grade_pct": "log_grade_pct", "altitude_m": "log_altitude_m",
    "passengers": "log_passengers", "charger_kw": "log_charger_kw",
    "solar_w_per_m2": "log_solar_w_per_m2", "battery_current_a": "log_current_a",
    "battery_voltage_v": "log_voltage_v", "cabin_temp_degc": "log_cabin_temp_degc",
}
"""The canonical columns checked against a declared range (``ebus_env.inputs.RANGES``)."""


def _exists(path: Path) -> None:
    if not path.exists():
        raise LogError("The file does not exist", path=path, fix="check the path")
    if path.stat().st_size == 0:
        raise LogError("The file is empty", path=path, fix="give a log with a header and rows")


def _read(path: Path, columns=None, report: LoadReport | None = None) -> pd.DataFrame:
    """The file as a table: CSV or Parquet as written; a CAN logger file (``.mf4``, ``.blf``,
    ``.asc``) decoded through the signal map ``columns`` (:mod:`ebus_env.io.can_log`), its
    counts added to ``report``."""
    _exists(path)
    if is_can_file(path):
        from ebus_env.io.can_log import read_can_log

        return read_can_log(path, columns, report if report is not None else LoadReport(
            str(path)))
    if path.suffix.lower() in SPREADSHEETS:
        raise LogError(f"The file is a spreadsheet workbook ({path.suffix}), not a table the "
                       "loader reads", path=path, fix="save the sheet as CSV (or Parquet)")
    header = []
    try:
        if path.suffix.lower() in (".parquet", ".pq"):
            frame = pd.read_parquet(path)
        else:
            sep = ","
            frame = pd.read_csv(path, dtype=str, keep_default_na=False,
                                encoding_errors="replace")
            if frame.shape[1] == 1 and ";" in frame.columns[0]:
                sep = ";"
                frame = pd.read_csv(path, sep=sep, dtype=str, keep_default_na=False,
                                    encoding_errors="replace")
            # pandas renames a repeated name ('speed_kmh.1'): which one is meant is the
            # user's call, not the loader's
            header = pd.read_csv(path, sep=sep, header=None, nrows=1, dtype=str,
                                 keep_default_na=False, encoding_errors="replace").iloc[0].tolist()
    except (EOFError, OSError, ValueError, zlib.error, lzma.LZMAError,
            zipfile.BadZipFile) as exc:
        kind = COMPRESSED.get(path.suffix.lower())
        if kind and not isinstance(exc, ValueError):  # ValueError: the table, not the archive
            raise LogError(f"The file is truncated or not a valid {kind} file ({exc})",
                           path=path, fix="copy or download it again, or give it "
                                          "uncompressed") from None
        raise LogError(f"The file cannot be read as a table: {exc}", path=path,
                       fix="give a CSV (comma or semicolon separated) or Parquet file") from None
    _refuse_repeated(header, path)
    if frame.empty:
        raise LogError("The file has a header but no rows", path=path, fix="give a log with data")
    return frame


def _refuse_repeated(names: list[str], path: Path) -> None:
    """A column name the header holds twice fails, naming where."""
    for name in dict.fromkeys(names):
        where = [i + 1 for i, n in enumerate(names) if n == name]
        if len(where) > 1:
            raise LogError(f"The column name appears {len(where)} times (columns "
                           f"{', '.join(map(str, where))})", path=path, column=name,
                           fix="keep one of them, or rename the others")


def open_log(path: str | Path, columns: dict | str | Path | None) -> tuple[
        Path, LoadReport, pd.DataFrame]:
    """Read a log file and map its columns (a mapping or a preset's name; for a CAN logger
    file, a signal map); returns the path, the report of what was done and the table with
    canonical column names."""
    if not isinstance(path, (str, Path)):
        table = isinstance(path, pd.DataFrame)
        raise ConfigError(f"A log is read from its file (CSV or Parquet), not from a "
                          f"{type(path).__name__}. Fix: give its path" + (
                              ", or write the table first: frame.to_csv(path, index=False)"
                              if table else "") + ".")
    path = paths.here_or_shipped(path)
    report = LoadReport(str(path))
    if is_can_file(path):  # decoded to canonical names by its signal map
        frame = _read(path, columns, report)
    else:
        if isinstance(columns, (str, Path)):
            columns = column_preset(columns)
        frame = _apply_columns(_read(path), columns, path, report)
    report.rows = len(frame)
    if len(frame) < 2:
        raise LogError("The log needs at least two rows", path=path)
    return path, report, frame


def _apply_columns(frame: pd.DataFrame, columns: dict | None, path: Path,
                   report: LoadReport) -> pd.DataFrame:
    renamed = {}
    for source, target in (columns or {}).items():
        scale = 1.0
        if isinstance(target, dict):
            scale = float(target.get("scale", 1.0))
            target = target["column"]
        if source not in frame.columns:
            raise LogError(f"The column map names '{source}', which the file lacks."
                           f"{did_you_mean(source, frame.columns)}", path=path,
                           fix=f"columns present: {', '.join(map(str, frame.columns))}")
        values = frame[source]
        if scale != 1.0:
            values = pd.to_numeric(values.replace("", np.nan), errors="coerce") * scale
            report.changes.append(f"column '{source}' multiplied by {scale:g} as '{target}'")
        renamed[target] = values
        report.columns[target] = source
    out = frame.drop(columns=[c for c in (columns or {}) if c in frame.columns])
    for target, values in renamed.items():
        if target in out.columns:
            raise LogError(f"Column '{target}' exists and the column map also maps to it",
                           path=path, column=target, fix="map only one column onto it")
        out[target] = values
    for name in out.columns:
        report.columns.setdefault(name, name)
    return out


def _close_column(wanted: str, columns) -> str:
    """`` The file has 'x': is that it?`` for the column most like ``wanted``, or ``""``."""
    import difflib

    match = difflib.get_close_matches(wanted, [str(c) for c in columns], n=1, cutoff=0.6)
    return f" The file has '{match[0]}': is that it?" if match else ""


def _numeric(frame: pd.DataFrame, name: str, path: Path) -> np.ndarray:
    """A column as floats; text that is not a number is an error (empty cells become NaN)."""
    raw = frame[name]
    if raw.dtype.kind in "fiub":
        return raw.to_numpy(dtype=float)
    text = raw.astype(str).str.strip()
    empty = text.isin(["", "nan", "NaN", "NA", "null", "None"])
    values = pd.to_numeric(text.where(~empty), errors="coerce")
    bad = np.flatnonzero(values.isna().to_numpy() & ~empty.to_numpy())
    if bad.size:
        examples = ", ".join(repr(text.iloc[i]) for i in bad[:3])
        raise LogError(f"Non-numeric values ({examples})", path=path, column=name, rows=bad,
                       fix="clean those cells, or leave them empty to mark missing values")
    return values.to_numpy(dtype=float)


def _nan_runs(values: np.ndarray) -> list[tuple[int, int]]:
    nan = np.isnan(values)
    if not nan.any():
        return []
    edges = np.diff(np.concatenate([[0], nan.astype(int), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1, strict=True))


def _time(frame: pd.DataFrame, path: Path, report: LoadReport,
          given_start_h: float | None = None) -> tuple[np.ndarray, float, datetime.date | None]:
    """Seconds from the first row, the time of day of the first row [h] and its date: the
    log's own clock (date-times in 'timestamp'), else ``given_start_h``, else 00:00 (with a
    note), and no date. 'time_s' and 'timestamp' together are used only when they agree."""
    if "time_s" not in frame.columns and "timestamp" not in frame.columns:
        raise LogError("No time column." + _close_column("time_s", frame.columns), path=path,
                       fix="name it 'time_s' (seconds) or 'timestamp', or map it with columns=")
    column, start_h, start_date = "time_s", None, None
    if "timestamp" in frame.columns:
        t, start_h, step, start_date = _timestamps(frame["timestamp"], path, report)
        column = "timestamp"
    if "time_s" in frame.columns:
        seconds = _seconds(frame, path)
        if column == "time_s":
            t = seconds
        else:
            seconds_step = _rounding(frame["time_s"])
            tol = step + seconds_step
            x, y = seconds - seconds[0], t - t[0]  # either may count from any origin
            off = np.flatnonzero(np.abs(x - y) > tol + 1e-9 * np.abs(y))
            if off.size:
                i = off[0]
                raise LogError(f"'time_s' and 'timestamp' disagree at {off.size} rows (row {i}: "
                               f"{x[i]:g} s and {y[i]:g} s after the first row)", path=path,
                               column="time_s", rows=off,
                               fix="keep one of them: drop or rename the other")
            if seconds_step < step:  # the finer of the two
                t, column = seconds, "time_s"
            clock = "" if start_h is None else \
                f", the clock (first row at {_hms(start_h)}) from 'timestamp'"
            report.changes.append(f"'time_s' and 'timestamp' agree (within {tol:g} s): elapsed "
                                  f"time from '{column}'{clock}")
    if start_h is not None and given_start_h is not None:
        raise LogError(f"The log has date-times (its first row at {_hms(start_h)}), "
                       "and a start time was given too", path=path,
                       column="timestamp", fix="leave out the start time (--start-time)")
    if start_h is None and given_start_h is not None:
        start_h = given_start_h
    elif start_h is None:
        start_h = 0.0
        report.changes.append("the log has no clock time: its first row is taken as 00:00 "
                              "(the time of day of passengers, chargers and diagnoses); give its "
                              "start time (--start-time 07:30) or a 'timestamp' column of "
                              "date-times")
    step = np.diff(t)
    duplicated = np.flatnonzero(step == 0) + 1
    if duplicated.size:
        raise LogError("Duplicated times", path=path, column=column, rows=duplicated,
                       fix="remove or average the duplicated rows")
    backwards = np.flatnonzero(step < 0) + 1
    if backwards.size:
        raise LogError("Time goes backwards", path=path, column=column, rows=backwards,
                       fix="sort the log by time, or split it into files at the jumps")
    return t - t[0], start_h, start_date


def _hms(hours: float) -> str:
    s = int(round(hours * 3600))
    return f"{s // 3600:02d}:{s // 60 % 60:02d}:{s % 60:02d}"


def _seconds(frame: pd.DataFrame, path: Path) -> np.ndarray:
    """'time_s' as floats: every row has one, and date-times there are named as such."""
    try:
        t = _numeric(frame, "time_s", path)
    except LogError as exc:
        example = str(frame["time_s"].iloc[exc.rows[0]]).strip()
        if pd.notna(pd.to_datetime(example, errors="coerce")):
            raise LogError(f"'time_s' holds date-times (e.g. '{example}'), not seconds",
                           path=path, column="time_s",
                           fix="rename the column 'timestamp'") from None
        raise
    nan = np.flatnonzero(np.isnan(t))
    if nan.size:
        raise LogError("Missing times", path=path, column="time_s", rows=nan,
                       fix="every row needs a time")
    return t


def _timestamps(column: pd.Series, path: Path, report: LoadReport) -> tuple[
        np.ndarray, float | None, float, datetime.date | None]:
    """Seconds from 'timestamp' (date-times or seconds), the first row's time of day [h]
    (None for seconds), the step the times are written to and the first row's local date
    (None for seconds). Date-times with UTC offsets
    count in UTC, so a daylight-saving switch is no jump; the clock starts at the first
    row's local time."""
    text = column.astype(str).str.strip()
    numeric = pd.to_numeric(text, errors="coerce")
    if numeric.notna().all():
        return numeric.to_numpy(float), None, _rounding(column), None
    offset = text.str.extract(r":\d\d(?:\.\d+)?\s*(Z|[+-]\d\d(?::?\d\d)?)$")[0]
    if offset.notna().any() and offset.isna().any():
        raise LogError("Some date-times have a UTC offset and some not", path=path,
                       column="timestamp", rows=np.flatnonzero(offset.isna().to_numpy()),
                       fix="give every date-time its offset (+01:00), or none")
    # '04/05/2026' is read day- or month-first as its first row suggests
    ambiguous = re.match(r"\d{1,2}[./-]\d{1,2}[./-]\d{2,4}\b", text.iloc[0]) is not None
    iso = "write date-times as ISO 8601, year first (2026-05-04 07:30:00)"
    stamps = pd.to_datetime(text, errors="coerce", utc=True)
    bad = np.flatnonzero(stamps.isna().to_numpy())
    if bad.size:
        raise LogError("Timestamps that cannot be read", path=path, column="timestamp",
                       rows=bad, fix=(f"dates such as '{text.iloc[0]}' can be day- or "
                                      f"month-first: {iso}" if ambiguous else
                                      "use ISO 8601 date-times or seconds"))
    t = (stamps - stamps.iloc[0]).dt.total_seconds().to_numpy(float)
    jump = np.flatnonzero(np.diff(t) > 25 * 86400.0)  # longer than any run: no real gap
    if ambiguous and jump.size:
        i = jump[0]
        raise LogError(f"The date-times jump by {(t[i + 1] - t[i]) / 86400:.1f} days from "
                       f"'{text.iloc[i]}' to '{text.iloc[i + 1]}': are the dates day-first "
                       "and read month-first (or the reverse)?", path=path, column="timestamp",
                       rows=[i + 1], fix=iso)
    first = pd.to_datetime(text.iloc[:1]).iloc[0]  # with its own offset: the local clock
    start_h = first.hour + first.minute / 60 + first.second / 3600
    if offset.notna().all():
        change = np.flatnonzero(offset.to_numpy()[1:] != offset.to_numpy()[:-1]) + 1
        if change.size:
            report.changes.append(
                f"the UTC offset changes within the log ({offset.iloc[change[0] - 1]} to "
                f"{offset.iloc[change[0]]} at row {change[0]}"
                f"{f', and {change.size - 1} more' if change.size > 1 else ''}): time counted "
                f"in UTC; the time of day runs on from the first row's clock "
                f"(UTC{offset.iloc[0]}), not the logged local time after the change")
    within = (stamps - stamps.dt.floor("s")).dt.total_seconds().to_numpy()
    step = 1.0 if not within.any() else (
        1e-3 if np.allclose(within * 1e3, np.round(within * 1e3)) else 1e-6)
    return t, start_h, step, first.date()


def _rounding(column: pd.Series) -> float:
    """The step a column of numbers is written to (0.1 for '12.3', 1e-05 for '1e-05'): its
    finest cell's; inf when it holds no numbers."""
    parts = column.astype(str).str.strip().str.extract(
        r"^([-+]?(?=\.?\d)\d*(?:\.(\d*))?(?:[eE]([-+]?\d+))?)$")
    written = parts[0].notna().to_numpy()
    if not written.any():
        return float("inf")
    decimals = parts[1].fillna("").str.len().to_numpy()
    exponent = parts[2].fillna("0").astype(int).to_numpy()
    return float(np.min(10.0 ** (exponent - decimals)[written]))


def _check_period(t: np.ndarray, dt_s: float, path: Path, report: LoadReport) -> float:
    """The median sample period, in the loader's range (0.5-20 Hz; faster is averaged with a
    warning), and a duration that fits in one run. Time in milliseconds is named as such."""
    period = float(np.median(np.diff(t)))
    rng = RANGES["log_period_s"]
    if 50.0 <= period <= 2000.0 and t[-1] > 48 * 3600.0:  # 0.5-20 Hz in ms, "days" long
        raise LogError(f"Times look like milliseconds (median step {period:g}, a log of "
                       f"{t[-1] / 86400:.1f} days if they were seconds)", path=path,
                       column="time_s", fix="divide the times by 1000 (time_s holds seconds)")
    try:
        report.warnings += rng.check(period, "the median sample period")
    except ConfigError as exc:
        raise LogError(str(exc), path=path, column="time_s",
                       fix="give a log sampled at 0.5-20 Hz") from None
    if t[-1] < dt_s:
        raise LogError(f"The log lasts {t[-1]:g} s, less than one time step of {dt_s:g} s",
                       path=path, column="time_s", fix="give a longer log")
    if t[-1] / dt_s > MAX_STEPS:
        raise LogError(f"The log lasts {t[-1] / 3600:.1f} h: {t[-1] / dt_s:,.0f} steps of "
                       f"{dt_s:g} s, more than one run holds ({MAX_STEPS:,})", path=path,
                       column="time_s", fix="split it into days, or check the time unit")
    return period


def _unknown_columns(values: dict, mapped: bool, report: LoadReport) -> None:
    """Say which columns the model does not read, and which shipped preset would map them."""
    unknown = [c for c in values if c not in CANONICAL]
    if not unknown:
        return
    report.changes.append("kept as measured signals, not read by the model: "
                          + ", ".join(f"'{c}'" for c in unknown))
    if mapped:
        return
    for preset in _column_presets():
        matched = [c for c in column_preset(preset) if c in unknown]
        if matched:
            report.warnings.append(
                f"the column preset '{preset}' maps {', '.join(repr(c) for c in matched)} "
                f"of this log onto the model's inputs: pass --columns {preset} "
                f"(columns='{preset}')")


def _fill_nan(name: str, values: np.ndarray, t: np.ndarray, path: Path, fill: str,
              report: LoadReport, flag: bool = False) -> np.ndarray:
    runs = _nan_runs(values)
    if not runs:
        return values
    rows = [r for a, b in runs for r in range(a, b + 1)]
    if np.isnan(values).all():
        raise LogError("The column has no values", path=path, column=name,
                       fix="drop the column or fill it")
    if fill == "error":
        raise LogError(f"Missing values in {len(runs)} run(s)", path=path, column=name, rows=rows,
                       fix="fill them, or pass fill='interpolate' (--fill interpolate) to "
                           "interpolate (hold for flags)")
    ok = ~np.isnan(values)
    if flag:
        filled = resample(t[ok], values[ok], t, 1.0, "hold")
    else:
        filled = np.interp(t, t[ok], values[ok])
    report.changes.append(f"'{name}': {len(rows)} missing values in {len(runs)} run(s) "
                          f"(rows {format_rows(rows)}) filled by "
                          f"{'holding' if flag else 'linear interpolation'}")
    return filled


def _check_units(frame_values: dict, t: np.ndarray, path: Path, check: bool) -> None:
    speed = frame_values.get("speed_kmh")
    if check and speed is not None and t[-1] > 120:
        moving = speed > 1.0
        if moving.sum() > 10 and np.nanmax(speed) < 25.0:
            step_s = np.diff(t)
            apart = step_s > 0  # repeated times are the time check's to name, not this one's
            accel = np.diff(speed / 3.6)[apart] / step_s[apart]
            speeding_up = accel[accel > 0]  # none at a steady speed: nothing to judge by
            if speeding_up.size and np.nanpercentile(speeding_up, 95) < 0.35:
                raise LogError(
                    f"Speeds look like m/s, not km/h (max {np.nanmax(speed):.1f}, accelerations "
                    "implausibly small for km/h)", path=path, column="speed_kmh",
                    fix="rename the column 'speed_mps' if it holds m/s (or pass "
                        "check_units=False / --no-unit-check if these really are km/h)")
    soc = frame_values.get("soc_pct")
    if check and soc is not None and np.nanmax(soc) <= 1.0:
        raise LogError(f"SoC looks like a fraction, not percent (max {np.nanmax(soc):g})",
                       path=path, column="soc_pct",
                       fix="rename the column 'soc_frac' if it holds 0-1 values")


def _check_range(name: str, values: np.ndarray, low: float, high: float, path: Path,
                 fix: str, open_low: bool = False, scale: float = 1.0) -> None:
    """Rows outside [low, high] (``open_low``: (low, high]) fail; ``scale`` takes the values
    and bounds back to the column's own unit for the message."""
    bad = np.flatnonzero((values < low) | (values > high) | ((values == low) & open_low))
    if bad.size:
        raise LogError(f"Values outside {'(' if open_low else '['}{low * scale:g}, "
                       f"{high * scale:g}] (e.g. {values[bad[0]] * scale:g})",
                       path=path, column=name, rows=bad, fix=fix)


def _check_values(frame: pd.DataFrame, values: dict[str, np.ndarray], t: np.ndarray,
                  path: Path, report: LoadReport, fill: str, check_units: bool) -> None:
    """Check the numeric columns in ``values`` (and fill them as ``fill`` says), in place:
    one column per quantity, flags 0/1, missing values, units and ranges."""
    _one_per_quantity(frame, values, path, report)
    for flag in FLAGS:
        if flag in values:
            v = values[flag]
            bad = np.flatnonzero(~np.isnan(v) & ~np.isin(v, (0.0, 1.0)))
            if bad.size:
                raise LogError("Flag values other than 0 and 1", path=path, column=flag,
                               rows=bad, fix="use 1 for yes and 0 for no")
    for name_ in list(values):
        if np.isnan(values[name_]).all() and name_ not in CANONICAL:
            report.ignored.append(f"column '{name_}' is empty and was not used")
            del values[name_]
            continue
        values[name_] = _fill_nan(name_, values[name_], t, path, fill, report,
                                  flag=name_ in FLAGS + ("passengers", "charger_kw"))
    _check_units(values, t, path, check_units)
    speed = RANGES["log_speed_kmh"]
    for column, factor in (("speed_kmh", 1.0), ("speed_mps", 3.6)):
        if column in values:
            _check_range(column, factor * values[column], speed.low, speed.high, path,
                         speed.why, scale=1 / factor)
    if "soc_frac" in values:
        _check_range("soc_frac", values["soc_frac"], 0.0, 1.0, path, "SoC as a fraction: 0-1")
    if "grade_frac" in values:
        grade = RANGES["log_grade_pct"]
        _check_range("grade_frac", 100.0 * values["grade_frac"], grade.low, grade.high, path,
                     grade.why, scale=0.01)
    for column, range_name in COLUMN_RANGES.items():
        if column in values:
            r = RANGES[range_name]
            _check_range(column, values[column], r.low, r.high, path, r.why, r.open_low)


def _one_per_quantity(frame: pd.DataFrame, values: dict[str, np.ndarray], path: Path,
                      report: LoadReport) -> None:
    """Two columns of one quantity (``SAME_QUANTITY``) are refused unless they agree within
    the rounding they are written to; then the finer is used, with a note. Grade is used
    over altitude (grade from altitude is noisier), with a note."""
    for first, second, factor, what in SAME_QUANTITY:
        if first not in values or second not in values:
            continue
        x, y = values[first], factor * values[second]
        both = ~np.isnan(x) & ~np.isnan(y)
        step_first, step_second = _rounding(frame[first]), factor * _rounding(frame[second])
        off = np.flatnonzero(both & (np.abs(x - y) > step_first + step_second
                                     + 1e-9 * np.abs(x)))
        keep = "keep one of them: drop or rename the other (or map only one with columns=)"
        if not both.any():
            raise LogError(f"'{first}' and '{second}' both give the {what}, and no row has "
                           "both to compare", path=path, column=second, fix=keep)
        if off.size:
            i = off[0]
            raise LogError(f"'{first}' and '{second}' both give the {what}, and disagree at "
                           f"{off.size} rows (row {i}: {first} {x[i]:g}, {second} "
                           f"{values[second][i]:g} x {factor:g} = {y[i]:g})", path=path,
                           column=second, rows=off, fix=keep)
        used, dropped = (second, first) if step_second < step_first else (first, second)
        del values[dropped]
        report.changes.append(f"'{first}' and '{second}' agree within their rounding: "
                              f"'{used}' used, '{dropped}' not")
    grade = [c for c in ("grade_pct", "grade_frac") if c in values]
    if grade and "altitude_m" in values:
        report.changes.append(f"grade from '{grade[0]}', not from 'altitude_m' (noisier); "
                              "altitude kept as a measured signal")


def load_log(path: str | Path, dt_s: float = 0.1, columns: dict | str | None = None,
             gaps: str = "error", max_gap_s: float | None = None, fill: str = "error",
             check_units: bool = True, grade_window_m: float = DEFAULT_WINDOW_M,
             max_speed_kmh: float | None = None, max_accel_mps2: float | None = None,
             name: str | None = None, start_h: float | None = None) -> MeasuredLog:
    """Read a measured log and bring it onto the simulation grid.

    Parameters
    ----------
    path
        CSV (comma or semicolon separated) or Parquet file, or a CAN logger file (``.mf4``,
        ``.blf``, ``.asc``) decoded through the signal map ``columns``
        (:mod:`ebus_env.io.can_log`; needs the ``can`` extra).
    dt_s
        Simulation time step [s]; 0.5-20 Hz logs are up- or down-sampled to it.
    columns
        Column map ``{source: canonical}`` or the name/path of a preset in ``configs/logs``;
        for a CAN logger file a signal map (a preset with ``dbc:`` and ``signals:``, e.g.
        ``ebus_j1939``, or such a mapping; :mod:`ebus_env.io.can_map`).
    gaps
        What to do with time gaps longer than ``max_gap_s``: ``error`` (default), ``split``
        (separate segments, each simulated from its own measured SoC), ``hold`` (hold the last
        sample before each gap across it) or ``interpolate``.
    max_gap_s
        Longest step that is not a gap (default: the larger of 10 s and 5 sample periods).
    fill
        Missing values (NaN runs): ``error`` (default) or ``interpolate``.
    check_units
        Reject columns whose values look like the wrong unit (m/s as km/h, SoC 0-1 as %).
    grade_window_m
        Smoothing window when grade comes from altitude [m].
    max_speed_kmh, max_accel_mps2
        Vehicle limits; samples beyond them are reported (the model cannot follow them).
    start_h
        Time of day of the first row [h] of a log without date-times (``time_s`` or seconds);
        without it such a log starts at 00:00, which misplaces time-of-day effects.
    """
    if gaps not in GAP_POLICIES:
        raise ConfigError(f"gaps must be one of {GAP_POLICIES}, got '{gaps}'.")
    if fill not in FILL_POLICIES:
        raise ConfigError(f"fill must be one of {FILL_POLICIES}, got '{fill}'.")
    path, report, frame = open_log(path, columns)
    if start_h is not None:
        check("log_start_h", start_h)
    t, start_h, start_date = _time(frame, path, report, start_h)

    if "speed_kmh" not in frame.columns and "speed_mps" not in frame.columns:
        raise LogError("No speed column." + _close_column("speed_kmh", frame.columns), path=path,
                       fix="name it 'speed_kmh' or 'speed_mps', or map it with columns=")
    values: dict[str, np.ndarray] = {}
    for name_ in frame.columns:
        if name_ in ("time_s", "timestamp"):
            continue
        if name_ in CANONICAL:
            values[name_] = _numeric(frame, name_, path)
        else:
            try:
                values[name_] = _numeric(frame, name_, path)
            except LogError:
                report.ignored.append(f"column '{name_}' is not numeric and was not used")
    _unknown_columns(values, columns is not None, report)
    _check_values(frame, values, t, path, report, fill, check_units)
    speed_col = "speed_kmh" if "speed_kmh" in values else "speed_mps"
    speed_mps = values[speed_col] / 3.6 if speed_col == "speed_kmh" else values[speed_col]
    if "soc_pct" not in values and "soc_frac" not in values:
        report.warnings.append("the log has no SoC column (soc_pct or soc_frac): nothing to "
                               "compare, and a simulation starts at the given or default SoC")

    period = _check_period(t, dt_s, path, report)
    report.sample_period_s = period
    limit = max(10.0, 5.0 * period) if max_gap_s is None else max_gap_s
    gap_rows = np.flatnonzero(np.diff(t) > limit)
    segments = [(0, len(t))]
    if gap_rows.size:
        listing = ", ".join(f"{t[i]:.1f}-{t[i + 1]:.1f} s" for i in gap_rows[:5])
        if gaps == "error":
            raise LogError(f"{gap_rows.size} time gap(s) longer than {limit:g} s ({listing})",
                           path=path, column="time_s", rows=gap_rows + 1,
                           fix="choose how to simulate them: gaps='split', 'hold' or "
                               "'interpolate' (--gaps ...), or a larger max_gap_s")
        if gaps == "split":
            edges = [0] + list(gap_rows + 1) + [len(t)]
            segments = list(zip(edges[:-1], edges[1:], strict=True))
            report.changes.append(f"split at {gap_rows.size} gap(s) ({listing}) into "
                                  f"{len(segments)} segments")
        else:
            how = "holding the last sample" if gaps == "hold" else "linear interpolation"
            report.changes.append(f"{gap_rows.size} gap(s) ({listing}) bridged by {how}")

    if len(segments) > 1:  # a segment of one sample has no time step to simulate
        short = [i for i, (a, b) in enumerate(segments)
                 if b - a < 2 or len(grid(t[a], t[b - 1], dt_s)) < 2]
        if short:
            raise LogError(f"Segments {short} (between gaps) are too short to simulate",
                           path=path, column="time_s", rows=[segments[i][0] + 1 for i in short],
                           fix="use gaps='hold' or 'interpolate' instead of 'split'")
    profiles = [_segment_profile(values, speed_col, speed_mps, t, a, b, dt_s, start_h,
                                 start_date, gaps, limit, grade_window_m, report, path, name)
                for a, b in segments]
    _check_limits(profiles, max_speed_kmh, max_accel_mps2, report)
    for p in profiles:
        p.notes = list(report.changes)
    return MeasuredLog(profiles, report)


def _segment_profile(values, speed_col, speed_mps, t, a, b, dt_s, start_h, start_date, gaps,
                     limit, grade_window_m, report, path, name) -> Profile:
    ts = t[a:b]
    g = grid(ts[0], ts[-1], dt_s)
    period = float(np.median(np.diff(ts))) if b - a > 1 else dt_s
    kind = "mean" if period < dt_s * 0.999 else "linear"
    if a == 0 and abs(period - dt_s) > 1e-9:
        how = "window means" if kind == "mean" else "linear interpolation"
        report.changes.append(f"resampled from {period:g} s to {dt_s:g} s ({how})")
    # gaps='hold': grid times inside a gap keep the sample before it; elsewhere as any log
    last = np.clip(np.searchsorted(ts, g + 1e-9, side="right") - 1, 0, len(ts) - 1)
    in_gap = np.append(np.diff(ts), 0.0)[last] > limit if gaps == "hold" else None

    def rs(data, flag=False, sliced=False):
        data = data if sliced else data[a:b]
        out = resample(ts, data, g, dt_s, "hold" if flag else kind)
        if in_gap is not None:
            out[in_gap] = data[last[in_gap]]
        return out

    channels = {"speed_ref_mps": np.maximum(rs(speed_mps), 0.0)}
    if "grade_frac" in values:
        channels["grade_frac"] = rs(values["grade_frac"])
    elif "grade_pct" in values:
        channels["grade_frac"] = rs(values["grade_pct"] / 100.0)
    elif "altitude_m" in values:
        dist = np.concatenate([[0.0], np.cumsum(0.5 * (speed_mps[a + 1:b] + speed_mps[a:b - 1])
                                                * np.diff(ts))])
        grade, clipped = grade_from_altitude(dist, values["altitude_m"][a:b], grade_window_m)
        channels["grade_frac"] = rs(grade, sliced=True)
        if a == 0:
            report.changes.append(f"grade from 'altitude_m', smoothed over {grade_window_m:g} m "
                                  f"of distance" + (f"; {clipped} samples clipped at +-15 %"
                                                    if clipped else ""))
    if "ambient_degc" in values:
        channels["ambient_degc"] = rs(values["ambient_degc"])
    if "passengers" in values:
        channels["passenger_count"] = rs(values["passengers"], flag=True)
    if "charging" in values:
        channels["charger_connected"] = rs(values["charging"], flag=True)
    if "charger_kw" in values:
        channels["charger_rating_w"] = rs(values["charger_kw"] * 1e3, flag=True)
    if "door_open" in values:
        channels["door_open"] = rs(values["door_open"], flag=True)
    if "solar_w_per_m2" in values:
        channels["solar_w_per_m2"] = rs(values["solar_w_per_m2"])
    if "logged_load_kw" in values:
        channels["logged_load_w"] = rs(values["logged_load_kw"] * 1e3)
    measured, samples = {}, {}
    soc = values["soc_pct"][a:b] / 100.0 if "soc_pct" in values else (
        values["soc_frac"][a:b] if "soc_frac" in values else None)
    if soc is not None:
        measured["soc_frac"] = resample(ts, soc, g, dt_s, "linear")
        # compare only where the log has a sample: the grid row nearest each sample time
        rows = np.unique(np.clip(np.rint((ts - g[0]) / dt_s).astype(np.int64), 0, len(g) - 1))
        samples["soc_frac"] = rows
    used = {speed_col, "grade_frac", "grade_pct", "ambient_degc", "passengers", "charging",
            "charger_kw", "door_open", "solar_w_per_m2", "soc_pct", "soc_frac", "logged_load_kw"}
    for name_, data in values.items():
        if name_ not in used:
            measured[name_] = rs(data)
    label = name or Path(path).stem
    segment_start_h = (start_h + ts[0] / 3600.0) % 24.0
    date = None if start_date is None else \
        start_date + datetime.timedelta(days=int((start_h + ts[0] / 3600.0) // 24.0))
    return Profile(channels, dt_s, label, segment_start_h, measured, samples=samples,
                   start_s=float(ts[0]), date=date)


def _check_limits(profiles, max_speed_kmh, max_accel_mps2, report) -> None:
    for p in profiles:
        v = p.channels["speed_ref_mps"]
        if max_speed_kmh is not None:
            over = np.flatnonzero(v * 3.6 > max_speed_kmh + 1e-9)
            if over.size:
                report.warnings.append(
                    f"{over.size} samples ({over.size * p.dt_s:.0f} s) above the vehicle's top "
                    f"speed {max_speed_kmh:g} km/h (max {3.6 * v.max():.1f} km/h): the model "
                    "drives at its top speed there and falls behind")
        if max_accel_mps2 is not None:
            a = np.abs(np.diff(v)) / p.dt_s
            over = np.flatnonzero(a > max_accel_mps2)
            if over.size:
                report.warnings.append(
                    f"{over.size} steps with |acceleration| above {max_accel_mps2:g} m/s^2 "
                    f"(max {a.max():.2f} m/s^2): the model cannot follow them exactly")
