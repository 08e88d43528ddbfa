"""``ebus train`` and ``ebus evaluate``: the agents' commands in the ``ebus`` app.

The arrow points down: ``ebus_env`` never imports ``agents``. Its CLI loads every function
registered in the entry-point group ``ebus_env.commands`` (this package's ``pyproject.toml``
names :func:`register` there) and calls it with the app, so installing ``agents`` next to
``ebus_env`` adds the commands. Each command parses its options and calls one function:
:func:`agents.evaluate.evaluate_policies`, :func:`agents.ppo.train_agent`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from ebus_env.cli_options import console, run_command

ThreadsOpt = Annotated[int, typer.Option(
    "--threads", min=1, help="Torch threads for the policy network (1 suits small MLPs)")]


def register(app: typer.Typer) -> None:
    """Add ``train`` and ``evaluate`` to ``app`` (the ``ebus`` command)."""
    app.command()(evaluate)
    app.command()(train)


def _env_overrides(items: list[str] | None) -> dict[str, Any]:
    """``key=value`` items of ``--set`` as env config overrides (values read as YAML)."""
    import yaml

    from ebus_env.errors import ConfigError

    out: dict[str, Any] = {}
    for item in items or []:
        if "=" not in item:
            raise ConfigError(f"--set needs key=value, got '{item}'.")
        key, value = item.split("=", 1)
        try:
            out[key.strip()] = yaml.safe_load(value)
        except yaml.YAMLError:
            raise ConfigError(f"--set {key}: '{value}' is not a value.") from None
    return out


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
) -> None:
    """Score policies on the same held-out days: energy, grid load, comfort, delay."""

    def body() -> None:
        from agents.evaluate import evaluate_policies, print_sheet

        done = evaluate_policies(policy, env, episodes, out, threads, **_env_overrides(set_))
        shown = console()
        print_sheet(done.sheet, shown)
        for path in done.written:
            shown.print(f"[bold green]->[/] {path}")

    run_command(body)


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
) -> None:
    """Train PPO on EBus-v0's native vector env (stable-baselines3)."""

    def body() -> None:
        from agents.ppo import train_agent

        done = train_agent(config, out, steps=steps, seed=seed, time_limit_min=time_limit_min,
                           threads=threads)
        limit = " (time limit reached)" if done["stopped_by_time_limit"] else ""
        console().print(f"[bold green]agent ->[/] {done['folder'] / 'model.zip'} "
                        f"({done['steps']:,} steps in {done['wall_s']:.0f} s{limit})")

    run_command(body)
