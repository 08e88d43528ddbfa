"""Signal maps: how a CAN logger's frames become the canonical log's columns.

A signal map is a preset in ``configs/logs`` (or a file or mapping of the same keys) that
names a DBC and maps its signals onto canonical columns::

    dbc: data/can/ebus_j1939.dbc     # beside the preset, a path, or a shipped file
    rate_hz: 1                       # rows of the canonical log per second
    timezone: Europe/Berlin          # the logger's clock where the file has no UTC offset
    signals:
      speed_kmh: {signal: CCVS1.WheelBasedVehicleSpeed, sample: mean, required: true}
      soc_pct: {signal: BMS2.PackSoC, sample: last, required: true}
      battery_current_a: {signal: BMS1.PackCurrent, sample: mean}
      charging: {signal: CHG1.ChargerState, values: {0: 0, 1: 1, 2: 1, 3: 1}, default: 0}

Each entry of ``signals`` (one per column) takes:

``signal``
    ``Message.Signal`` of the DBC (or the signal's name alone where only one message has it).
``sample``
    How a row of the canonical log, covering ``[t, t + 1/rate_hz)``, is made from the frames
    in it: ``mean`` (of the values in the row; for speed, current, voltage: what a BMS
    integrates), ``last`` (the last value in the row, else the last before it, held for at most
    ``hold_s``), ``max`` or ``min`` (of the values in the row). Default: ``mean`` for the
    columns in :data:`MEAN_COLUMNS`, ``last`` for the rest.
``required``
    A file without a valid value of this signal is refused (default false).
``unit``
    The signal's unit where the DBC gives none or a wrong one (see :data:`CONVERSIONS`); the
    value is converted to the column's unit (``m/s`` to ``km/h`` x 3.6, ``K`` to ``degC``).
``scale``, ``offset``
    After the unit conversion: ``column = offset + scale * value`` (``scale: -1`` for a pack
    current counted positive while charging).
``values``
    Raw value to column value, for states (``{0: 0, 1: 1, 2: 1, 3: 1}``); a raw value not
    listed counts as out of range.
``default``
    The column's value where the signal has none (no frame yet, or none for longer than
    ``hold_s``), e.g. 0 for ``charging`` where the charge unit only talks when a charger is
    connected. Each row so filled is counted in the loader's report.
``hold_s``
    How long ``last`` holds a value (default: 5 cycle times of its message, at least 5 s).
"""

from __future__ import annotations

import datetime
import zoneinfo
from dataclasses import dataclass
from pathlib import Path

from ebus_env import paths
from ebus_env.errors import ConfigError, did_you_mean

SAMPLING = ("mean", "last", "max", "min")
MEAN_COLUMNS = ("speed_kmh", "speed_mps", "battery_current_a", "battery_voltage_v",
                "logged_load_kw")
ENTRY_KEYS = ("signal", "sample", "required", "unit", "scale", "offset", "values", "default",
              "hold_s")
MAP_KEYS = ("dbc", "rate_hz", "timezone", "signals")
COLUMN_UNITS = {
    "speed_kmh": "km/h", "speed_mps": "m/s", "soc_pct": "%", "soc_frac": "",
    "battery_current_a": "A", "battery_voltage_v": "V", "ambient_degc": "degC",
    "cabin_temp_degc": "degC", "charger_kw": "kW", "logged_load_kw": "kW", "altitude_m": "m",
    "grade_pct": "%", "grade_frac": "", "solar_w_per_m2": "W/m^2",
}
"""The unit of each canonical column with one ("" for fractions); counts and flags
(``passengers``, ``charging``, ``door_open``) and columns of the user's own are not checked."""
ALIASES = {"kph": "km/h", "km/hr": "km/h", "kmh": "km/h", "kmph": "km/h", "mps": "m/s",
           "°c": "degc", "deg c": "degc", "c": "degc", "celsius": "degc", "°f": "degf",
           "deg f": "degf", "f": "degf", "k": "k", "kelvin": "k", "percent": "%",
           "w/m2": "w/m^2", "w/m²": "w/m^2"}
CONVERSIONS = {  # (from, to) lower case: to = scale * from + offset
    ("m/s", "km/h"): (3.6, 0.0), ("mph", "km/h"): (1.609344, 0.0),
    ("km/h", "m/s"): (1 / 3.6, 0.0),
    ("k", "degc"): (1.0, -273.15), ("degf", "degc"): (5 / 9, -32 * 5 / 9),
    ("w", "kw"): (1e-3, 0.0), ("mw", "kw"): (1e3, 0.0),
    ("ma", "a"): (1e-3, 0.0), ("ka", "a"): (1e3, 0.0),
    ("mv", "v"): (1e-3, 0.0), ("kv", "v"): (1e3, 0.0),
    ("ft", "m"): (0.3048, 0.0), ("1", "%"): (100.0, 0.0), ("%", ""): (0.01, 0.0),
}


