"""``EBus-v0``: one battery-electric bus through one service day, with ECO actions."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import ArrayLike

from ebus_env.envs.batch import OBSERVATIONS, S_SOC, BusBatch
from ebus_env.envs.common import (
    ACTION_NAMES,
    EnvConfig,
    bus_info,
    checked_actions,
    clipped_observations,
    physical,
    reward_of,
    spaces,
)
from ebus_env.errors import ConfigError, EnvError


class EBusEnv(gym.Env[np.ndarray, np.ndarray]):
    """One battery-electric bus through one service day, with ECO-driving, ECO-comfort and
    ECO-charging actions.

    ## Description
    The bus drives laps of a line (a standard cycle, a King County route, or a measured log's
    speed profile, described by distance: stops stay where they are) for a service day, with
    a layover on the terminal's charger after each trip, through a day of ambient temperature
    and passengers that rise to morning and evening peaks. Each agent step is one decision
    interval: ``decision_s`` (60 s), or with ``decide_at_stops`` one stop-to-stop segment
    (from a departure to the next, driving and dwelling) or a layover, at most ``decision_s``
    (longer ones are split). Inside it the compiled Lo-Fi model (:mod:`ebus_env.model`)
    advances the physics at ``dt_s`` (10 Hz): powertrain, battery, CC/CV charging, cabin HVAC.
    ``info["duration_s"]`` holds the decision's length.

    ## Action Space
    ``Box(-1, 1, (5,), float32)``, each mapped linearly onto its range:

    | index | action | range | unit |
    |---|---|---|---|
    | 0 | ECO-driving: speed cap | 20 - 80 | km/h |
    | 1 | ECO-driving: acceleration cap (jerk-limited ramp, 1 m/s^3) | 0.3 - 1.5 | m/s^2 |
    | 2 | ECO-comfort: cabin setpoint | 14 - 28 | degC |
    | 3 | ECO-charging: charging power, fraction of the charger's rating | 0.1 - 1 | 1 |
    | 4 | ECO-charging: pulse duty cycle (period 10 s; 1 = continuous) | 0.2 - 1 | 1 |

    Capped driving keeps the distance: the bus stops at the same stops and takes longer;
    the delay is absorbed by the layover's slack (``layover_min - min_layover_min``) before
    it costs reward. The HVAC power follows from the cabin model and the setpoint; the cabin
    is preconditioned from the grid while on the charger. Charging actions act while
    connected; CC/CV behaviour comes from the model.

    ## Observation Space
    ``Box(float32)`` with finite bounds; names in ``env.observation_names``:

    | index | observation | unit |
    |---|---|---|
    | 0 | state of charge | 1 |
    | 1 | cabin temperature | degC |
    | 2 | ambient temperature | degC |
    | 3 | passengers on board | 1 |
    | 4 | speed | km/h |
    | 5 | time of day | h |
    | 6 | distance to the charger (the terminal) | km |
    | 7 | schedule delay (negative: early) | min |
    | 8 | charger connected | 1 |
    | 9 | the line's reference speed here | km/h |
    | 10 | road grade here | % |
    | 11 | service left | h |
    | 12, 13 | comfort band, low and high | degC |
    | 14 | the day's peak grid power so far (decision means; what the peak term charges) | kW |
    | 15 | layover left before the timetable's departure (0 while driving) | min |

    ## Rewards
    ``-(cost)`` of :class:`ebus_env.envs.reward.Reward`: battery energy [kWh], grid energy
    [kWh], rise of the peak grid power [kW], comfort violation [K h], delay at departures
    [min], SoC below the reserve [%-points h], service lost to an empty battery [h], each
    with a documented weight. ``info`` holds
    each term, the step's energy breakdown [kWh] and the grid power [kW].

    ## Starting State
    At the first departure, ``start_time_h``, SoC ``soc_start_pct``, the cabin at its
    setpoint; the day's mean ambient and the passenger base and peak are drawn from the
    seed.

    ## Episode End
    Terminated at the end of service (``service_h``) or when the battery is empty (SoC at the
    pack's floor ``soc_min_frac``, or a demand it cannot deliver): the service hours left are
    charged as lost service. Truncation: ``gymnasium.make`` adds a TimeLimit of
    10,000 decisions (``max_episode_steps``; a 24 h day of 10 s decisions fits).

    ## Arguments
    ``gymnasium.make("EBus-v0", config="kc45_hilly", **overrides)``: ``config`` names a
    file in ``configs/env`` (or a path or a dict); overrides are :class:`EnvConfig` keys
    (``bus``, ``overlay``, ``cycle``/``route``/``log``, ``service_h``, ``decision_s``,
    ``decide_at_stops``, ``climate`` and ``month``, ``ambient_mean_degc``, ``reward``
    (weights, or a :class:`Reward`), ...).
    ``render_mode``: ``"rgb_array"`` or ``"human"``.
    ``gymnasium.make_vec("EBus-v0", num_envs=64, ...)`` gives the native vector env
    (:class:`ebus_env.envs.vector.EBusVectorEnv`: one compiled call for all sub-envs, equal
    to single envs seeded ``seed + i``); :class:`ebus_env.envs.sb3.SB3VecEnv` adapts it to
    stable-baselines3.

    ## Version History
    * v0: first version (the peak so far, the layover left, the lost-service term and
      stop-to-stop decisions were added before the first release).
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 4}
    action_space: gym.spaces.Box
    observation_space: gym.spaces.Box

    def __init__(self, config: str | Path | dict | None = None, render_mode: str | None = None,
                 **overrides: Any) -> None:
        self.config = cfg = EnvConfig.load(config, **overrides)
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ConfigError(f"render_mode '{render_mode}': use one of "
                              f"{self.metadata['render_modes']} or None.")
        self.render_mode = render_mode
        self.buses = BusBatch(cfg, 1)
        self.bus, self.model, self.course = self.buses.bus, self.buses.model, self.buses.course
        self.reward_fn = reward_of(cfg)
        self.observation_names = [o[0] for o in OBSERVATIONS]
        self.action_names = list(ACTION_NAMES)
        self.action_space, self.observation_space = spaces()
        self._history: list[np.ndarray] = []
        self._started = self._ended = False
        self._warned: set[str] = set()

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self.buses.reset(0, self.np_random)
        self._history = []
        self._started, self._ended = True, False
        self._warned = set()
        return self.buses.obs[0].copy(), {"observation_names": self.observation_names}

    def step(self, action: ArrayLike) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if not self._started:
            raise EnvError("Call reset() before step().")
        if self._ended:
            raise EnvError("step() after the episode ended (terminated): call reset() to "
                           "start a new day.")
        values = physical(checked_actions(action, self.action_space.shape, self.action_names,
                                          "EBus-v0"))
        buses = self.buses
        buses.step(values[None])
        reward, costs = self.reward_fn(buses.quantities)
        depleted, end = buses.ended()
        info = bus_info(buses, 0, values, costs[0])
        info["reward"] = float(reward[0])
        info["depleted"] = bool(depleted[0])
        if self.render_mode is not None:  # the day so far, for render()
            self._history.append(np.array([
                buses.elapsed_h()[0], info["speed_kmh_mean"],
                buses.states[0, buses.at[S_SOC]], info["battery_kw"], info["grid_kw"],
                buses.cabin_degc(0), values[2]]))
            if self.render_mode == "human":
                self.render()
        self._ended = bool(depleted[0] or end[0])
        self._flag_bounds(info)
        return (buses.obs[0].copy(), info["reward"], self._ended, False, info)

    def _flag_bounds(self, info: dict[str, Any]) -> None:
        """Name the observations whose true value lies beyond the observation bounds (the
        observation holds the bound; ``info`` the true value), warning once per episode."""
        info["clipped_observations"] = [name for name, beyond in
                                        clipped_observations(info, self._warned).items() if beyond]

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gym.logger.warn("render() without a render_mode: pass render_mode='rgb_array' or "
                            "'human' to gymnasium.make.")
            return None
        from ebus_env.envs.render import draw

        title = (f"{self.spec.id if self.spec else 'EBus'}: {self.course.name}, "
                 f"decision {int(self.buses.decisions()[0])}")
        return draw(self._history, title, self.render_mode)
