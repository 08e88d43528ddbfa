"""The accepted range of every user input, declared once and used by every check.

Each :class:`Range` holds the physical limits of one input. Outside ``[low, high]`` the input
is an error; inside it but outside ``[warn_low, warn_high]`` (values a user may mean, though
they are unusual) the run goes on with a printed warning that names the value and the range.
Nothing is clipped or replaced. ``docs/inputs.md`` shows this table (``tests`` keep the two
equal).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

from ebus_env.errors import ConfigError, InputWarning
from ebus_env.units import with_unit


def _num(x: float) -> str:
    return f"{x:,.10g}"


@dataclass(frozen=True)
class Range:
    """Accepted range of one input.

    Parameters
    ----------
    name
        Key of the input in :data:`RANGES` (where users give it: ``given``).
    unit
        Its unit.
    low, high
        Hard limits: outside them the input is an error.
    open_low
        The low limit itself is excluded (``(0, 48]``).
    warn_low, warn_high
        Usual range: between it and the hard limits a warning is printed.
    why
        What the limits rest on, and the fix for a value outside.
    given
        Where users give it (options, config keys, log columns), for ``docs/inputs.md``.
    """

    name: str
    unit: str
    low: float
    high: float
    why: str
    open_low: bool = False
    warn_low: float = -math.inf
    warn_high: float = math.inf
    given: str = ""

    def text(self, unit: bool = True) -> str:
        """``(0, 48] h`` style."""
        return (f"{'(' if self.open_low else '['}{_num(self.low)}, {_num(self.high)}]"
                + (self._unit if unit else ""))

    def check(self, value, source: str | None = None) -> list[str]:
        """Raise :class:`ConfigError` outside the hard limits; return the warning (a list of
        one line) outside the usual range, else ``[]``."""
        where = source or self.name
        try:
            x = float(value)
        except (TypeError, ValueError):
            raise ConfigError(f"{where}: {value!r} is not a number; accepted: {self.text()}."
                              ) from None
        if isinstance(value, bool) or not math.isfinite(x) or x > self.high or x < self.low \
                or (self.open_low and x == self.low):
            raise ConfigError(f"{where} = {value!r} is outside the accepted range "
                              f"{self.text()}. {self.why}")
        if x < self.warn_low or x > self.warn_high:
            return [f"{where} = {x:g}{self._unit} is {self.usual()}, though accepted: "
                    f"{self.why}"]
        return []

    @property
    def _unit(self) -> str:
        return with_unit("", self.unit)

    def usual(self) -> str:
        """``outside the usual 5-50 km/h`` style; empty when every accepted value is usual."""
        if math.isinf(self.warn_low) and math.isinf(self.warn_high):
            return ""
        if math.isinf(self.warn_low):
            return f"above the usual {_num(self.warn_high)}{self._unit}"
        if math.isinf(self.warn_high):
            return f"below the usual {_num(self.warn_low)}{self._unit}"
        return f"outside the usual {_num(self.warn_low)}-{_num(self.warn_high)}{self._unit}"


MAX_STEPS = 2_000_000
"""Most time steps in one run (48 h at 10 Hz is 1.73 million); each recorded step holds about
40 signals, so a longer run would need gigabytes of memory."""

RANGES: dict[str, Range] = {r.name: r for r in (
    Range("hours", "h", 0.0, 48.0, "Length of a cycle day: give hours, at most two days.",
          open_low=True, given="`--hours`"),
    Range("dt_s", "s", 0.01, 1.0, "The model is built and checked at 0.1 s (10 Hz); a "
          "SORT 2 hour uses 0.4 % less energy at 1 s, and coarser steps break the speed "
          "tracking and the CC/CV taper.", warn_high=0.2, given="`--dt`; env `dt_s`"),
    Range("steps", "1", 2.0, MAX_STEPS, "Steps of one run (duration / dt): a run needs two "
          "steps at least, and a longer one does not fit in memory. Fix: a day or log of at "
          "least two steps and at most the largest, or a larger --dt for a long one.",
          given="hours or log duration / dt"),
    Range("mean_speed_kmh", "km/h", 0.0, 100.0, "Mean speed of the scaled cycle, stops "
          "included: city buses run 10-30 km/h.", open_low=True, warn_low=5.0, warn_high=50.0,
          given="`--mean-speed-kmh`"),
    Range("ambient_degc", "degC", -50.0, 60.0, "Ambient temperature in degC (not kelvin: "
          "subtract 273.15).", given="`--ambient-degc`; bus `service.ambient_degc`; env "
          "`ambient_mean_degc`; log column `ambient_degc`"),
    Range("soc_start_pct", "%", 0.0, 100.0, "State of charge in percent (90 for 90 %).",
          warn_low=5.0, given="`--soc-start-pct`; bus `service.soc_start_pct`; env "
          "`soc_start_pct`, `reserve_soc_pct`"),
    Range("load_frac", "1", 0.0, 1.0, "Passenger load as a fraction of capacity, or driver, "
          "half, full.", given="`--load`"),
    Range("start_time_h", "h", 0.0, 24.0, "Time of day of the first departure.",
          given="bus `service.start_time_h`; env `start_time_h`"),
    Range("layover_every_min", "min", 0.0, 1440.0, "Driving time between layovers (may be 0 "
          "only with layover_min 0, no layovers).", open_low=True,
          given="bus `service.layover_every_min`"),
    Range("layover_min", "min", 0.0, 720.0, "Length of a layover on the charger; 0: no "
          "layovers (charge_at_layovers: false for layovers without charging).",
          given="bus `service.layover_min`; env `layover_min`"),
    Range("min_layover_min", "min", 0.0, 720.0, "Shortest layover of an env episode "
          "(plugging in and out); at most layover_min.", given="env `min_layover_min`"),
    Range("charger_kw", "kW", 0.0, 1000.0, "Charger rating.", open_low=True,
          given="bus `service.layover_charger_kw`, `service.depot_charger_kw`; env "
          "`charger_kw`; study `terminal_charger_kw`, `depot_charger_kw`"),
    Range("population", "1", 2.0, 1000.0, "iSOPT population (default 11).",
          given="`calibrate --population`"),
    Range("iterations", "1", 1.0, 100_000.0, "iSOPT iterations (default 50).",
          given="`calibrate --iterations`"),
    Range("window_s", "s", 10.0, 86_400.0, "Diagnosis window: long enough to hold several "
          "SoC steps (default 300 s), at most a day.", given="`diagnose --window-s`"),
    Range("log_period_s", "s", 0.001, 2.0, "Sample period of a measured log (0.5-20 Hz); "
          "faster logs are averaged onto the grid. Logs with a sample every few minutes: "
          "calibrate --sparse.", warn_low=0.05, given="median step of a log's time"),
    Range("log_speed_kmh", "km/h", 0.0, 400.0, "Speeds are >= 0 and plausible.",
          given="log column `speed_kmh` (or `speed_mps` x 3.6)"),
    Range("log_start_h", "h", 0.0, 24.0, "Time of day of a log's first row, for a log "
          "without date-times (07:30 is 7.5 h); a log with date-times has its own clock.",
          given="`--start-time HH:MM`; `load_log(start_h=)`"),
    Range("log_load_kw", "kW", -1000.0, 1000.0, "A load on the DC bus in kW (not W: divide "
          "by 1000); a bus's HVAC draws up to about 40 kW, a compressor 10 kW. Negative where "
          "the logged load returns power to the bus.", given="log column `logged_load_kw`"),
    Range("log_soc_pct", "%", 0.0, 100.0, "SoC in percent; a 0-1 column is `soc_frac`.",
          given="log column `soc_pct`"),
    Range("log_grade_pct", "%", -30.0, 30.0, "Road grade in percent (the steepest streets "
          "buses climb are about 15 %); a column of fractions is `grade_frac`.",
          given="log column `grade_pct` (`grade_frac` x 100)"),
    Range("log_altitude_m", "m", -500.0, 6000.0, "Altitude above sea level in metres (not "
          "feet: multiply by 0.3048).", given="log column `altitude_m`"),
    Range("log_passengers", "1", 0.0, 300.0, "Passengers on board, a count (a 12 m bus "
          "carries up to about 100, an 18 m one about 160).", given="log column `passengers`; bus "
          "`service.passenger_profile`"),
    Range("log_charger_kw", "kW", 0.0, 1000.0, "Rating of the charger the bus is on, in kW "
          "(not W); 0 where there is none.", given="log column `charger_kw`"),
    Range("log_solar_w_per_m2", "W/m^2", 0.0, 1500.0, "Solar irradiance; clear-sky noon "
          "gives about 1000 W/m^2.", given="log column `solar_w_per_m2`"),
    Range("log_current_a", "A", -5000.0, 5000.0, "Pack current in A (not mA), > 0 "
          "discharging; a preset's `scale: -1` flips a log that counts charging positive.",
          given="log column `battery_current_a`"),
    Range("log_voltage_v", "V", 0.0, 2000.0, "Pack voltage in V (an e-bus pack 300-800 V).",
          open_low=True, given="log column `battery_voltage_v`"),
    Range("log_cabin_temp_degc", "degC", -50.0, 80.0, "Cabin air temperature in degC (not "
          "kelvin).", given="log column `cabin_temp_degc`"),
    Range("service_h", "h", 0.0, 24.0, "Service hours of an env episode.", open_low=True,
          given="env `service_h`"),
    Range("decision_s", "s", 1.0, 3600.0, "Length of an env decision.",
          given="env `decision_s`"),
    Range("passenger_frac", "1", 0.0, 1.0, "A share of the bus's passenger capacity.",
          given="env `passengers_base_frac`, `passengers_peak_frac`, `passengers_random_frac`"),
    Range("temperature_span_k", "K", 0.0, 30.0, "A temperature swing or spread.",
          given="env `ambient_amplitude_k`, `ambient_random_k`"),
    Range("jerk_mps3", "m/s^3", 0.0, 10.0, "Ramp of the acceleration (default 1 m/s^3).",
          open_low=True, given="env `jerk_mps3`"),
    Range("decel_mps2", "m/s^2", 0.0, 5.0, "Braking towards stops.", open_low=True,
          given="env `comfort_decel_mps2`"),
    Range("laps_per_trip", "1", 1.0, 1000.0, "Cycle laps between terminal layovers (a whole "
          "number).", given="env `laps_per_trip`"),
)}

ENV_KEYS = {"service_h": "service_h", "start_time_h": "start_time_h", "dt_s": "dt_s",
            "decision_s": "decision_s", "soc_start_pct": "soc_start_pct",
            "reserve_soc_pct": "soc_start_pct", "layover_min": "layover_min",
            "min_layover_min": "min_layover_min", "charger_kw": "charger_kw",
            "ambient_mean_degc": "ambient_degc", "ambient_amplitude_k": "temperature_span_k",
            "ambient_random_k": "temperature_span_k", "passengers_base_frac": "passenger_frac",
            "passengers_peak_frac": "passenger_frac", "passengers_random_frac": "passenger_frac",
            "jerk_mps3": "jerk_mps3", "comfort_decel_mps2": "decel_mps2",
            "laps_per_trip": "laps_per_trip"}
"""Env config keys (``ebus_env.envs.ebus.EnvConfig``) and the range each one is checked in."""


def markdown_table() -> str:
    """The table of ``docs/inputs.md``: input, unit, accepted range, what happens outside and
    why the range is what it is."""
    rows = ["| input | where | unit | accepted | outside |", "|---|---|---|---|---|"]
    for r in RANGES.values():
        outside = "error" + (f"; warning {r.usual()}" if r.usual() else "")
        rows.append(f"| {r.name} | {r.given} | {r.unit} | {r.text(unit=False)} | {outside}. {r.why} |")
    return "\n".join(rows) + "\n"


def check(name: str, value, source: str | None = None) -> list[str]:
    """Check ``value`` against the declared range of input ``name`` (see :data:`RANGES`): an
    error outside it; outside the usual range an :class:`~ebus_env.errors.InputWarning` (the
    command line prints it), whose line is returned. ``source`` names where the value came
    from (``--hours``, a file and key)."""
    lines = RANGES[name].check(value, source)
    for line in lines:  # keyed by input and value: checked where read and where used
        warnings.warn(InputWarning(line, (name, round(float(value), 9))), stacklevel=2)
    return lines