def _unit_key(unit: str | None) -> str:
    text = (unit or "").strip().lower()
    return ALIASES.get(text, text)


@dataclass(frozen=True)
class Entry:
    """One column of the canonical log and the DBC signal it comes from."""

    column: str
    message: str
    signal: str
    sample: str
    required: bool
    scale: float  # column = offset + scale * (the DBC's physical value)
    offset: float
    values: dict | None  # raw value -> column value (states)
    default: float | None
    hold_s: float
    how: str  # the conversion in words, for the report ("" when none)

    @property
    def source(self) -> str:
        return f"{self.message}.{self.signal}"


@dataclass(frozen=True)
class SignalMap:
    """A parsed signal map: the DBC (a cantools database), the rate and the entries."""

    name: str
    dbc_path: Path
    database: object
    rate_hz: float
    timezone: datetime.tzinfo | None
    entries: tuple[Entry, ...]

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    def message(self, name: str):
        return self.database.get_message_by_name(name)


def need(what: str = "reading CAN logger files"):
    """Import cantools, or fail naming the extra that installs it."""
    try:
        import cantools
    except ImportError:
        raise ConfigError(f"{what[0].upper() + what[1:]} needs the optional packages asammdf, "
                          "python-can and cantools. Fix: pip install 'ebus-env[can]' (in a "
                          "checkout: pip install -e '.[can]').") from None
    return cantools


def is_signal_map(data) -> bool:
    """Whether a preset's content (a mapping) is a CAN signal map rather than a column map."""
    return isinstance(data, dict) and ("dbc" in data or "signals" in data)


def load_signal_map(source, name: str | None = None) -> SignalMap:
    """A :class:`SignalMap` from a preset's name or path (``configs/logs``) or a mapping of
    the same keys (a relative ``dbc`` then counts from the working folder)."""
    from ebus_env.config import find_config, read_yaml

    if isinstance(source, SignalMap):
        return source
    base = Path.cwd()
    if isinstance(source, (str, Path)):
        path = find_config(source, kind="logs")
        data, base, name = read_yaml(path), path.parent, name or path.stem
        where = str(path)
    else:
        data, where, name = dict(source), "the signal map", name or "signal map"
    if not is_signal_map(data):
        raise ConfigError(f"{where} is a column map for CSV and Parquet logs, not a CAN signal "
                          "map. Fix: give a preset with dbc: and signals: (e.g. ebus_j1939) for "
                          "a logger file (.mf4, .blf, .asc).")
    for key in data:
        if key not in MAP_KEYS:
            raise ConfigError(f"{where}: unknown key '{key}'.{did_you_mean(key, MAP_KEYS)} "
                              f"Valid: {', '.join(MAP_KEYS)}.")
    for key in ("dbc", "signals"):
        if not data.get(key):
            raise ConfigError(f"{where} needs '{key}'.")
    cantools = need()
    dbc = _dbc_path(str(data["dbc"]), base, where)
    try:
        database = cantools.database.load_file(str(dbc))
    except Exception as exc:  # cantools raises its parsers' own errors
        raise ConfigError(f"{where}: the DBC {dbc} cannot be read ({exc}). Fix: give a valid "
                          "DBC file.") from None
    rate = data.get("rate_hz", 1.0)
    if not isinstance(rate, (int, float)) or not 0.05 <= rate <= 20:
        raise ConfigError(f"{where}: rate_hz {rate!r} is not a rate of 0.05-20 rows per second "
                          "(the loader reads logs of 0.5-20 Hz; 1 is usual).")
    zone = _zone(data.get("timezone"), where)
    if not isinstance(data["signals"], dict):
        raise ConfigError(f"{where}: 'signals' maps each column to its signal "
                          "({speed_kmh: {signal: CCVS1.WheelBasedVehicleSpeed}, ...}).")
    entries = tuple(_entry(column, spec, database, where)
                    for column, spec in data["signals"].items())
    return SignalMap(name, dbc, database, float(rate), zone, entries)


def _dbc_path(text: str, base: Path, where: str) -> Path:
    path = Path(text)
    for candidate in (path if path.is_absolute() else base / path, paths.here_or_shipped(path)):
        if candidate.is_file():
            return candidate
    raise ConfigError(f"{where}: the DBC '{text}' does not exist (looked beside the preset, in "
                      "the working folder and among the shipped files). Fix: give its path.")


def _zone(text, where: str) -> datetime.tzinfo | None:
    if text is None:
        return None
    try:
        return zoneinfo.ZoneInfo(str(text))
    except (zoneinfo.ZoneInfoNotFoundError, ValueError):
        raise ConfigError(f"{where}: timezone '{text}' is no IANA time zone. Fix: give one such "
                          "as Europe/Berlin or America/New_York (or UTC).") from None


