"""``EBusFleet-v0``: buses on one or more lines sharing a terminal's chargers and its grid
connection, driven by one central agent."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import ArrayLike

from ebus_env.envs.batch import OBS_HIGH, OBS_LOW, OBSERVATIONS, BusBatch
from ebus_env.envs.charging_site import ChargingSite
from ebus_env.envs.common import (
    ACTIONS,
    EnvConfig,
    bus_info,
    checked_actions,
    config_keys,
    physical,
    reward_of,
)
from ebus_env.envs.reward import TERMS
from ebus_env.errors import ConfigError, EnvError

SITE_OBSERVATIONS = (  # name, unit, low, high
    ("site_grid_kw", "kW", 0.0, 1e4),
    ("site_peak_kw", "kW", 0.0, 1e4),
    ("chargers_free", "1", 0.0, 100.0),
    ("buses_waiting", "1", 0.0, 100.0),
)
SHARED = ("decision_s", "dt_s", "start_time_h", "service_h")  # the same on every line


@dataclass(frozen=True)
class FleetConfig:
    """A site: lines of buses (each an env config of ``configs/env``, a path or a dict of
    :class:`EnvConfig` keys, with ``buses``: how many run it) and the terminal they share:
    ``chargers`` plugs and a grid connection of ``site_limit_kw``."""

    lines: tuple = ({"config": "sort2_day", "buses": 6},)
    chargers: int = 2
    site_limit_kw: float = 600.0
    reward: dict | None = None  # weights of Reward (None: the first line's)

    @classmethod
    def load(cls, source: str | Path | dict | None = None, **overrides: Any) -> FleetConfig:
        data = config_keys(cls, source, overrides, "fleet")
        if "lines" in data:
            data["lines"] = tuple(data["lines"])
        out = cls(**data)
        for i, line in enumerate(out.lines):
            if not isinstance(line, dict) or int(line.get("buses", 0)) < 1:
                raise ConfigError(f"lines[{i}] = {line!r}: each line is a mapping with "
                                  "'buses' >= 1 and optionally 'config' and EnvConfig keys.")
        if out.chargers < 1 or out.site_limit_kw <= 0.0:
            raise ConfigError(f"chargers = {out.chargers} and site_limit_kw = "
                              f"{out.site_limit_kw} must be positive.")
        return out

    def line_configs(self) -> list[tuple[EnvConfig, int]]:
        out = []
        for line in self.lines:
            keys = dict(line)
            n = int(keys.pop("buses"))
            out.append((EnvConfig.load(keys.pop("config", None), **keys), n))
        first = out[0][0]
        for i, (cfg, _) in enumerate(out):
            if cfg.decide_at_stops:
                raise ConfigError(f"lines[{i}]: decide_at_stops is for EBus-v0; a fleet's central "
                                  "agent decides for every bus at once, every decision_s.")
        for cfg, _ in out[1:]:
            for key in SHARED:
                if getattr(cfg, key) != getattr(first, key):
                    raise ConfigError(f"Every line of a fleet needs the same {key} (the site "
                                      f"runs one clock): {getattr(cfg, key)} vs "
                                      f"{getattr(first, key)}.")
        return out


class EBusFleetEnv(gym.Env[np.ndarray, np.ndarray]):
    """Battery-electric buses on one or more lines sharing a terminal's chargers and its grid
    connection, with ECO actions per bus chosen by one central agent.

    ## Description
    Each line (an ``EBus-v0`` config) runs ``buses`` buses at equal headways: bus ``k`` first
    departs ``k`` lap periods / ``buses`` after the start of service and waits on the
    terminal until then. All lines end at one terminal with ``chargers`` plugs behind a grid
    connection of ``site_limit_kw``: a bus on its layover takes a free plug first come, first
    served (or waits, not charging); the plugged buses' charger ratings are scaled down
    together whenever their grid draw would exceed the site limit, at every 10 Hz step. Each
    bus is the single env's physics (:class:`ebus_env.envs.batch.BusBatch`).

    ## Action Space
    ``Box(-1, 1, (5 n,), float32)``: bus ``b``'s five ``EBus-v0`` actions (speed cap,
    acceleration cap, setpoint, charging power fraction, pulse duty) at ``5 b .. 5 b + 4``;
    names in ``env.action_names``.

    ## Observation Space
    ``Box(float32, (16 n + 4,))``: each bus's 16 ``EBus-v0`` observations in turn (charger
    connected: holding a plug), then the site's grid power over the last decision [kW], its
    peak so far [kW], free chargers and buses waiting for one; names in
    ``env.observation_names``.

    ## Rewards
    One reward for the site: the sum over buses of the ``Reward`` terms, with the peak term
    on the *site's* peak grid power (its rise, [kW]): the demand charge of the connection.

    ## Starting State
    Service starts at ``start_time_h``: bus 0 of each line departs, the others wait on the
    charger; each bus's day (ambient mean, passengers) is drawn from the seed in turn.

    ## Episode End
    Terminated at the end of service or when any bus's battery is empty. Truncation:
    TimeLimit of 10,000 decisions (``gymnasium.make``).

    ## Arguments
    ``gymnasium.make("EBusFleet-v0", config="fleet_sort2", chargers=2, site_limit_kw=600)``:
    ``config`` names a file in ``configs/env`` (or a path or a dict) of :class:`FleetConfig`.
    ``info["site_load_kw"]``: the site's grid power per decision so far [kW];
    ``info["buses"]``: each bus's ``EBus-v0`` info.
    ``render_mode``: only ``None`` (``metadata["render_modes"]`` is empty: the fleet does not
    render; ``info`` holds the site's load and each bus's figures).

    ## Version History
    * v0: first version.
    """

    metadata: dict[str, Any] = {"render_modes": []}
    action_space: gym.spaces.Box
    observation_space: gym.spaces.Box

    def __init__(self, config: str | Path | dict | None = None, render_mode: str | None = None,
                 **overrides: Any) -> None:
        if render_mode is not None:
            raise ConfigError(f"render_mode '{render_mode}': EBusFleet-v0 has no render modes "
                              f"(metadata render_modes is {self.metadata['render_modes']}); leave "
                              "render_mode out (None) and read the site's load from "
                              "info['site_load_kw'] and each bus's figures from info['buses'].")
        self.render_mode = render_mode
        self.config = cfg = FleetConfig.load(config, **overrides)
        lines: list[BusBatch] = []
        for line_cfg, n in cfg.line_configs():
            line = BusBatch(line_cfg, n)
            line.offsets_s = np.arange(n) * line.lap_period_s / n  # equal headways
            lines.append(line)
        self.site = ChargingSite(lines, cfg.chargers, cfg.site_limit_kw)
        self.lines = lines
        self.env_config = lines[0].config
        self.n = self.site.n
        self.efficiency = self.site.efficiency  # each bus's charger efficiency
        self.reward_fn = reward_of(EnvConfig(reward=cfg.reward) if cfg.reward is not None
                                   else self.env_config)
        self.action_names = [f"bus{b}.{a.name}" for b in range(self.n) for a in ACTIONS]
        self.observation_names = [f"bus{b}.{o[0]}" for b in range(self.n)
                                  for o in OBSERVATIONS] + [o[0] for o in SITE_OBSERVATIONS]
        self.action_space = gym.spaces.Box(-1.0, 1.0, (len(ACTIONS) * self.n,), np.float32)
        self.observation_space = gym.spaces.Box(
            np.concatenate([np.tile(OBS_LOW, self.n), [o[2] for o in SITE_OBSERVATIONS]]
                           ).astype(np.float32),
            np.concatenate([np.tile(OBS_HIGH, self.n), [o[3] for o in SITE_OBSERVATIONS]]
                           ).astype(np.float32), dtype=np.float32)
        self._edges = self.site.edges
        self._started = self._ended = False

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self.site.reset(self.np_random)
        self._site_kw: list[float] = []
        self._peak_kw = 0.0
        self._started, self._ended = True, False
        return self._observe(), {"observation_names": self.observation_names}

    def step(self, action: ArrayLike) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if not self._started:
            raise EnvError("Call reset() before step().")
        if self._ended:
            raise EnvError("step() after the episode ended (terminated): call reset() to "
                           "start a new day.")
        values = physical(checked_actions(action, self.action_space.shape, self.action_names,
                                          "EBusFleet-v0").reshape(self.n, len(ACTIONS)))
        self.site.step(values)
        quantities = np.concatenate([line.quantities for line in self.lines])
        _, bus_costs = self.reward_fn(quantities)
        site_kw = float(self.site.column("grid_kw").sum())
        rise_kw = max(site_kw - self._peak_kw, 0.0)
        self._peak_kw = max(self._peak_kw, site_kw)
        self._site_kw.append(site_kw)
        site = quantities.sum(axis=0)
        site[2] = rise_kw  # the demand charge is the site's
        reward, costs = self.reward_fn(site[None])
        ended = [line.ended() for line in self.lines]
        depleted = any(d.any() for d, _ in ended)
        terminated = self._ended = bool(depleted or all(e.all() for _, e in ended))
        info: dict[str, Any] = {"reward_terms": dict(zip(TERMS, costs[0].tolist(), strict=True)),
                "site_grid_kw": site_kw, "site_peak_kw": self._peak_kw,
                "site_limit_kw": self.config.site_limit_kw,
                "site_load_kw": np.array(self._site_kw), "depleted": depleted,
                "grid_kwh": float(site[1]), "battery_kwh": float(site[0]),
                "buses": [bus_info(line, b, values[lo + b], bus_costs[lo + b])
                          for line, lo in zip(self.lines, self._edges[:-1], strict=True)
                          for b in range(line.n)]}
        info["ended_by"] = "; ".join(f"bus {i}: {bus['ended_by']}" for i, bus in
                                     enumerate(info["buses"]) if bus["empty"]) if depleted \
            else "end of service" if terminated else ""
        return self._observe(), float(reward[0]), terminated, False, info

    def render(self) -> None:
        gym.logger.warn("EBusFleet-v0 does not render (metadata render_modes is empty): the "
                        "site's load is in info['site_load_kw'], each bus's figures in "
                        "info['buses'].")
        return None

    def _observe(self) -> np.ndarray:
        buses = self.site.observations()  # "charger connected": holding a plug
        free = self.config.chargers - int(self.site.plugged.sum())
        site = np.array([self._site_kw[-1] if self._site_kw else 0.0, self._peak_kw, free,
                         self.site.waiting()], np.float32)
        obs = np.concatenate([buses.ravel(), site]).astype(np.float32)
        return np.clip(obs, self.observation_space.low, self.observation_space.high)
