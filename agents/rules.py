"""Rule-based ECO policies (the paper's ECO strategies, Hasan et al. 2023, App. B).

Each rule acts on ``EBus-v0`` observations, one row per bus, and returns actions in
[-1, 1] (mapped by the env onto ``ACTIONS``):

* baseline: no ECO feature: no speed or acceleration cap (80 km/h, 1.5 m/s^2), a fixed
  setpoint (21 degC), charging at full power, continuously;
* ECO-driving (App. B.1): caps the top speed and the acceleration (jerk-limited in the env);
* ECO-comfort (App. B.2, docs/physics.md §10.2): the setpoint follows ambient temperature and
  occupancy; on the charger the cabin is preconditioned to it with grid power (the env's
  cabin runs from the charger while connected)::

      T_amb < 15 degC:   T_set = max(17, 20 - occ)          occ = passengers / capacity
      15 - 22 degC:      T_set = T_amb + 2
      T_amb > 22 degC:   T_set = min(27, max(22 + 0.33 (T_amb - 22), T_amb - 7))

* ECO-charging (App. B.3): pulsed charging at ``charge_power_frac``, the duty falling
  linearly from 1 (continuous) at SoC ``pulse_full_below_soc`` to ``pulse_duty`` at
  ``pulse_lightest_soc``: a full pack takes light pulses (a lower grid peak), an emptier one
  the full power (a pulsed layover delivers less energy, and a bus whose layovers
  ECO-driving shortened must not run down its pack for a lower peak).

The coefficients are parametrisations (docs/physics.md §10), exposed as fields.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import VectorEnv
from numpy.typing import ArrayLike

from agents.policy import PolicyState
from ebus_env.envs.batch import OBSERVATIONS, BusBatch
from ebus_env.envs.common import ACTION_LOW, ACTION_SPAN, ACTIONS
from ebus_env.errors import ConfigError

OBS = {o[0]: i for i, o in enumerate(OBSERVATIONS)}
N_ACT = len(ACTIONS)


def normalised(values: np.ndarray) -> np.ndarray:
    """Physical action values (..., 5) -> [-1, 1] (the inverse of the env's mapping)."""
    return np.clip(2.0 * (values - ACTION_LOW) / ACTION_SPAN - 1.0, -1.0, 1.0).astype(np.float32)


def eco_setpoint_degc(ambient_degc: np.ndarray, occupancy: np.ndarray) -> np.ndarray:
    """ECO-comfort setpoint (docs/physics.md §10.2) from ambient [degC] and occupancy [0-1]."""
    heating = np.maximum(17.0, 20.0 - 1.0 * np.clip(occupancy, 0.0, 1.0))
    neutral = ambient_degc + 2.0
    cooling = np.minimum(27.0, np.maximum(22.0 + 0.33 * (ambient_degc - 22.0), ambient_degc - 7.0))
    return np.where(ambient_degc < 15.0, heating, np.where(ambient_degc <= 22.0, neutral, cooling))


@dataclass(frozen=True)
class RulePolicy:
    """A rule-based policy: the baseline with any of the three ECO features switched on."""

    name: str = "baseline"
    eco_driving: bool = False
    eco_comfort: bool = False
    eco_charging: bool = False
    capacity: float = 85.0  # passengers, for the occupancy (the env's bus: ``for_env``)
    speed_cap_kmh: float = 40.0  # ECO-driving caps (docs/physics.md §10.1)
    accel_cap_mps2: float = 0.7
    baseline_setpoint_degc: float = 21.0
    pulse_duty: float = 0.3  # ECO-charging (docs/physics.md §10.3)
    pulse_full_below_soc: float = 0.6
    pulse_lightest_soc: float = 0.9
    charge_power_frac: float = 1.0

    def values(self, obs: np.ndarray) -> np.ndarray:
        """Actions in physical units (n, 5) for observations (n, 16)."""
        n = obs.shape[0]
        out = np.empty((n, N_ACT))
        out[:, 0] = self.speed_cap_kmh if self.eco_driving else 80.0
        out[:, 1] = self.accel_cap_mps2 if self.eco_driving else 1.5
        if self.eco_comfort:
            occupancy = obs[:, OBS["passengers"]] / self.capacity
            out[:, 2] = eco_setpoint_degc(obs[:, OBS["ambient_degc"]], occupancy)
        else:
            out[:, 2] = self.baseline_setpoint_degc
        out[:, 3] = self.charge_power_frac if self.eco_charging else 1.0
        out[:, 4] = 1.0
        if self.eco_charging:
            x = (obs[:, OBS["soc"]] - self.pulse_full_below_soc) / (
                self.pulse_lightest_soc - self.pulse_full_below_soc)
            out[:, 4] = 1.0 - (1.0 - self.pulse_duty) * np.clip(x, 0.0, 1.0)
        return out

    def for_env(self, env: gym.Env | VectorEnv | BusBatch) -> RulePolicy:
        """This rule for the bus of ``env`` (``EBus-v0``, its vector env or their ``buses``):
        its passenger capacity."""
        from ebus_env.envs.ebus import EBusEnv
        from ebus_env.envs.vector import EBusVectorEnv

        bus_env = env if isinstance(env, BusBatch) else env.unwrapped
        if not isinstance(bus_env, BusBatch | EBusEnv | EBusVectorEnv):
            raise ConfigError(f"A rule is for EBus-v0, its vector env or their buses, not "
                              f"{type(bus_env).__name__}.")
        buses = bus_env if isinstance(bus_env, BusBatch) else bus_env.buses
        return replace(self, capacity=buses.capacity)

    def predict(self, obs: ArrayLike, state: PolicyState = None,
                episode_start: np.ndarray | None = None,
                deterministic: bool = True) -> tuple[np.ndarray, PolicyState]:
        """Actions for one observation (16,) or a batch (n, 16), as stable-baselines3's."""
        obs = np.asarray(obs, dtype=np.float64)
        actions = normalised(self.values(np.atleast_2d(obs)))
        return (actions[0] if obs.ndim == 1 else actions), state


RULES = {
    "baseline": {},
    "eco_driving": {"eco_driving": True},
    "eco_comfort": {"eco_comfort": True},
    "eco_charging": {"eco_charging": True},
    "eco_all": {"eco_driving": True, "eco_comfort": True, "eco_charging": True},
}


def rule(name: str, capacity: float = 85.0, **fields: Any) -> RulePolicy:
    """A rule by name (``RULES``), for a bus of ``capacity`` passengers."""
    if name not in RULES:
        raise ConfigError(f"No rule '{name}'; rules: {', '.join(RULES)}.")
    return RulePolicy(name=name, capacity=capacity, **{**RULES[name], **fields})


FLEET_RULES = ("greedy", "balanced", "peak_shaving")


@dataclass(frozen=True)
class FleetChargingRule:
    """Charging rules for ``EBusFleet-v0`` (the vocabulary of charging-strategy simulators);
    driving and comfort come from ``per_bus`` (a :class:`RulePolicy`, baseline by default).

    * greedy: every plugged bus asks for its charger's full power (the site scales all
      down together when the sum passes its limit);
    * balanced: each plug's share of the site, ``P_site / chargers``, scaled by the bus's need
      against the fleet's mean need, ``(1 - SoC_b) / mean(1 - SoC)``;
    * peak_shaving: each plug gets an equal share of ``target_frac`` of the site limit,
      except a bus below ``floor_soc``, which takes full power.

    Shares go to every bus, plugged or not: a bus that plugs in during the decision then
    charges at its share, not at full power.
    """

    name: str = "greedy"
    n_buses: int = 1
    charger_kw: float = 450.0
    site_limit_kw: float = 600.0
    chargers: int = 2
    efficiency: float = 0.95
    target_frac: float = 0.5
    floor_soc: float = 0.4
    per_bus: RulePolicy = RulePolicy()

    @classmethod
    def for_env(cls, env: gym.Env, name: str = "greedy", **fields: Any) -> FleetChargingRule:
        """This rule for a fleet env: its buses, charger rating, site limit and efficiency."""
        from ebus_env.envs.fleet import EBusFleetEnv

        u = env.unwrapped
        if not isinstance(u, EBusFleetEnv):
            raise ConfigError(f"A fleet charging rule is for EBusFleet-v0, not "
                              f"{type(u).__name__}.")
        line = u.lines[0]
        return cls(name=name, n_buses=u.n, charger_kw=line.charger_w / 1e3,
                   site_limit_kw=u.config.site_limit_kw, chargers=u.config.chargers,
                   efficiency=float(u.efficiency[0]),
                   per_bus=replace(RulePolicy(), capacity=line.capacity), **fields)

    def predict(self, obs: ArrayLike, state: PolicyState = None,
                episode_start: np.ndarray | None = None,
                deterministic: bool = True) -> tuple[np.ndarray, PolicyState]:
        obs = np.asarray(obs, dtype=np.float64)
        buses = obs[:self.n_buses * len(OBS)].reshape(self.n_buses, len(OBS))
        values = self.per_bus.values(buses)
        soc = buses[:, OBS["soc"]]
        # a plug's share of what the site can feed (charger output)
        share = self.site_limit_kw * self.efficiency / self.chargers / self.charger_kw
        frac = np.ones(self.n_buses)
        if self.name == "balanced":
            need = np.maximum(1.0 - soc, 1e-3)
            frac = share * need / need.mean()
        elif self.name == "peak_shaving":
            frac = np.where(soc < self.floor_soc, 1.0, self.target_frac * share)
        elif self.name not in FLEET_RULES:
            raise ConfigError(f"No fleet charging rule '{self.name}'; rules: "
                              f"{', '.join(FLEET_RULES)}.")
        values[:, 3] = np.clip(frac, ACTIONS[3].low, ACTIONS[3].high)
        return normalised(values).ravel(), state
