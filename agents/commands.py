"""``ebus train`` and ``ebus evaluate``: the agents' commands in the ``ebus`` app.

The arrow points down: ``ebus_env`` never imports ``agents``. Its CLI loads every function
registered in the entry-point group ``ebus_env.commands`` (this package's ``pyproject.toml``
names :func:`register` there) and calls it with the app, so installing ``agents`` next to
``ebus_env`` adds the commands.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

ThreadsOpt = Annotated[int, typer.Option(
    "--threads", min=1, help="Torch threads for the policy network (1 suits small MLPs)")]


def register(app: typer.Typer) -> None:
    """Add ``train`` and ``evaluate`` to ``app`` (the ``ebus`` command)."""
    app.command()(evaluate)
    app.command()(train)


def _run(body) -> None:
    """The app's way to run a command body: errors as one line, exit code 2. Imported at
    call time, as ``ebus_env.cli`` imports this module while it loads."""
    from ebus_env.cli import _run as run

    run(body)


def _console():
    from ebus_env.cli import _console as console

    return console()


def _env_overrides(items: list[str] | None) -> dict:
    import yaml

    from ebus_env.errors import ConfigError

    out = {}
    for item in items or []:
        if "=" not in item:
            raise ConfigError(f"--set needs key=value, got '{item}'.")
        key, value = item.split("=", 1)
        try:
            out[key.strip()] = yaml.safe_load(value)
        except yaml.YAMLError:
            raise ConfigError(f"--set {key}: '{value}' is not a value.") from None
    return out


def _output_folder(out: Path, option: str) -> Path:
    """``out`` as a folder to write into, refused before the run when it is a file."""
    from ebus_env.errors import ConfigError

    if out.exists() and not out.is_dir():
        raise ConfigError(f"{option} {out}: is a file; give a folder (new or existing).")
    return out


def _refuse_overwriting_inputs(folder: Path, option: str, names, inputs) -> None:
    """Refuse, before the run, an output ``folder / name`` that is one of the ``inputs``
    (paths, or None): writing it would destroy the input."""
    from ebus_env.errors import ConfigError
    from ebus_env.outputs import same_file

    for source in inputs:
        if source is None or not Path(source).is_file():
            continue
        for name in names:
            if same_file(folder / name, Path(source)):
                raise ConfigError(f"{option} {folder}: the command writes {name} there, which "
                                  f"is its input {source}. Fix: give another {option}, or "
                                  "move the input elsewhere.")


def _env_inputs(env, overrides: dict) -> list:
    """Files an env config reads that an output could overwrite: its YAML and a measured
    log."""
    return [Path(str(env)) if Path(str(env)).suffix else None,
            overrides.get("log") if isinstance(overrides.get("log"), str | Path) else None]


def evaluate(
    policy: Annotated[list[str], typer.Option(
        help="rule:NAME (baseline, eco_driving, eco_comfort, eco_charging, eco_all), "
             "ppo:PATH or ppo:default (the shipped agent); repeatable")],
    env: Annotated[str, typer.Option(help="Env config: name in configs/env or a YAML path")]
    = "sort2_day",
    episodes: Annotated[int, typer.Option(help="Held-out days (seeds 10000, 10001, ...)")] = 20,
    set_: Annotated[list[str] | None, typer.Option(
        "--set", help="Override an env config key: key=value (repeatable)")] = None,
    out: Annotated[Path, typer.Option(help="Folder for scores.json, CSV and plots")]
    = Path("runs/evaluate"),
    threads: ThreadsOpt = 1,
):
    """Score policies on the same held-out days: energy, grid load, comfort, delay."""

    def body():
        from agents.evaluate import OUTPUTS, print_sheet
        from agents.evaluate import evaluate as run
        from agents.ppo import load_policy
        from ebus_env.errors import ConfigError

        if episodes < 1:
            raise ConfigError(f"--episodes {episodes}: needs at least 1 held-out day.")
        folder = _output_folder(out, "--out")
        overrides = _env_overrides(set_)
        policy_files = [Path(spec.partition(":")[2]) for spec in policy
                        if spec.startswith("ppo:") and spec != "ppo:default"]
        _refuse_overwriting_inputs(folder, "--out", OUTPUTS,
                                   _env_inputs(env, overrides) + policy_files)
        console = _console()
        sheet = run([load_policy(spec, threads) for spec in policy], env, episodes=episodes,
                    **overrides)
        print_sheet(sheet, console)
        for path in sheet.write(folder):
            console.print(f"[bold green]->[/] {path}")

    _run(body)


def train(
    config: Annotated[Path | None, typer.Option(help="PPO config (configs/agents/ppo.yaml)")]
    = None,
    steps: Annotated[int | None, typer.Option(help="Total env steps (overrides the config)")]
    = None,
    seed: Annotated[int | None, typer.Option(help="Seed (overrides the config)")] = None,
    time_limit_min: Annotated[float | None, typer.Option(
        help="Stop and save after this many minutes of wall-clock time (overrides the config)")]
    = None,
    threads: Annotated[int | None, typer.Option(
        "--threads", help="Torch threads (overrides the config; 1 suits small MLPs)")] = None,
    out: Annotated[Path, typer.Option(help="Folder for the agent, checkpoints, TensorBoard")]
    = Path("runs/ppo"),
):
    """Train PPO on EBus-v0's native vector env (stable-baselines3)."""

    def body():
        from agents.ppo import OUTPUTS, PPOConfig, require_rl
        from agents.ppo import train as run

        overrides = {k: v for k, v in (("total_steps", steps), ("seed", seed),
                                       ("time_limit_min", time_limit_min),
                                       ("torch_threads", threads)) if v is not None}
        cfg = PPOConfig.load(config, **overrides)
        cfg.env_config()  # a bad env name or override: refused before --out is made
        folder = _output_folder(out, "--out")
        _refuse_overwriting_inputs(folder, "--out", OUTPUTS,
                                   [config, *_env_inputs(cfg.env, cfg.env_overrides)])
        require_rl()
        path = run(cfg, folder, progress=False)
        done = json.loads((path / "training.json").read_text())
        limit = " (time limit reached)" if done["stopped_by_time_limit"] else ""
        _console().print(f"[bold green]agent ->[/] {path / 'model.zip'} ({done['steps']:,} "
                         f"steps in {done['wall_s']:.0f} s{limit})")

    _run(body)
