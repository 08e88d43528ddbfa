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
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ebus_env import paths
from ebus_env.envs.ebus import config_keys
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


def _time_limit(minutes: float):
    """A callback that ends training after ``minutes`` of wall-clock time."""
    import time

    from stable_baselines3.common.callbacks import BaseCallback

    class TimeLimit(BaseCallback):
        def _on_training_start(self):
            self.deadline = time.perf_counter() + 60.0 * minutes

        def _on_step(self) -> bool:
            return time.perf_counter() < self.deadline

    return TimeLimit()


def train(cfg: PPOConfig, out_dir: str | Path, progress: bool = False) -> Path:
    """Train PPO as configured; returns ``out_dir`` holding the agent and ``training.json``
    (steps done, wall time, machine)."""
    import importlib.util
    import os
    import platform
    import time

    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import CheckpointCallback
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecNormalize

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
    if cfg.time_limit_min:
        callbacks.append(_time_limit(cfg.time_limit_min))
    t0 = time.perf_counter()
    model.learn(cfg.total_steps, callback=callbacks, progress_bar=progress)
    wall_s = time.perf_counter() - t0
    model.save(out / "model.zip")
    if cfg.normalize:
        venv.save(str(out / "vecnormalize.pkl"))
    venv.close()
    (out / "training.json").write_text(json.dumps({
        "steps": int(model.num_timesteps), "wall_s": round(wall_s, 1),
        "steps_per_s": round(model.num_timesteps / wall_s), "cpus": os.cpu_count(),
        "machine": platform.processor() or platform.machine()}, indent=2))
    return out


class PPOPolicy:
    """A trained agent (``model.zip`` and, if trained with it, ``vecnormalize.pkl``) with
    ``predict(obs, deterministic=True)`` on raw observations."""

    def __init__(self, path: str | Path, name: str | None = None):
        from stable_baselines3 import PPO

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


def load_policy(spec: str):
    """``rule:NAME`` (``ebus_env.agents.rules.RULES``), ``ppo:PATH`` (a training folder or a
    checkpoint's zip) or ``ppo:default`` (the shipped agent)."""
    from ebus_env.agents.rules import rule

    kind, _, arg = spec.partition(":")
    if kind == "rule":
        return rule(arg)
    if kind == "ppo":
        return PPOPolicy(DEFAULT_AGENT, "ppo:default") if arg == "default" else PPOPolicy(arg)
    raise ConfigError(f"Policy '{spec}': use rule:NAME (baseline, eco_driving, eco_comfort, "
                      "eco_charging, eco_all), ppo:PATH or ppo:default.")
