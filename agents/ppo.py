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
import math
import numbers
import time
import warnings
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, NoReturn

import numpy as np
from numpy.typing import ArrayLike

from agents.policy import Policy, PolicyState
from ebus_env import paths
from ebus_env.envs.common import config_keys
from ebus_env.errors import ConfigError

if TYPE_CHECKING:  # torch and stable-baselines3 load when an agent trains or runs
    from stable_baselines3 import PPO
    from stable_baselines3.common.base_class import BaseAlgorithm
    from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback
    from stable_baselines3.common.vec_env import VecEnv, VecMonitor, VecNormalize

    from ebus_env.envs.common import EnvConfig

DEFAULT_AGENT = paths.trained("ppo_sort2_day")
"""The shipped agent (``ppo:default``): PPO trained on ``sort2_day`` (see its README)."""
OUTPUTS = ("config.json", "training.json", "model.zip", "vecnormalize.pkl", "progress.csv")
"""The files :func:`train` writes into its folder (besides ``checkpoints/``)."""


SEED_MAX = 2**32 - 1  # numpy's legacy seeding, which stable-baselines3 uses, takes no more


def _is_int(value: object) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _is_real(value: object) -> bool:
    return (isinstance(value, numbers.Real) and not isinstance(value, bool)
            and math.isfinite(value))


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

    def __post_init__(self) -> None:
        """Every field's type and range, and what stable-baselines3's PPO requires of the
        rollout and its mini-batches: a clear :class:`ConfigError` before any work."""
        def fail(name: str, needs: str) -> NoReturn:
            raise ConfigError(f"PPO config {name}={getattr(self, name)!r}: needs {needs}.")

        def put(name: str, value: object) -> None:
            object.__setattr__(self, name, value)

        if isinstance(self.env, Path):
            put("env", str(self.env))
        if not isinstance(self.env, str) or not self.env.strip():
            fail("env", "an env config: a name in configs/env (sort2_day) or a YAML path")
        if not isinstance(self.env_overrides, Mapping) \
                or not all(isinstance(k, str) for k in self.env_overrides):
            fail("env_overrides", "a mapping of env config keys to values, e.g. "
                 "{service_h: 3.0}")
        put("env_overrides", dict(self.env_overrides))
        for name in ("num_envs", "total_steps", "n_steps", "batch_size", "n_epochs",
                     "checkpoint_every", "torch_threads"):
            if not _is_int(getattr(self, name)) or getattr(self, name) < 1:
                fail(name, "a whole number >= 1")
            put(name, int(getattr(self, name)))
        if not _is_int(self.seed) or not 0 <= self.seed <= SEED_MAX:
            fail("seed", f"a whole number from 0 to {SEED_MAX}")
        put("seed", int(self.seed))
        for name, low_open, low in (("learning_rate", True, 0.0), ("gamma", True, 0.0),
                                    ("gae_lambda", False, 0.0)):
            value = getattr(self, name)
            if not _is_real(value) or not (low < value if low_open else low <= value) \
                    or value > 1.0:
                fail(name, f"a number in {'(' if low_open else '['}{low:g}, 1]")
            put(name, float(value))
        if not _is_real(self.ent_coef) or self.ent_coef < 0:
            fail("ent_coef", "a number >= 0 (0: no entropy bonus)")
        put("ent_coef", float(self.ent_coef))
        if not _is_real(self.log_std_init):
            fail("log_std_init", "a finite number (the log of the initial action noise std, "
                 "e.g. -1.0)")
        put("log_std_init", float(self.log_std_init))
        if not isinstance(self.net_arch, (list, tuple)) \
                or not all(_is_int(n) and n >= 1 for n in self.net_arch):
            fail("net_arch", "a list of layer widths, whole numbers >= 1, e.g. [64, 64]")
        put("net_arch", tuple(int(n) for n in self.net_arch))
        if not isinstance(self.normalize, bool):
            fail("normalize", "true or false")
        if self.time_limit_min is not None:
            if not _is_real(self.time_limit_min) or not self.time_limit_min > 0:
                fail("time_limit_min", "minutes > 0, or leave it out for no limit")
            put("time_limit_min", float(self.time_limit_min))
        # stable-baselines3 normalizes the advantages over each mini-batch (not over one sample)
        if self.batch_size < 2:
            fail("batch_size", "at least 2 (stable-baselines3 normalizes the advantages over "
                 "each mini-batch)")
        if self.batch_size > self.rollout:
            raise ConfigError(
                f"PPO config batch_size={self.batch_size} is larger than one rollout, num_envs "
                f"x n_steps = {self.num_envs} x {self.n_steps} = {self.rollout}. Fix: lower "
                f"batch_size to at most {self.rollout}, or raise n_steps or num_envs.")

    @property
    def rollout(self) -> int:
        """Env steps per update: ``num_envs x n_steps``."""
        return self.num_envs * self.n_steps

    @property
    def planned_steps(self) -> int:
        """The steps training takes without a time limit: ``total_steps`` rounded up to whole
        rollouts (stable-baselines3 collects whole rollouts)."""
        return -(-self.total_steps // self.rollout) * self.rollout

    def rounding_note(self) -> str | None:
        """A line saying that ``total_steps`` rounds up to whole rollouts, or None."""
        if self.planned_steps == self.total_steps:
            return None
        return (f"{self.total_steps} steps round up to {self.planned_steps}: whole rollouts of "
                f"num_envs x n_steps = {self.num_envs} x {self.n_steps} = {self.rollout} steps.")

    def env_config(self) -> EnvConfig:
        """The env config this trains on (``env`` with ``env_overrides``): a clear error when
        either is wrong."""
        from ebus_env.envs.common import EnvConfig

        return EnvConfig.load(self.env, **self.env_overrides)

    @classmethod
    def load(cls, source: str | Path | None = "ppo", **overrides: Any) -> PPOConfig:
        """From a name in ``configs/agents`` or a YAML path, with overrides."""
        return cls(**config_keys(cls, source or "ppo", overrides, "PPO", paths.configs("agents")))


def _venv(cfg: PPOConfig, num_envs: int) -> VecMonitor:
    from stable_baselines3.common.vec_env import VecMonitor

    from ebus_env.envs.sb3 import SB3VecEnv

    return VecMonitor(SB3VecEnv(num_envs=num_envs, config=cfg.env, **cfg.env_overrides))


def require_rl() -> tuple[ModuleType, ModuleType]:
    """Import torch and stable-baselines3, or say which extra installs them."""
    try:
        import stable_baselines3
        import torch
    except ImportError as exc:
        raise ConfigError(f"PPO needs the rl extra ({exc.name} is missing): "
                          "pip install 'ebus-env[rl]'.") from None
    return torch, stable_baselines3


def _time_limit(minutes: float, clock: Callable[[], float]
                ) -> tuple[BaseCallback, Callable[[], bool]]:
    """A callback that ends training once ``clock`` [s] has advanced ``minutes``, and a
    function that says whether it did."""
    from stable_baselines3.common.callbacks import BaseCallback

    class TimeLimit(BaseCallback):
        reached = False

        def _on_training_start(self) -> None:
            self.deadline = clock() + 60.0 * minutes

        def _on_step(self) -> bool:
            TimeLimit.reached = clock() >= self.deadline
            return not TimeLimit.reached

    limit = TimeLimit()
    return limit, lambda: limit.reached


def _save_agent(model: BaseAlgorithm, norm: VecNormalize | None, model_path: Path,
                norm_path: Path) -> None:
    """``model`` (and the VecNormalize ``norm``, unless None) each through a temporary file
    renamed over its target: a crash leaves the previous file whole. The temporary path keeps
    the suffix, so stable-baselines3 does not append ``.zip``."""
    from ebus_env.outputs import atomic

    with atomic(model_path) as tmp:
        model.save(tmp)
    if norm is not None:
        with atomic(norm_path) as tmp:
            norm.save(str(tmp))


def _checkpoints(every: int, folder: Path, normalize: bool) -> CheckpointCallback:
    """stable-baselines3's CheckpointCallback (same names: ``ppo_<steps>_steps.zip``,
    ``ppo_vecnormalize_<steps>_steps.pkl``), each file written through a temporary file."""
    from stable_baselines3.common.callbacks import CheckpointCallback

    class AtomicCheckpoints(CheckpointCallback):
        def _on_step(self) -> bool:
            if self.n_calls % self.save_freq == 0:
                norm = self.model.get_vec_normalize_env() if self.save_vecnormalize else None
                _save_agent(self.model, norm, Path(self._checkpoint_path(extension="zip")),
                            Path(self._checkpoint_path("vecnormalize_", extension="pkl")))
            return True

    return AtomicCheckpoints(every, str(folder), name_prefix="ppo", save_vecnormalize=normalize)


def build(cfg: PPOConfig) -> PPO:
    """The untrained PPO model of ``cfg`` on its seeded vector env (VecNormalize around it when
    ``cfg.normalize``); ``model.get_env()`` is that env, to close."""
    require_rl()
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    from ebus_env.errors import InputWarning

    if cfg.rollout % cfg.batch_size:  # said in one line, not in stable-baselines3's three
        warnings.warn(InputWarning(
            f"PPO config batch_size={cfg.batch_size} does not divide a rollout of num_envs x "
            f"n_steps = {cfg.rollout} steps: each epoch ends with a mini-batch of "
            f"{cfg.rollout % cfg.batch_size}. Fix: a batch_size that divides {cfg.rollout}.",
            ("ppo batch", cfg.batch_size, cfg.rollout)), stacklevel=2)
    venv: VecEnv = _venv(cfg, cfg.num_envs)
    try:
        venv.seed(cfg.seed)
        if cfg.normalize:
            venv = VecNormalize(venv, gamma=cfg.gamma)
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", "You have specified a mini-batch size",
                                    UserWarning)
            return PPO("MlpPolicy", venv, n_steps=cfg.n_steps, batch_size=cfg.batch_size,
                       n_epochs=cfg.n_epochs, learning_rate=cfg.learning_rate,
                       gamma=cfg.gamma, gae_lambda=cfg.gae_lambda, ent_coef=cfg.ent_coef,
                       seed=cfg.seed, policy_kwargs={"net_arch": list(cfg.net_arch),
                                                     "log_std_init": cfg.log_std_init},
                       device="cpu", verbose=0)
    except BaseException:
        venv.close()
        raise


