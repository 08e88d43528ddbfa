"""PPO (stable-baselines3) on the native vector env: training, checkpoints, and a policy that
loads a trained agent for the evaluator.

``ebus train --config configs/agents/ppo.yaml`` writes into ``--out`` (``runs/ppo``):
``model.zip`` and ``vecnormalize.pkl`` (the agent), ``checkpoints/``, ``config.json`` and
``progress.csv``, the training curve: one row per update with stable-baselines3's losses, fps
and, once days have ended, episode returns (TensorBoard event files too when tensorboard is
installed: ``tensorboard --logdir runs/ppo``). Training days are drawn from the generators
seeded ``seed + i``; the evaluator's held-out days use seeds from 10,000.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ebus_env import paths
from ebus_env.envs.spec import config_keys
from ebus_env.errors import ConfigError

DEFAULT_AGENT = paths.trained("ppo_sort2_day")
"""The shipped agent (``ppo:default``): PPO trained on ``sort2_day`` (see its README)."""


@dataclass(frozen=True)
class PPOConfig:
    env: str = "sort2_day"
    env_overrides: dict = field(default_factory=dict)
    num_envs: int = 16
    total_steps: int = 400_000
    seed: int = 0
    n_steps: int = 256
    batch_size: int = 512
    n_epochs: int = 10
    learning_rate: float = 3e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    ent_coef: float = 0.0
    net_arch: tuple = (64, 64)
    log_std_init: float = 0.0  # initial log std of the Gaussian policy (actions span [-1, 1])
    normalize: bool = True
    checkpoint_every: int = 100_000
    time_limit_min: float | None = None  # stop (and save) after this much wall-clock time
    torch_threads: int = 1  # a small MLP on a shared CPU: more threads mostly wait on each other

    def __post_init__(self):
        for name in ("num_envs", "total_steps", "n_steps", "batch_size", "n_epochs",
                     "checkpoint_every", "torch_threads"):
            if not isinstance(getattr(self, name), int) or getattr(self, name) < 1:
                raise ConfigError(f"PPO config {name}={getattr(self, name)!r}: needs a whole "
                                  "number >= 1.")
        for name in ("learning_rate", "gamma", "gae_lambda"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise ConfigError(f"PPO config {name}={getattr(self, name)!r}: needs a value "
                                  "in (0, 1].")
        if self.time_limit_min is not None and not self.time_limit_min > 0:
            raise ConfigError(f"PPO config time_limit_min={self.time_limit_min!r}: needs "
                              "minutes > 0, or leave it out for no limit.")

    @classmethod
    def load(cls, source: str | Path | None = "ppo", **overrides) -> PPOConfig:
        """From a name in ``configs/agents`` or a YAML path, with overrides."""
        data = config_keys(cls, source or "ppo", overrides, "PPO", paths.configs("agents"))
        data["net_arch"] = tuple(data.get("net_arch", cls.net_arch))
        return cls(**data)


def _venv(cfg: PPOConfig, num_envs: int):
    from stable_baselines3.common.vec_env import VecMonitor

    from ebus_env.envs.sb3 import SB3VecEnv

    return VecMonitor(SB3VecEnv(num_envs=num_envs, config=cfg.env, **cfg.env_overrides))


def require_rl():
    """Import torch and stable-baselines3, or say which extra installs them."""
    try:
        import stable_baselines3
        import torch
    except ImportError as exc:
        raise ConfigError(f"PPO needs the rl extra ({exc.name} is missing): "
                          "pip install 'ebus-env[rl]'.") from None
    return torch, stable_baselines3


def _time_limit(minutes: float, clock: Callable[[], float]):
    """A callback that ends training once ``clock`` [s] has advanced ``minutes``."""
    from stable_baselines3.common.callbacks import BaseCallback

    class TimeLimit(BaseCallback):
        reached = False

        def _on_training_start(self):
            self.deadline = clock() + 60.0 * minutes

        def _on_step(self) -> bool:
            TimeLimit.reached = clock() >= self.deadline
            return not TimeLimit.reached

    return TimeLimit()


def train(cfg: PPOConfig, out_dir: str | Path, progress: bool = False,
          clock: Callable[[], float] = time.perf_counter) -> Path:
    """Train PPO as configured; returns ``out_dir`` holding the agent and ``training.json``
    (steps done, wall time, whether the time limit ended it, machine).

    ``clock`` [s] measures the time limit and the wall time (tests pass a counter); torch runs
    on ``cfg.torch_threads`` threads (set for the whole process)."""
    import importlib.util
    import os
    import platform

    torch, _ = require_rl()
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import CheckpointCallback
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecNormalize

    torch.set_num_threads(cfg.torch_threads)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps(asdict(cfg), indent=2))
    venv = _venv(cfg, cfg.num_envs)
    venv.seed(cfg.seed)
    if cfg.normalize:
        venv = VecNormalize(venv, gamma=cfg.gamma)
    model = PPO("MlpPolicy", venv, n_steps=cfg.n_steps, batch_size=cfg.batch_size,
                n_epochs=cfg.n_epochs, learning_rate=cfg.learning_rate, gamma=cfg.gamma,
                gae_lambda=cfg.gae_lambda, ent_coef=cfg.ent_coef, seed=cfg.seed,
                policy_kwargs={"net_arch": list(cfg.net_arch), "log_std_init": cfg.log_std_init},
                device="cpu", verbose=0)
    # Our own logger: the curve lands next to the agent, and stable-baselines3 does not leave
    # an empty SB3-<time> folder in the system's temp directory on every run.
    formats = ["csv"] + (["tensorboard"] if importlib.util.find_spec("tensorboard") else [])
    model.set_logger(configure(str(out), formats))
    callbacks = [CheckpointCallback(max(cfg.checkpoint_every // cfg.num_envs, 1),
                                    str(out / "checkpoints"), name_prefix="ppo",
                                    save_vecnormalize=cfg.normalize)]
    limit = _time_limit(cfg.time_limit_min, clock) if cfg.time_limit_min else None
    t0 = clock()
    model.learn(cfg.total_steps, callback=callbacks + ([limit] if limit else []),
                progress_bar=progress)
    wall_s = clock() - t0
    model.save(out / "model.zip")
    if cfg.normalize:
        venv.save(str(out / "vecnormalize.pkl"))
    venv.close()
    (out / "training.json").write_text(json.dumps({
        "steps": int(model.num_timesteps), "wall_s": round(wall_s, 1),
        "steps_per_s": round(model.num_timesteps / max(wall_s, 1e-9)),
        "stopped_by_time_limit": bool(limit and limit.reached),
        "torch_threads": cfg.torch_threads, "cpus": os.cpu_count(),
        "machine": platform.processor() or platform.machine()}, indent=2))
    return out


class PPOPolicy:
    """A trained agent (``model.zip`` and, if trained with it, ``vecnormalize.pkl``) with
    ``predict(obs, deterministic=True)`` on raw observations; torch runs on ``torch_threads``
    threads (set for the whole process)."""

    def __init__(self, path: str | Path, name: str | None = None, torch_threads: int = 1):
        torch, _ = require_rl()
        from stable_baselines3 import PPO

        torch.set_num_threads(torch_threads)
        path = Path(path)
        folder = path if path.is_dir() else path.parent
        model_file = folder / "model.zip" if path.is_dir() else path
        if not model_file.exists():
            raise ConfigError(f"No trained agent at {model_file} (ebus train writes one).")
        self.model = PPO.load(model_file, device="cpu")
        label = folder.name if model_file.stem == "model" else f"{folder.name}/{model_file.stem}"
        self.name = name or f"ppo:{label}"
        self._norm = None
        stats = folder / "vecnormalize.pkl"
        if model_file.stem.startswith("ppo_") and model_file.stem.endswith("_steps"):
            stats = folder / model_file.name.replace("ppo_", "ppo_vecnormalize_").replace(
                ".zip", ".pkl")  # a checkpoint: the statistics saved with it
        if stats.exists():
            import pickle

            with open(stats, "rb") as f:
                self._norm = pickle.load(f)  # VecNormalize without its env: stats only

    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True):
        obs = np.asarray(obs, dtype=np.float32)
        if self._norm is not None:
            obs = self._norm.normalize_obs(obs)
        return self.model.predict(obs, deterministic=deterministic)


def load_policy(spec: str, torch_threads: int = 1):
    """``rule:NAME`` (``agents.rules.RULES``), ``ppo:PATH`` (a training folder or a
    checkpoint's zip) or ``ppo:default`` (the shipped agent)."""
    from agents.rules import rule

    kind, _, arg = spec.partition(":")
    if kind == "rule":
        return rule(arg)
    if kind == "ppo":
        if arg == "default":
            return PPOPolicy(DEFAULT_AGENT, "ppo:default", torch_threads)
        return PPOPolicy(arg, torch_threads=torch_threads)
    raise ConfigError(f"Policy '{spec}': use rule:NAME (baseline, eco_driving, eco_comfort, "
                      "eco_charging, eco_all), ppo:PATH or ppo:default.")
