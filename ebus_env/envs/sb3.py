"""stable-baselines3 adapter for the native vector env (needs the ``rl`` extra).

stable-baselines3 has its own ``VecEnv`` interface (reset returns only observations, infos are
a list of dicts, an ended episode is reset in the same step with its last observation in
``info["terminal_observation"]``). :class:`SB3VecEnv` presents :class:`EBusVectorEnv` that way,
so PPO steps all sub-envs in one compiled call::

    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor
    from ebus_env.envs.sb3 import SB3VecEnv

    venv = VecMonitor(SB3VecEnv(num_envs=16, config="sort2_day"))
    PPO("MlpPolicy", venv, seed=0).learn(100_000)

(``VecMonitor`` adds episode returns and lengths to the infos, for the logs.)
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvStepReturn

from ebus_env.envs.vector import EBusVectorEnv
from ebus_env.errors import EnvError


class SB3VecEnv(VecEnv):
    """``EBusVectorEnv(num_envs, config, **overrides)`` as a stable-baselines3 ``VecEnv``."""

    def __init__(self, num_envs: int = 8, config: str | Path | dict | None = None,
                 **overrides: Any) -> None:
        self.env = EBusVectorEnv(num_envs=num_envs, config=config,
                                 autoreset_mode=AutoresetMode.SAME_STEP, **overrides)
        super().__init__(self.env.num_envs, self.env.single_observation_space,  # checked
                         self.env.single_action_space)
        self._actions: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        seeds = self._seeds if any(s is not None for s in self._seeds) else None
        obs, _ = self.env.reset(seed=seeds)
        self._reset_seeds()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise EnvError("step_wait() before step_async(actions): give the actions first.")
        obs, reward, terminated, truncated, info = self.env.step(self._actions)
        dones = terminated | truncated
        infos: list[dict] = [{} for _ in range(self.num_envs)]
        for b in np.flatnonzero(dones):
            infos[b]["terminal_observation"] = info["final_obs"][b]
            infos[b]["TimeLimit.truncated"] = bool(truncated[b] and not terminated[b])
        return obs, reward.astype(np.float32), dones, infos

    def close(self) -> None:
        self.env.close()

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(self.env, attr_name)] * len(self._indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        setattr(self.env, attr_name, value)

    def env_method(self, method_name: str, *args: Any, indices: VecEnvIndices = None,
                   **kwargs: Any) -> list[Any]:
        result = getattr(self.env, method_name)(*args, **kwargs)
        return [result] * len(self._indices(indices))

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper],
                       indices: VecEnvIndices = None) -> list[bool]:
        return [False] * len(self._indices(indices))

    def _indices(self, indices: VecEnvIndices) -> Sequence[int]:
        if indices is None:
            return range(self.num_envs)
        return [indices] if isinstance(indices, int) else list(indices)
