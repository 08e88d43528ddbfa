"""What every policy of the package offers: stable-baselines3's ``predict``, so that one
evaluator scores rules (:mod:`agents.rules`) and trained agents (:mod:`agents.ppo`) alike."""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

PolicyState = tuple[np.ndarray, ...] | None
"""A recurrent policy's hidden state (None: the package's policies keep none)."""


class Policy(Protocol):
    """A policy by name, with ``predict(obs, deterministic=True) -> (action, state)``: for one
    observation an action, for a batch (n, ...) a batch of actions (each in [-1, 1])."""

    @property
    def name(self) -> str: ...

    def predict(self, obs: ArrayLike, state: PolicyState = None,
                episode_start: np.ndarray | None = None,
                deterministic: bool = True) -> tuple[np.ndarray, PolicyState]: ...
