"""What every env of the package shares: the actions and their ranges, the spaces, the
episode config (:class:`EnvConfig`, ``configs/env/*.yaml``) and the one ``info`` builder."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path

import gymnasium as gym
import numpy as np

from ebus_env import paths
from ebus_env.config import read_yaml
from ebus_env.envs.batch import OBS_HIGH, OBS_LOW, OBSERVATIONS, OUT, BusBatch
from ebus_env.envs.climate import climate_of
from ebus_env.envs.reward import TERMS, Reward
from ebus_env.errors import ActionError, ConfigError
from ebus_env.inputs import ENV_KEYS, check
from ebus_env.units import with_unit

CONFIG_DIR = paths.configs("env")
SCORED = ("peak_rise_kw", "comfort_kh", "late_min", "reserve_pct_h", "service_lost_h")  # in info, with OUT


@dataclass(frozen=True)
class ActionRange:
    name: str
    unit: str
    low: float
    high: float
    meaning: str  # mapped linearly from [-1, 1] onto [low, high] (``physical``)


ACTIONS = (
    ActionRange("speed_cap_kmh", "km/h", 20.0, 80.0, "ECO-driving: cap on the top speed"),
    ActionRange("accel_cap_mps2", "m/s^2", 0.3, 1.5,
                "ECO-driving: cap on the acceleration (reached with a jerk-limited ramp)"),
    ActionRange("setpoint_degc", "degC", 14.0, 28.0, "ECO-comfort: cabin setpoint"),
    ActionRange("charge_power_frac", "1", 0.1, 1.0,
                "ECO-charging: charging power as a fraction of the charger's rating"),
    ActionRange("pulse_duty", "1", 0.2, 1.0,
                "ECO-charging: pulse duty cycle (1: continuous charging)"),
)
ACTION_NAMES = tuple(r.name for r in ACTIONS)
ACTION_LOW = np.array([r.low for r in ACTIONS])
ACTION_SPAN = np.array([r.high - r.low for r in ACTIONS])


def checked_actions(actions, shape: tuple[int, ...], names: list[str], env: str) -> np.ndarray:
    """Actions as float64 of ``shape``, each finite and in [-1, 1], or a clear error naming
    the first bad one (``names`` along the last axis)."""
    a = np.asarray(actions, dtype=np.float64)
    if a.shape == shape and a.size:  # the common case, quickly (NaN fails every comparison)
        if a.size <= 16:  # one bus: Python's comparisons beat two numpy reductions (1.6 vs 5 us)
            if all(-1.0 <= x <= 1.0 for x in a.ravel().tolist()):
                return a
        elif -1.0 <= a.min() and a.max() <= 1.0:
            return a
    if a.shape != shape:
        raise ActionError(f"Action has shape {a.shape}; {env} takes {shape} ({', '.join(names)}),"
                         " each in [-1, 1].")
    bad = ~np.isfinite(a) | (a < -1.0 - 1e-6) | (a > 1.0 + 1e-6)
    if bad.any():
        i = np.unravel_index(int(np.flatnonzero(bad)[0]), a.shape)
        where = ", ".join(str(int(k)) for k in i)
        raise ActionError(f"Action [{where}] ({names[i[-1]]}) = {a[i]}: every action must be a "
                         f"finite number in [-1, 1] (the env maps it onto its range).")
    return np.clip(a, -1.0, 1.0)


def physical(actions: np.ndarray) -> np.ndarray:
    """Checked actions (..., 5) in [-1, 1] -> values in the units of ``ACTIONS``; -1 and 1
    give exactly low and high (a pulse duty of exactly 1 is continuous charging)."""
    return ACTION_LOW + 0.5 * (actions + 1.0) * ACTION_SPAN


@dataclass(frozen=True)
class EnvConfig:
    """Everything that defines an episode (``configs/env/*.yaml`` hold these keys)."""

    bus: str = "12m"  # name in configs/bus or a path
    overlay: str | None = None  # a calibrated overlay (``ebus calibrate --out``)
    cycle: str | None = "sort2"  # laps of a cycle, or
    route: str | None = None  # a King County route (``kc45_out``...), or
    log: str | None = None  # a measured log (CSV/Parquet): its speed profile is one trip
    log_columns: str | dict | None = None  # the log's column map or preset (configs/logs)
    laps_per_trip: int | None = None  # cycle laps between terminal layovers (None: ~1 h)
    service_h: float = 13.5
    start_time_h: float = 5.0
    decision_s: float = 60.0  # a decision's length (with decide_at_stops: the longest)
    decide_at_stops: bool = False  # decide at each departure (stop-to-stop segments, layovers)
    dt_s: float = 0.1
    soc_start_pct: float = 95.0
    reserve_soc_pct: float = 20.0
    layover_min: float = 6.0  # scheduled layover at the terminal, on the charger
    min_layover_min: float = 2.0  # the shortest layover (plugging in and out)
    charger_kw: float | None = None  # terminal charger rating (None: the bus's charger)
    charge_at_terminal: bool = True
    climate: str | dict | None = None  # monthly normals (ebus_env.envs.climate), with month
    month: int | None = None  # 1-12: the climate's month (sets the two ambient keys below)
    ambient_mean_degc: float | None = None  # daily mean (default 15 without a climate)
    ambient_amplitude_k: float | None = None  # half the daily swing (coldest 05:00,
    # warmest 15:00; default 4 without a climate)
    ambient_random_k: float = 2.0  # daily mean drawn +- this per episode
    passengers_base_frac: float = 0.2  # of capacity, between peaks
    passengers_peak_frac: float = 0.8  # at the morning and evening peaks
    passengers_random_frac: float = 0.15  # each drawn +- this per episode
    jerk_mps3: float = 1.0  # ramp of the acceleration (paper App. B.1)
    comfort_decel_mps2: float = 1.0  # braking towards stops
    reward: dict | Reward = field(default_factory=dict)  # weights of Reward, or one

    def __post_init__(self):
        mean, amplitude = self.ambient_mean_degc, self.ambient_amplitude_k
        if self.climate is not None or self.month is not None:
            if self.climate is None or self.month is None:
                raise ConfigError("climate and month go together: e.g. climate: barcelona, "
                                  "month: 7.")
            if mean is not None or amplitude is not None:
                raise ConfigError("Give either climate and month or ambient_mean_degc and "
                                  "ambient_amplitude_k, not both (the climate sets them).")
            mean, amplitude = climate_of(self.climate).ambient(self.month)
        object.__setattr__(self, "ambient_mean_degc", 15.0 if mean is None else float(mean))
        object.__setattr__(self, "ambient_amplitude_k",
                           4.0 if amplitude is None else float(amplitude))
        for key, name in ENV_KEYS.items():
            if getattr(self, key) is not None:
                value = getattr(self, key)
                check(name, value, f"env config {key}")
                if key == "laps_per_trip" and float(value) != int(float(value)):
                    raise ConfigError(f"env config laps_per_trip = {value!r} must be a whole "
                                      "number.")
                kind = int if key == "laps_per_trip" else float
                object.__setattr__(self, key, kind(float(value)))  # "1e3" read from YAML
        for key in ("bus", "overlay", "cycle", "route", "log"):
            if not isinstance(getattr(self, key), (str, Path, type(None))):
                raise ConfigError(f"env config {key} = {getattr(self, key)!r} must name a "
                                  "config or file.")
        if not isinstance(self.reward, (dict, Reward)):
            raise ConfigError(f"env config reward = {self.reward!r} must map reward terms to "
                              "weights (or be a Reward).")
        for key in ("decide_at_stops", "charge_at_terminal"):
            if not isinstance(getattr(self, key), bool):
                raise ConfigError(f"env config {key} = {getattr(self, key)!r} must be true or "
                                  "false.")
        if self.min_layover_min > self.layover_min:
            raise ConfigError(f"env config min_layover_min = {self.min_layover_min:g} is longer "
                              f"than layover_min = {self.layover_min:g}.")

    @classmethod
    def load(cls, source: str | Path | dict | None = None, **overrides) -> EnvConfig:
        """From a name in ``configs/env``, a YAML path or a mapping, with overrides."""
        return cls(**config_keys(cls, source, overrides, "env"))


def config_keys(cls, source: str | Path | dict | None, overrides: dict, kind: str,
                folder: Path = CONFIG_DIR) -> dict:
    """The keys of a config dataclass ``cls`` from a mapping, a YAML path or a name in
    ``folder``, with overrides on top; a missing file or an unknown key is a clear error."""
    data: dict = {}
    if isinstance(source, dict):
        data = dict(source)
    elif source is not None:
        path = paths.here_or_shipped(source)  # configs/env/x.yaml from any folder too
        if not path.suffix:
            path = folder / f"{source}.yaml"
        if not path.exists():
            names = sorted(p.stem for p in folder.glob("*.yaml"))
            raise ConfigError(f"No {kind} config '{source}' (looked for {path}); shipped: "
                              f"{', '.join(names)}.")
        data = read_yaml(path)  # bad YAML or a duplicated key: a ConfigError with the line
    data.update(overrides)
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(f"Unknown {kind} config key(s) {unknown}; known: {sorted(known)}.")
    return data


def spaces() -> tuple[gym.spaces.Box, gym.spaces.Box]:
    """Action and observation space of one bus."""
    return (gym.spaces.Box(-1.0, 1.0, (len(ACTIONS),), np.float32),
            gym.spaces.Box(OBS_LOW, OBS_HIGH, dtype=np.float32))


def reward_of(cfg: EnvConfig) -> Reward:
    """The config's reward: a :class:`Reward` instance as is, a dict as its weights."""
    if isinstance(cfg.reward, Reward):
        return cfg.reward
    known = {f.name for f in fields(Reward) if f.init}
    unknown = sorted(set(cfg.reward) - known)
    if unknown:
        raise ConfigError(f"Unknown reward weight(s) {unknown}; known: {sorted(known)}.")
    return Reward(**cfg.reward)


def decision_info(out, scored, costs, kwh, values, energy_terms) -> dict:
    """``info`` of a decision, the one builder of every env: figures with units (``OUT``, then
    the battery's mean power and the mean speed), the scored quantities (``SCORED``), the
    reward terms, the energy breakdown [kWh] by ``energy_terms`` and the actions in their
    units. Each argument holds one value per name: Python floats for one bus (``bus_info``),
    arrays over the buses for a batch (``batch_info``)."""
    info = dict(zip(OUT, out, strict=True))
    hours = info["duration_s"] / 3600.0
    info["battery_kw"] = info["battery_kwh"] / hours
    info["speed_kmh_mean"] = info["distance_km"] / hours
    info.update(zip(SCORED, scored, strict=True))
    info["reward_terms"] = dict(zip(TERMS, costs, strict=True))
    info["breakdown_kwh"] = dict(zip(energy_terms, kwh, strict=True))
    info["actions"] = dict(zip(ACTION_NAMES, values, strict=True))
    return info


def bus_info(buses: BusBatch, b: int, values: np.ndarray, costs: np.ndarray) -> dict:
    """``info`` of bus ``b``'s last decision, in Python floats (``values``, ``costs``: its
    actions in their units and reward terms), with why its service ended (``ended_by``)."""
    info = decision_info(buses.out[b].tolist(), buses.quantities[b, -len(SCORED):].tolist(),
                         costs.tolist(), buses.breakdown_kwh(b).values(), values.tolist(),
                         buses.energy_terms)
    info["ended_by"] = buses.end_reason(b)
    return info


def batch_info(buses: BusBatch, values: np.ndarray, costs: np.ndarray) -> dict:
    """``info`` of every bus's last decision, arrays (n,) (``values`` (n, 5), ``costs``
    (n, terms)); ``ended_by`` only where a bus's service ended."""
    info = decision_info(buses.out.T.copy(), buses.quantities[:, -len(SCORED):].T.copy(),
                         costs.T, buses.breakdown_matrix_kwh().T, values.T, buses.energy_terms)
    info["ended_by"] = np.array([buses.end_reason(b) for b in range(buses.n)], object)
    return info


IN_INFO = [(k, o) for k, o in enumerate(OBSERVATIONS) if o[0] in OUT]
"""Observations whose true value ``info`` carries (from ``OUT``), checked against the bounds."""


def clipped_observations(info: dict, warned: set[str]) -> dict[str, np.ndarray]:
    """Whether each observation of ``IN_INFO`` holds its bound (its true value in ``info``, a
    float or an array over the sub-envs, lies beyond it), a bool or a bool array per name;
    warns once per name not yet in ``warned`` (and adds it)."""
    flags = {}
    for k, (name, unit, low, high) in IN_INFO:
        true = np.asarray(info[name])
        beyond = ~((true >= low) & (true <= high))  # NaN too
        flags[name] = beyond
        if name not in warned and beyond.any():
            warned.add(name)
            where = f" in sub-env {np.flatnonzero(beyond)[0]}" if true.ndim else ""
            first = float(true[beyond][0]) if true.ndim else float(true)
            gym.logger.warn(f"observation {k} ({name}) holds its bound{where}: the true value "
                            f"is {first:.1f}{with_unit('', unit)}, outside [{low:g}, {high:g}] "
                            f"(info['{name}'] has it).")
    return flags
