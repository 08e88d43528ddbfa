"""Standard driving cycles and service days built from them.

Shipped cycles (``data/cycles``, licenses beside them):

* UITP SORT 1/2/3 (1 Hz, via PSI's carculator_utils, BSD-3) and the SORT 1+2+3 composite;
* VECTO Urban/Coach bus missions with road grade (carculator_utils, BSD-3);
* NREL ADVISOR transit-bus cycles (Manhattan, New York Bus, Orange County, CBD-14, ...) and
  three measured bus journeys (Denver mall shuttle, Nuremberg route 36, London), ADVISOR
  license.

:func:`service_day` repeats a cycle to a duration, optionally scaled to a target mean speed
(as the paper fills sparse logs), with layovers on a charger.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ebus_env import paths
from ebus_env.config import Service
from ebus_env.errors import ConfigError, unknown_name
from ebus_env.inputs import RANGES, check
from ebus_env.profile import Profile
from ebus_env.resample import grid, resample

CYCLE_DIR = paths.data("cycles")


@dataclass(frozen=True)
class CycleInfo:
    file: str
    description: str
    source: str


_CARC = "UITP SORT via PSI carculator_utils (BSD-3), data/cycles/carculator"
_ADV = "NREL ADVISOR 2003 (ADVISOR license), data/cycles/advisor"
CYCLES: dict[str, CycleInfo] = {
    "sort1": CycleInfo("carculator/sort1.csv", "UITP SORT 1, heavy urban (520 m)", _CARC),
    "sort2": CycleInfo("carculator/sort2.csv", "UITP SORT 2, easy urban (920 m)", _CARC),
    "sort3": CycleInfo("carculator/sort3.csv", "UITP SORT 3, easy suburban (1450 m)", _CARC),
    "sort123": CycleInfo("", "SORT 1 + 2 + 3 composite ('hybrid SORT', docs/physics.md §8.2)", _CARC),
    "vecto_urban_13m": CycleInfo("carculator/vecto_urban_13m.csv",
                                 "VECTO Urban mission, 13 m bus, with grade", _CARC),
    "vecto_urban_18m": CycleInfo("carculator/vecto_urban_18m.csv",
                                 "VECTO Urban mission, 18 m bus, with grade", _CARC),
    "vecto_coach_13m": CycleInfo("carculator/vecto_coach_13m.csv",
                                 "VECTO Coach mission, 13 m, with grade", _CARC),
    "manhattan": CycleInfo("advisor/CYC_MANHATTAN.csv", "Manhattan Bus cycle (WVU)", _ADV),
    "nybus": CycleInfo("advisor/CYC_NewYorkBus.csv", "New York Bus cycle (WVU)", _ADV),
    "occ": CycleInfo("advisor/CYC_OCC.csv", "Orange County (OCTA) Bus cycle", _ADV),
    "cbd": CycleInfo("advisor/CYC_CBDBUS.csv", "Central Business District CBD-14 (SAE J1376)",
                     _ADV),
    "cbd14_10hz": CycleInfo("advisor/CYC_CBD14.csv", "CBD-14 at 10 Hz", _ADV),
    "arterial": CycleInfo("advisor/CYC_ARTERIAL.csv", "BAC Arterial (SAE J1376)", _ADV),
    "commuter": CycleInfo("advisor/CYC_COMMUTER.csv", "BAC Commuter (SAE J1376)", _ADV),
    "denver_mall": CycleInfo("advisor/CYC_BUSRTE.csv",
                             "Measured: Denver 16th St Mall shuttle (NREL)", _ADV),
    "nuremberg36": CycleInfo("advisor/CYC_NurembergR36.csv",
                             "Measured: Nuremberg route 36 (Siemens)", _ADV),
    "london": CycleInfo("advisor/CYC_UKBUS6.csv", "Measured: London bus route (Cranfield)", _ADV),
    "wvu_city": CycleInfo("advisor/CYC_WVUCITY.csv", "WVU City", _ADV),
    "wvu_suburban": CycleInfo("advisor/CYC_WVUSUB.csv", "WVU Suburban", _ADV),
    "wvu_interstate": CycleInfo("advisor/CYC_WVUINTER.csv", "WVU Interstate", _ADV),
    "nyc_composite": CycleInfo("advisor/CYC_NYCCOMP.csv", "New York Composite (heavy duty)", _ADV),
    "udds_hdv": CycleInfo("advisor/CYC_UDDSHDV.csv", "EPA UDDS for heavy-duty vehicles", _ADV),
}


@dataclass(frozen=True)
class Cycle:
    """A speed trace (and optional grade) over time, at its native sampling."""

    name: str
    time_s: np.ndarray
    speed_kmh: np.ndarray
    grade_frac: np.ndarray | None = None
    description: str = ""
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0])

    @property
    def distance_km(self) -> float:
        v = self.speed_kmh / 3.6
        return float(np.sum(0.5 * (v[1:] + v[:-1]) * np.diff(self.time_s))) / 1000.0

    @property
    def mean_speed_kmh(self) -> float:
        """Mean speed including stops [km/h]."""
        return self.distance_km / (self.duration_s / 3600.0)

    def scaled(self, mean_speed_kmh: float) -> Cycle:
        """The cycle with every speed scaled so that its mean speed is ``mean_speed_kmh``
        (same duration, distance scaled)."""
        factor = mean_speed_kmh / self.mean_speed_kmh
        return replace(self, name=f"{self.name} x{factor:.3f}", speed_kmh=self.speed_kmh * factor,
                       notes=self.notes + (f"speeds scaled by {factor:.4f} to a mean of "
                                           f"{mean_speed_kmh:.2f} km/h",))

    def then(self, other: Cycle) -> Cycle:
        """This cycle followed by ``other``."""
        t = np.concatenate([self.time_s, other.time_s[1:] - other.time_s[0] + self.time_s[-1]])
        v = np.concatenate([self.speed_kmh, other.speed_kmh[1:]])
        g = None
        if self.grade_frac is not None or other.grade_frac is not None:
            g = np.concatenate([_grade(self), _grade(other)[1:]])
        return Cycle(f"{self.name}+{other.name}", t, v, g, "", self.notes + other.notes)

    def lap(self, dt_s: float) -> dict[str, np.ndarray]:
        """One lap on the grid ``dt_s`` without its last sample (so laps join seamlessly)."""
        g = grid(self.time_s[0], self.time_s[-1], dt_s)[:-1]
        channels = {"speed_ref_mps": resample(self.time_s, self.speed_kmh / 3.6, g, dt_s)}
        if self.grade_frac is not None:
            channels["grade_frac"] = resample(self.time_s, self.grade_frac, g, dt_s)
        return channels

    def profile(self, dt_s: float = 0.1, **constants: float) -> Profile:
        """The cycle once, on the simulation grid, with constant channels (``ambient_degc=5``)."""
        g = grid(self.time_s[0], self.time_s[-1], dt_s)
        channels = {"speed_ref_mps": resample(self.time_s, self.speed_kmh / 3.6, g, dt_s)}
        if self.grade_frac is not None:
            channels["grade_frac"] = resample(self.time_s, self.grade_frac, g, dt_s)
        for name, value in constants.items():
            channels[name] = np.full(len(g), float(value))
        return Profile(channels, dt_s, self.name, notes=list(self.notes) + _resample_note(self, dt_s))


def _grade(cycle: Cycle) -> np.ndarray:
    return cycle.grade_frac if cycle.grade_frac is not None else np.zeros_like(cycle.time_s)


def _resample_note(cycle: Cycle, dt_s: float) -> list[str]:
    native = float(np.median(np.diff(cycle.time_s)))
    if abs(native - dt_s) < 1e-9:
        return []
    how = "linear interpolation" if native > dt_s else "window means"
    return [f"{cycle.name}: resampled from {native:g} s to {dt_s:g} s by {how}"]


def _read_cycle(path) -> np.ndarray:
    """The cycle table (numpy: no pandas import for a command-line run); a missing file or
    column is a :class:`ConfigError`."""
    try:
        frame = np.genfromtxt(path, delimiter=",", names=True)
    except OSError:
        raise ConfigError(f"Cycle file {path} does not exist.") from None
    names = frame.dtype.names or ()
    missing = [c for c in ("time_s", "speed_kmh") if c not in names]
    if missing or frame.ndim != 1 or len(frame) < 2:
        raise ConfigError(f"Cycle {path} needs at least two rows and the columns time_s, "
                          f"speed_kmh (optional grade_frac); it has {', '.join(names) or 'none'}.")
    return frame


def load_cycle(name: str) -> Cycle:
    """A shipped cycle by name (see :data:`CYCLES`), or a CSV path with ``time_s,speed_kmh``
    (optional ``grade_frac``)."""
    if name == "sort123":
        composite = load_cycle("sort1").then(load_cycle("sort2")).then(load_cycle("sort3"))
        return replace(composite, name=name, description=CYCLES[name].description)
    if name.endswith(".csv"):
        path, info = name, CycleInfo(name, name, name)
    else:
        if name not in CYCLES:
            raise unknown_name("cycle", name, CYCLES)
        info = CYCLES[name]
        path = CYCLE_DIR / info.file
    frame = _read_cycle(path)
    t = np.asarray(frame["time_s"], dtype=float)
    v = np.asarray(frame["speed_kmh"], dtype=float)
    notes = ()
    step_s = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    if 0 < t[0] <= 1.5 * step_s:  # ADVISOR's loaders prepend [0, v(1)] to cycles that start at t = 1 s
        t = np.concatenate([[0.0], t])
        v = np.concatenate([[v[0]], v])
        notes = (f"{name}: prepended t = 0 with the first speed, as ADVISOR does",)
    elif t[0] != 0:  # a cut from a longer record: its own start is the cycle's start
        notes = (f"{name}: time starts at {t[0]:g} s; shifted to start at 0",)
        t = t - t[0]
    g = np.asarray(frame["grade_frac"], dtype=float) if "grade_frac" in frame.dtype.names else None
    for label, values in (("time_s", t), ("speed_kmh", v), ("grade_frac", g)):
        if values is not None and not np.all(np.isfinite(values)):
            raise ConfigError(f"Cycle {path}: column '{label}' has missing or non-numeric values.")
    if np.any(np.diff(t) <= 0):
        raise ConfigError(f"Cycle {path}: time_s must increase strictly.")
    speed = RANGES["log_speed_kmh"]
    if np.any(v < speed.low) or np.any(v > speed.high):
        raise ConfigError(f"Cycle {path}: speed_kmh outside [{speed.low:g}, {speed.high:g}] "
                          f"(e.g. {v[(v < speed.low) | (v > speed.high)][0]:g}).")
    if g is not None and np.any(np.abs(g) > 0.3):
        raise ConfigError(f"Cycle {path}: grade_frac beyond +-0.3 (a fraction: 0.05 for 5 %).")
    if g is not None and len(g) != len(t):
        g = np.concatenate([[g[0]], g])
    return Cycle(name, t, v, g, info.description, notes)


def service_day(cycle: Cycle | str, hours: float, dt_s: float = 0.1,
                service: Service | None = None, mean_speed_kmh: float | None = None,
                ambient_degc: float | None = None) -> Profile:
    """A day of repeated laps with layovers on a charger.

    After each lap, once ``layover_every_min`` of driving has passed since the last layover,
    the bus stands ``layover_min`` at a charger of ``layover_charger_kw`` (NaN rating: the
    charger's own power parameter) when ``charge_at_layovers``. The day is cut at ``hours``.
    A ``passenger_profile`` ({hour of day: passengers}) sets the passengers over the day.
    """
    service = service or Service()
    check("hours", hours, "hours")
    check("dt_s", dt_s, "dt_s")
    check("steps", hours * 3600.0 / dt_s, f"{hours:g} h at dt {dt_s:g} s: steps")
    if ambient_degc is not None:
        check("ambient_degc", ambient_degc, "ambient_degc")
    if isinstance(cycle, str):
        cycle = load_cycle(cycle)
    if mean_speed_kmh is not None:
        check("mean_speed_kmh", mean_speed_kmh, "mean_speed_kmh")
        cycle = cycle.scaled(mean_speed_kmh)
    lap = cycle.lap(dt_s)
    n_lap = len(lap["speed_ref_mps"])
    n_total = int(round(hours * 3600.0 / dt_s))
    n_layover = int(round(service.layover_min * 60.0 / dt_s))
    every = service.layover_every_min * 60.0 / dt_s
    rating = np.nan if service.layover_charger_kw is None else service.layover_charger_kw * 1e3
    pieces: list[dict[str, np.ndarray]] = []
    rows = driving = 0
    layovers = 0
    while rows < n_total:
        pieces.append({**lap, "charger_connected": np.zeros(n_lap),
                       "charger_rating_w": np.full(n_lap, np.nan)})
        rows += n_lap
        driving += n_lap
        if driving >= every and n_layover > 0 and rows < n_total:
            connected = 1.0 if service.charge_at_layovers else 0.0
            block = {k: np.zeros(n_layover) for k in lap}
            block["charger_connected"] = np.full(n_layover, connected)
            block["charger_rating_w"] = np.full(n_layover, rating)
            pieces.append(block)
            rows += n_layover
            driving = 0
            layovers += 1
    channels = {k: np.concatenate([p[k] for p in pieces])[:n_total] for k in pieces[0]}
    ambient = service.ambient_degc if ambient_degc is None else ambient_degc
    channels["ambient_degc"] = np.full(n_total, float(ambient))
    if service.passenger_profile:
        hours_of_day = sorted(float(h) for h in service.passenger_profile)
        counts = [float(service.passenger_profile[h]) for h in sorted(service.passenger_profile)]
        clock = (service.start_time_h + np.arange(n_total) * dt_s / 3600.0) % 24.0
        channels["passenger_count"] = np.interp(clock, hours_of_day, counts)
    notes = list(cycle.notes) + _resample_note(cycle, dt_s) + [
        f"{hours:g} h of {cycle.name} laps with {layovers} layovers of {service.layover_min:g} min"
        f" every {service.layover_every_min:g} min of driving"
        + (" on a charger" if service.charge_at_layovers else "")]
    return Profile(channels, dt_s, f"{cycle.name} day", service.start_time_h, notes=notes)
