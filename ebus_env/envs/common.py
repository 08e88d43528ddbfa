"""What every env of the package shares: the actions and their ranges, the spaces, the
episode config (:class:`EnvConfig`, ``configs/env/*.yaml``, kept in
:mod:`ebus_env.envs.env_config` and named here too) and the one ``info`` builder."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, fields
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import ArrayLike

from ebus_env.envs.batch import OBS_HIGH, OBS_LOW, OBSERVATIONS, OUT, BusBatch
from ebus_env.envs.env_config import CONFIG_DIR as CONFIG_DIR
from ebus_env.envs.env_config import EnvConfig as EnvConfig
from ebus_env.envs.env_config import config_keys as config_keys
from ebus_env.envs.reward import TERMS, Reward
from ebus_env.errors import ActionError, ConfigError
from ebus_env.units import with_unit

PerName = Iterable[float] | Iterable[np.ndarray]
"""Values in the order of their names: floats for one bus, arrays over the buses for a batch."""
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


def checked_actions(actions: ArrayLike, shape: tuple[int, ...], names: list[str], env: str
                    ) -> np.ndarray:
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


def decision_info(out: PerName, scored: PerName, costs: PerName, kwh: PerName, values: PerName,
                  energy_terms: list[str]) -> dict[str, Any]:
    """``info`` of a decision, the one builder of every env: figures with units (``OUT``, then
    the battery's mean power and the mean speed), the scored quantities (``SCORED``), the
    reward terms, the energy breakdown [kWh] by ``energy_terms`` and the actions in their
    units. Each argument holds one value per name: Python floats for one bus (``bus_info``),
    arrays over the buses for a batch (``batch_info``)."""
    info: dict[str, Any] = dict(zip(OUT, out, strict=True))
    hours = info["duration_s"] / 3600.0
    info["battery_kw"] = info["battery_kwh"] / hours
    info["speed_kmh_mean"] = info["distance_km"] / hours
    info.update(zip(SCORED, scored, strict=True))
    info["reward_terms"] = dict(zip(TERMS, costs, strict=True))
    info["breakdown_kwh"] = dict(zip(energy_terms, kwh, strict=True))
    info["actions"] = dict(zip(ACTION_NAMES, values, strict=True))
    return info


def bus_info(buses: BusBatch, b: int, values: np.ndarray, costs: np.ndarray) -> dict[str, Any]:
    """``info`` of bus ``b``'s last decision, in Python floats (``values``, ``costs``: its
    actions in their units and reward terms), with why its service ended (``ended_by``)."""
    info = decision_info(buses.out[b].tolist(), buses.quantities[b, -len(SCORED):].tolist(),
                         costs.tolist(), buses.breakdown_kwh(b).values(), values.tolist(),
                         buses.energy_terms)
    info["ended_by"] = buses.end_reason(b)
    return info


def batch_info(buses: BusBatch, values: np.ndarray, costs: np.ndarray) -> dict[str, Any]:
    """``info`` of every bus's last decision, arrays (n,) (``values`` (n, 5), ``costs``
    (n, terms)); ``ended_by`` only where a bus's service ended."""
    info = decision_info(buses.out.T.copy(), buses.quantities[:, -len(SCORED):].T.copy(),
                         costs.T, buses.breakdown_matrix_kwh().T, values.T, buses.energy_terms)
    info["ended_by"] = np.array([buses.end_reason(b) for b in range(buses.n)], object)
    return info


IN_INFO = [(k, o) for k, o in enumerate(OBSERVATIONS) if o[0] in OUT]
"""Observations whose true value ``info`` carries (from ``OUT``), checked against the bounds."""


def clipped_observations(info: dict[str, Any], warned: set[str]) -> dict[str, np.ndarray]:
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
