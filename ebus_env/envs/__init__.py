"""Gymnasium environments: ``EBus-v0`` (one bus, one service day; a native vector
env) and ``EBusFleet-v0`` (buses sharing a terminal's chargers and grid connection).

Registered when :mod:`ebus_env` is imported (``import ebus_env; gymnasium.make("EBus-v0")``),
or without an import as ``gymnasium.make("ebus_env:EBus-v0")``.
"""

from __future__ import annotations

import gymnasium as gym

MAX_DECISIONS = 10_000  # TimeLimit: a 24 h day of 10 s stop-to-stop decisions fits


def register_envs() -> None:
    """Register the environments with Gymnasium (idempotent)."""
    if "EBus-v0" not in gym.registry:
        gym.register("EBus-v0", entry_point="ebus_env.envs.ebus:EBusEnv",
                     vector_entry_point="ebus_env.envs.vector:EBusVectorEnv",
                     max_episode_steps=MAX_DECISIONS)
    if "EBusFleet-v0" not in gym.registry:
        gym.register("EBusFleet-v0", entry_point="ebus_env.envs.fleet:EBusFleetEnv",
                     max_episode_steps=MAX_DECISIONS)
