"""Profiles: what a bus is asked to do, on the simulation time grid.

A :class:`Profile` holds the input channels of a run (reference speed, grade, ambient, charger
connection, ...) at the simulation step ``dt_s``, one row per step, plus the measured signals
of a log on the same grid (``soc_frac``, ``battery_current_a``, ...) for comparison, and the list
of every change made to the data on the way (resampling, smoothing, filling).
"""

from __future__ import annotations

import dataclasses
import datetime
from dataclasses import dataclass, field

import numpy as np

from ebus_env.signals import INPUTS

STANDING_SPEED_MPS = 0.05
"""Below this reference speed the bus is standing (doors may open)."""


@dataclass
class Profile:
    """Inputs of one run, one row per simulation step.

    Parameters
    ----------
    channels
        Input channels by canonical name (see :data:`ebus_env.signals.INPUTS`), SI units,
        each an array of length ``n_steps``. ``speed_ref_mps`` is required.
    dt_s
        Simulation time step [s].
    name
        Label for reports.
    start_time_h
        Time of day at the first row [h].
    measured
        Measured signals on the same grid (``soc_frac``, ``battery_current_a``, ...), NaN where
        the log has none; interpolated between the log's samples.
    samples
        For a measured signal, the rows where the log really has a sample (a 1 Hz log on a
        0.1 s grid: every 10th row; a 5-minute log: every 3000th). Fits compare only there.
    start_s
        The log's own time at the first row, from the log's first row [s]: a segment of a log
        split at its gaps starts where it does in the log.
    date
        The local date of the first row, where the log has date-times (None otherwise): the
        day a run belongs to when several days of a bus are compared.
    notes
        Every change made to the data, in words.
    """

    channels: dict[str, np.ndarray]
    dt_s: float
    name: str = ""
    start_time_h: float = 0.0
    measured: dict[str, np.ndarray] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    samples: dict[str, np.ndarray] = field(default_factory=dict)
    start_s: float = 0.0
    date: datetime.date | None = None
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self):
        if "speed_ref_mps" not in self.channels:
            raise ValueError("A profile needs the channel 'speed_ref_mps'.")
        n = len(self.channels["speed_ref_mps"])
        for name, values in list(self.channels.items()) + list(self.measured.items()):
            if len(values) != n:
                raise ValueError(f"Profile channel '{name}' has {len(values)} rows, expected {n}.")
        if n < 2:
            raise ValueError("A profile needs at least two time steps.")
        self.channels = {k: np.asarray(v, dtype=float) for k, v in self.channels.items()}
        self.measured = {k: np.asarray(v, dtype=float) for k, v in self.measured.items()}

    @property
    def n_steps(self) -> int:
        return len(self.channels["speed_ref_mps"])

    @property
    def time_s(self) -> np.ndarray:
        return np.arange(self.n_steps) * self.dt_s

    @property
    def duration_s(self) -> float:
        return self.n_steps * self.dt_s

    @property
    def distance_m(self) -> float:
        """Distance of the reference speed [m] (trapezoidal)."""
        v = self.channels["speed_ref_mps"]
        return float(np.sum(0.5 * (v[1:] + v[:-1])) * self.dt_s)

    def sample_rows(self, name: str = "soc_frac") -> np.ndarray:
        """Rows where the measured signal ``name`` was really sampled (all finite rows when
        the profile does not say)."""
        if name in self.samples:
            return self.samples[name]
        values = self.measured.get(name)
        if values is None:
            return np.zeros(0, dtype=np.int64)
        return np.flatnonzero(np.isfinite(values))

    def channel(self, name: str) -> np.ndarray:
        """A channel as given, derived from others, or filled with its default.

        Derived channels are computed once: treat a profile as immutable (``with_channels``
        makes a changed copy)."""
        if name in self.channels:
            return self.channels[name]
        if name not in self._cache:
            self._cache[name] = self._derive(name)
        return self._cache[name]

    def stacked(self, names: tuple[str, ...]) -> np.ndarray:
        """(len(names), n_steps) array of channels, computed once per set of names."""
        key = ("stacked", names)
        if key not in self._cache:
            self._cache[key] = np.stack([self.channel(n) for n in names])
        return self._cache[key]

    def _derive(self, name: str) -> np.ndarray:
        v = self.channels["speed_ref_mps"]
        if name == "accel_ref_mps2":
            a = np.zeros_like(v)
            a[:-1] = np.diff(v) / self.dt_s
            return a
        if name == "time_of_day_h":
            return (self.start_time_h + self.time_s / 3600.0) % 24.0
        if name == "door_open":
            connected = self.channel("charger_connected") > 0.5
            return ((v < STANDING_SPEED_MPS) & ~connected).astype(float)
        if name in INPUTS:
            return np.full(self.n_steps, INPUTS[name].default)
        raise KeyError(f"Profile has no channel '{name}' and no rule to derive it.")

    def with_channels(self, **channels) -> Profile:
        """A copy with channels replaced or added (arrays or scalars)."""
        new = dict(self.channels)
        for name, value in channels.items():
            new[name] = np.broadcast_to(np.asarray(value, dtype=float), (self.n_steps,)).copy()
        return self._copy(channels=new)

    def with_measured(self, **signals) -> Profile:
        """A copy with measured signals replaced or added (arrays of ``n_steps`` rows)."""
        return self._copy(measured={**self.measured, **{
            k: np.asarray(v, dtype=float) for k, v in signals.items()}},
            samples={k: v for k, v in self.samples.items() if k not in signals})

    def without_measured(self, *names: str) -> Profile:
        """A copy without the measured signals ``names`` (the model's inputs unchanged)."""
        return self._copy(measured={k: v for k, v in self.measured.items() if k not in names},
                          samples={k: v for k, v in self.samples.items() if k not in names})

    def slice(self, start: int, stop: int) -> Profile:
        """Rows ``start:stop`` as a profile of their own."""
        samples = {k: rows[(rows >= start) & (rows < stop)] - start
                   for k, rows in self.samples.items()}
        elapsed_h = self.start_time_h + start * self.dt_s / 3600.0
        return self._copy(channels={k: v[start:stop] for k, v in self.channels.items()},
                          start_time_h=elapsed_h % 24.0,
                          measured={k: v[start:stop] for k, v in self.measured.items()},
                          samples=samples, start_s=self.start_s + start * self.dt_s,
                          date=None if self.date is None else
                          self.date + datetime.timedelta(days=int(elapsed_h // 24.0)))

    def _copy(self, **changes) -> Profile:
        """A copy with ``changes``: containers copied, the derived-signal cache empty."""
        keep = {"channels": dict(self.channels), "measured": dict(self.measured),
                "notes": list(self.notes), "samples": dict(self.samples)}
        return dataclasses.replace(self, **{**keep, **changes, "_cache": {}})


def as_profiles(profiles, what: str = "profiles") -> list[Profile]:
    """``profiles`` as a non-empty list of :class:`Profile`, or an error naming what was given
    (a loaded log's profiles are ``log.profiles``)."""
    from ebus_env.errors import ConfigError

    if isinstance(profiles, Profile):
        return [profiles]
    if hasattr(profiles, "profiles") and not isinstance(profiles, (str, bytes)):
        raise ConfigError(f"{what}: give the log's profiles (log.profiles), not the "
                          f"{type(profiles).__name__}.")
    try:
        out = list(profiles)
    except TypeError:
        raise ConfigError(f"{what}: give a list of Profile, not a "
                          f"{type(profiles).__name__}.") from None
    if not out:
        raise ConfigError(f"{what}: no profiles; give at least one (load_log(path).profiles).")
    for p in out:
        if not isinstance(p, Profile):
            raise ConfigError(f"{what}: give a list of Profile; one item is a "
                              f"{type(p).__name__}.")
    return out