def _find_signal(text: str, database, where: str, column: str):
    """The (message, signal) that ``Message.Signal`` or a signal's bare name means."""
    message_name, _, signal_name = text.rpartition(".")
    names = [m.name for m in database.messages]
    if message_name:
        if message_name not in names:
            raise ConfigError(f"{where}, {column}: the DBC has no message '{message_name}'."
                              f"{did_you_mean(message_name, names)} Messages: "
                              f"{', '.join(names)}.")
        message = database.get_message_by_name(message_name)
        signals = [s.name for s in message.signals]
        if signal_name not in signals:
            raise ConfigError(f"{where}, {column}: message {message_name} has no signal "
                              f"'{signal_name}'.{did_you_mean(signal_name, signals)} Signals: "
                              f"{', '.join(signals)}.")
        return message, message.get_signal_by_name(signal_name)
    found = [(m, s) for m in database.messages for s in m.signals if s.name == signal_name]
    if len(found) == 1:
        return found[0]
    every = [f"{m.name}.{s.name}" for m in database.messages for s in m.signals]
    if not found:
        raise ConfigError(f"{where}, {column}: the DBC has no signal '{signal_name}'."
                          f"{did_you_mean(signal_name, [s.split('.')[1] for s in every])}")
    raise ConfigError(f"{where}, {column}: the signal '{signal_name}' is in several messages "
                      f"({', '.join(m.name for m, _ in found)}). Fix: name it Message.Signal.")


def _entry(column: str, spec, database, where: str) -> Entry:
    if isinstance(spec, str):
        spec = {"signal": spec}
    if not isinstance(spec, dict) or "signal" not in spec:
        raise ConfigError(f"{where}, {column}: give the DBC signal ({column}: {{signal: "
                          "Message.Signal}}).")
    for key in spec:
        if key not in ENTRY_KEYS:
            raise ConfigError(f"{where}, {column}: unknown key '{key}'."
                              f"{did_you_mean(key, ENTRY_KEYS)} Valid: {', '.join(ENTRY_KEYS)}.")
    message, signal = _find_signal(str(spec["signal"]), database, where, column)
    sample = spec.get("sample", "mean" if column in MEAN_COLUMNS else "last")
    if sample not in SAMPLING:
        raise ConfigError(f"{where}, {column}: sample '{sample}' is none of "
                          f"{', '.join(SAMPLING)}.{did_you_mean(str(sample), SAMPLING)}")
    values = spec.get("values")
    if values is not None:
        if not isinstance(values, dict) or not values:
            raise ConfigError(f"{where}, {column}: values maps raw values to the column's "
                              "({0: 0, 1: 1}).")
        values = {int(k): float(v) for k, v in values.items()}
    scale, offset, how = _conversion(column, spec, signal, values is not None, where)
    numbers = {}
    for key in ("default", "hold_s"):
        value = spec.get(key)
        if value is not None and (not isinstance(value, (int, float)) or isinstance(value, bool)):
            raise ConfigError(f"{where}, {column}: {key} must be a number, got {value!r}.")
        numbers[key] = value
    cycle_s = (message.cycle_time or 0) / 1000.0
    hold = numbers["hold_s"] if numbers["hold_s"] is not None else max(5.0, 5 * cycle_s)
    if hold <= 0:
        raise ConfigError(f"{where}, {column}: hold_s must be > 0 s.")
    return Entry(column, message.name, signal.name, sample, bool(spec.get("required", False)),
                 scale, offset, values, None if numbers["default"] is None
                 else float(numbers["default"]), float(hold), how)


def _conversion(column: str, spec: dict, signal, state: bool, where: str
                ) -> tuple[float, float, str]:
    """``(scale, offset, words)`` from the signal's unit to the column's, then the entry's own
    ``scale`` and ``offset``."""
    scale, offset, how = 1.0, 0.0, []
    unit = spec.get("unit", signal.unit)
    want = COLUMN_UNITS.get(column)
    if want is not None and not state:
        have, target = _unit_key(unit), _unit_key(want)
        if have == target:
            pass
        elif (have, target) in CONVERSIONS:
            scale, offset = CONVERSIONS[(have, target)]
            how.append(f"{unit} to {want}")
        elif not have and "scale" not in spec:
            how.append(f"no unit in the DBC: taken as {want or 'a count'}")
        elif "scale" not in spec:
            raise ConfigError(f"{where}, {column}: the signal {signal.name} is in '{unit}', the "
                              f"column in '{want}', and the loader knows no conversion. Fix: "
                              f"give the entry's unit (unit: ...) if the DBC's is wrong, or "
                              f"scale: and offset: that take {unit} to {want}.")
    user_scale = float(spec.get("scale", 1.0))
    user_offset = float(spec.get("offset", 0.0))
    if user_scale == 0:
        raise ConfigError(f"{where}, {column}: scale must not be 0.")
    if user_scale != 1.0 or user_offset != 0.0:
        how.append(f"x {user_scale:g}" + (f" {user_offset:+g}" if user_offset else ""))
    return scale * user_scale, offset * user_scale + user_offset, ", ".join(how)