def train(cfg: PPOConfig, out_dir: str | Path, progress: bool = False,
          clock: Callable[[], float] = time.perf_counter) -> Path:
    """Train PPO as configured; returns ``out_dir`` holding the agent and ``training.json``
    (steps asked and done, wall time, whether the time limit ended it, machine).

    The env and the model are built before ``out_dir`` is made: a config that fails there
    leaves nothing behind. ``total_steps`` rounds up to whole rollouts (``num_envs x
    n_steps``), said by an :class:`~ebus_env.errors.InputWarning`. Every file is written
    through a temporary file and renamed, but for the curve (``progress.csv``, TensorBoard
    logs), which grows as it trains.
    ``clock`` [s] measures the time limit and the wall time (tests pass a counter); torch runs
    on ``cfg.torch_threads`` threads (set for the whole process)."""
    import importlib.util
    import os
    import platform

    from ebus_env.errors import InputWarning
    from ebus_env.outputs import write_text

    torch, _ = require_rl()
    from stable_baselines3.common.logger import configure

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"PPO output {out} is a file. Fix: give a folder (new or existing).")
    cfg.env_config()  # a bad env name or override: an error before anything is built
    note = cfg.rounding_note()
    if note:
        warnings.warn(InputWarning(note, ("ppo rollout", cfg.total_steps, cfg.rollout)),
                      stacklevel=2)
    torch.set_num_threads(cfg.torch_threads)
    model = build(cfg)
    venv = model.get_env()
    assert venv is not None  # build() gives the model its env
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_text(out / "config.json", json.dumps(asdict(cfg), indent=2))
        # Our own logger: the curve lands next to the agent, and stable-baselines3 does not
        # leave an empty SB3-<time> folder in the system's temp directory on every run.
        formats = ["csv"] + (["tensorboard"] if importlib.util.find_spec("tensorboard") else [])
        model.set_logger(configure(str(out), formats))
        callbacks = [_checkpoints(max(cfg.checkpoint_every // cfg.num_envs, 1),
                                  out / "checkpoints", cfg.normalize)]
        limit = _time_limit(cfg.time_limit_min, clock) if cfg.time_limit_min else None
        t0 = clock()
        model.learn(cfg.total_steps, callback=callbacks + ([limit[0]] if limit else []),
                    progress_bar=progress)
        wall_s = clock() - t0
        model.logger.close()
        _save_agent(model, model.get_vec_normalize_env(), out / "model.zip",
                    out / "vecnormalize.pkl")
    finally:
        venv.close()
    write_text(out / "training.json", json.dumps({
        "steps": int(model.num_timesteps), "steps_asked": cfg.total_steps,
        "rollout": cfg.rollout, "wall_s": round(wall_s, 1),
        "steps_per_s": round(model.num_timesteps / max(wall_s, 1e-9)),
        "stopped_by_time_limit": bool(limit and limit[1]()),
        "torch_threads": cfg.torch_threads, "cpus": os.cpu_count(),
        "machine": platform.processor() or platform.machine()}, indent=2))
    return out


def train_agent(config: str | Path | None = None, out: str | Path = "runs/ppo", *,
                steps: int | None = None, seed: int | None = None,
                time_limit_min: float | None = None, threads: int | None = None) -> dict:
    """Train PPO from a config file with the command's overrides (``ebus train``).

    The config, its env and every output path are checked before anything is built: an
    output folder that is a file, or a file there that is one of the inputs, is refused.

    Parameters
    ----------
    config
        PPO config: a name in ``configs/agents`` or a YAML path (default ``ppo``).
    out
        Folder for the agent (``model.zip``, ``vecnormalize.pkl``), checkpoints, the curve
        and ``training.json``.
    steps, seed, time_limit_min, threads
        Override the config's ``total_steps``, ``seed``, ``time_limit_min`` [min] and
        ``torch_threads``.

    Returns
    -------
    dict
        ``training.json``: steps asked and done, wall time, whether the time limit ended it;
        and ``folder``, the output folder.
    """
    from agents.evaluate import env_files
    from ebus_env.outputs import output_folder, refuse_overwriting

    overrides = {k: v for k, v in (("total_steps", steps), ("seed", seed),
                                   ("time_limit_min", time_limit_min),
                                   ("torch_threads", threads)) if v is not None}
    cfg = PPOConfig.load(config, **overrides)
    cfg.env_config()  # a bad env name or override: refused before --out is made
    folder = output_folder(Path(out), "--out")
    refuse_overwriting(folder, "--out", OUTPUTS, [config, *env_files(cfg.env, cfg.env_overrides)])
    require_rl()
    path = train(cfg, folder, progress=False)
    return {**json.loads((path / "training.json").read_text()), "folder": path}


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

    def predict(self, obs: ArrayLike, state: PolicyState = None,
                episode_start: np.ndarray | None = None,
                deterministic: bool = True) -> tuple[np.ndarray, PolicyState]:
        x = np.asarray(obs, dtype=np.float32)
        if self._norm is not None:
            x = self._norm.normalize_obs(x)
        return self.model.predict(x, deterministic=deterministic)


def load_policy(spec: str, torch_threads: int = 1) -> Policy:
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
