"""The native vector env of ``EBus-v0``: ``num_envs`` buses in one :class:`BusBatch`.

``gymnasium.make_vec("EBus-v0", num_envs=64)`` builds it (``vector_entry_point``). One step
advances every sub-env with one call of each compiled pass (split over threads for 16 and
more sub-envs), not a loop over single envs. Sub-env ``i`` of ``reset(seed=s)`` is seeded
``s + i`` and equals ``gymnasium.make("EBus-v0")`` reset with that seed, step for step.
"""

from __future__ import annotations

from numbers import Integral
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from numpy.typing import ArrayLike

from ebus_env.envs import MAX_DECISIONS
from ebus_env.envs.batch import OBSERVATIONS, BusBatch
from ebus_env.envs.common import (
    ACTION_NAMES,
    ACTIONS,
    EnvConfig,
    batch_info,
    checked_actions,
    clipped_observations,
    physical,
    reward_of,
    spaces,
)
from ebus_env.errors import ConfigError, EnvError


def positive_count(name: str, value: object, example: str) -> int:
    """``value`` as an int >= 1 (a Python or numpy integer, not a bool), or a clear error
    naming ``name`` and the fix."""
    if isinstance(value, bool) or not isinstance(value, Integral) or value < 1:
        raise ConfigError(f"{name} = {value!r}: must be a whole number >= 1 ({example}).")
    return int(value)


class EBusVectorEnv(VectorEnv):
    """``num_envs`` copies of ``EBus-v0`` (same config, own seeds) stepped together.

    Arguments: ``num_envs``, ``config`` and overrides as for ``EBus-v0``,
    ``max_episode_steps`` (the TimeLimit, 10,000), ``autoreset_mode`` (``NEXT_STEP`` as
    Gymnasium's own vector envs; ``SAME_STEP`` puts the last observation and info of an
    ended episode in ``info["final_obs"]`` / ``info["final_info"]``, what stable-baselines3
    expects: see :mod:`ebus_env.envs.sb3`). ``info`` holds arrays (num_envs,) of the
    single env's figures, ``info["reward_terms"]`` and ``info["breakdown_kwh"]`` dicts of them,
    ``info["clipped_observations"]`` a dict of bool arrays: the observations that hold their
    bound (the single env's list of names, per sub-env; warned once per reset).
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, config: str | Path | dict | None = None,
                 max_episode_steps: int = MAX_DECISIONS,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                 **overrides: Any) -> None:
        try:
            mode = AutoresetMode(autoreset_mode)
        except ValueError:
            mode = None
        if mode not in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP):
            raise ConfigError(f"autoreset_mode = {autoreset_mode!r}: EBusVectorEnv autoresets; "
                              "use AutoresetMode.NEXT_STEP or AutoresetMode.SAME_STEP.")
        num_envs = positive_count("num_envs", num_envs, "the number of sub-envs, e.g. "
                                  "gymnasium.make_vec('EBus-v0', num_envs=8)")
        max_episode_steps = positive_count("max_episode_steps", max_episode_steps,
                                           f"decisions before truncation; the default is "
                                           f"{MAX_DECISIONS}")
        self.metadata = {**self.metadata, "autoreset_mode": mode}
        self.config = cfg = EnvConfig.load(config, **overrides)
        self.num_envs = num_envs
        self.max_episode_steps = max_episode_steps
        self.buses = BusBatch(cfg, num_envs)
        self.reward_fn = reward_of(cfg)
        self.single_action_space, self.single_observation_space = spaces()
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.observation_names = [o[0] for o in OBSERVATIONS]
        self.action_names = list(ACTION_NAMES)
        self._rngs: list[np.random.Generator] = []
        self._ended = np.zeros(num_envs, bool)
        self._elapsed = np.zeros(num_envs, np.int64)
        self._warned: set[str] = set()  # observations warned of as holding their bound

    def reset(self, *, seed: int | list[int | None] | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        if seed is None or isinstance(seed, int):
            super().reset(seed=seed)
            seeds = [None if seed is None else seed + i for i in range(self.num_envs)]
        elif len(seed) == self.num_envs:
            seeds = list(seed)
        else:
            raise ConfigError(f"reset(seed=...) takes an int or {self.num_envs} seeds, got "
                             f"{len(seed)}.")
        self._rngs = [seeding.np_random(s)[0] for s in seeds]
        for b in range(self.num_envs):
            self.buses.reset(b, self._rngs[b])
        self._ended[:] = False
        self._elapsed[:] = 0
        self._warned = set()
        return self.buses.obs.copy(), {}

    def step(self, actions: ArrayLike
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        if not self._rngs:
            raise EnvError("Call reset() before step().")
        values = physical(checked_actions(actions, (self.num_envs, len(ACTIONS)), self.action_names,
                                          "EBusVectorEnv"))
        buses = self.buses
        buses.step(values)
        reward, costs = self.reward_fn(buses.quantities)
        depleted, end = buses.ended()
        self._elapsed += 1
        terminated = depleted | end
        truncated = (self._elapsed >= self.max_episode_steps) & ~terminated
        info = batch_info(buses, values, costs)
        info["depleted"] = depleted
        # name -> (num_envs,) bool: the observation holds its bound, info has the true value
        info["clipped_observations"] = clipped_observations(info, self._warned)
        obs = buses.obs.copy()
        if self.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP:
            was_ended = self._ended
            restarted = np.flatnonzero(was_ended)
            for b in restarted.tolist():  # the ended episodes start again; their actions are ignored
                self._restart(b)
                obs[b] = buses.obs[b]
            reward[restarted] = 0.0
            terminated[restarted] = truncated[restarted] = False
            self._ended = terminated | truncated
            if len(restarted):  # their figures are of the ignored step: masked out
                info.update({f"_{k}": ~was_ended for k in list(info)})
        else:
            ended = np.flatnonzero(terminated | truncated)
            if len(ended):
                final = np.zeros(self.num_envs, bool)
                final[ended] = True
                info["final_obs"] = obs.copy()
                info["final_info"] = info.copy()
                info["_final_obs"] = info["_final_info"] = final
                for b in ended.tolist():
                    self._restart(b)
                    obs[b] = buses.obs[b]
        return obs, reward, terminated, truncated, info

    def _restart(self, b: int) -> None:
        self.buses.reset(b, self._rngs[b])
        self._elapsed[b] = 0

    def close_extras(self, **kwargs: Any) -> None:
        self._rngs = []
