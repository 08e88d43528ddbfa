"""PPO (stable-baselines3) on the native vector env: training, checkpoints, and a policy that
loads a trained agent for the evaluator.

``ebus train --config configs/agents/ppo.yaml`` writes into ``--out`` (``runs/ppo``):
``model.zip`` and ``vecnormalize.pkl`` (the agent), ``checkpoints/``, ``tb/`` (TensorBoard:
``tensorboard --logdir runs/ppo/tb``) and ``config.json``. Training days are drawn from the
generators seeded ``seed + i``; the evaluator's held-out days use seeds from 10,000.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ebus_env.config import ROOT
from ebus_env.envs.ebus import config_keys
from ebus_env.errors import ConfigError


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
    normalize: bool = True
    checkpoint_every: int = 100_000

    @classmethod
    def load(cls, source: str | Path | None = "ppo", **overrides) -> PPOConfig:
        """From a name in ``configs/agents`` or a YAML path, with overrides."""
        data = config_keys(cls, source or "ppo", overrides, "PPO", ROOT / "configs" / "agents")
        data["net_arch"] = tuple(data.get("net_arch", cls.net_arch))
        return cls(**data)


def _venv(cfg: PPOConfig, num_envs: int):
    from stable_baselines3.common.vec_env import VecMonitor

    from ebus_env.envs.sb3 import SB3VecEnv

    return VecMonitor(SB3VecEnv(num_envs=num_envs, config=cfg.env, **cfg.env_overrides))


def train(cfg: PPOConfig, out_dir: str | Path, progress: bool = False) -> Path:
    """Train PPO as configured; returns ``out_dir`` holding the agent."""
    import importlib.util

    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import CheckpointCallback
    from stable_baselines3.common.vec_env import VecNormalize

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps(asdict(cfg), indent=2))
    venv = _venv(cfg, cfg.num_envs)
    venv.seed(cfg.seed)
    if cfg.normalize:
        venv = VecNormalize(venv, gamma=cfg.gamma)
    tensorboard = str(out / "tb") if importlib.util.find_spec("tensorboard") else None
    model = PPO("MlpPolicy", venv, n_steps=cfg.n_steps, batch_size=cfg.batch_size,
                n_epochs=cfg.n_epochs, learning_rate=cfg.learning_rate, gamma=cfg.gamma,
                gae_lambda=cfg.gae_lambda, ent_coef=cfg.ent_coef, seed=cfg.seed,
                policy_kwargs={"net_arch": list(cfg.net_arch)}, tensorboard_log=tensorboard,
                device="cpu", verbose=0)
    checkpoints = CheckpointCallback(max(cfg.checkpoint_every // cfg.num_envs, 1),
                                     str(out / "checkpoints"), name_prefix="ppo",
                                     save_vecnormalize=cfg.normalize)
    model.learn(cfg.total_steps, callback=checkpoints, progress_bar=progress)
    model.save(out / "model.zip")
    if cfg.normalize:
        venv.save(str(out / "vecnormalize.pkl"))
    venv.close()
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
        self.name = name or f"ppo:{folder.name}"
        self._norm = None
        stats = folder / "vecnormalize.pkl"
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
    """``rule:NAME`` (``ebus_env.agents.rules.RULES``) or ``ppo:PATH``."""
    from ebus_env.agents.rules import rule

    kind, _, arg = spec.partition(":")
    if kind == "rule":
        return rule(arg)
    if kind == "ppo":
        return PPOPolicy(arg)
    raise ConfigError(f"Policy '{spec}': use rule:NAME (baseline, eco_driving, eco_comfort, "
                      "eco_charging, eco_all) or ppo:PATH.")
