"""Command line: ``ebus simulate``, ``calibrate``, ``diagnose``, ``cycles``, ``effects``,
``demo``."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Annotated

import typer

from ebus_env.errors import EbusError

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="Lo-Fi electric-bus model: simulate, calibrate, diagnose; train and evaluate "
                       "ECO policies.")

BusOpt = Annotated[str, typer.Option("--bus", "-b", help="Bus config: name (12m, 18m, bmw_i3) "
                                                         "or path to a YAML file")]
WithOpt = Annotated[list[str] | None, typer.Option(
    "--with", help="Add an effect: registry name or my_effects.py:Name (repeatable)")]
WithoutOpt = Annotated[list[str] | None, typer.Option(
    "--without", help="Remove an effect, e.g. cabin_hvac (repeatable; comma lists allowed)")]
SetOpt = Annotated[list[str] | None, typer.Option(
    "--set", help="Override a parameter: effect.param=value (repeatable)")]
OverlayOpt = Annotated[list[Path] | None, typer.Option(
    "--overlay", help="Bus-config overlay to merge, e.g. a calibration result")]


def _console():
    from rich.console import Console

    return Console()


def _split(items: list[str] | None) -> list[str]:
    return [part.strip() for item in items or [] for part in item.split(",") if part.strip()]


def _overrides(items: list[str] | None) -> dict[str, float]:
    from ebus_env.errors import ConfigError

    out = {}
    for item in items or []:
        if "=" not in item or "." not in item.split("=", 1)[0]:
            raise ConfigError(f"--set needs effect.param=value, got '{item}'.")
        key, value = item.split("=", 1)
        try:
            out[key.strip()] = float(value)
        except ValueError:
            raise ConfigError(f"--set {key}: '{value}' is not a number.") from None
    return out


def _load_logs(paths, model, params, columns, gaps, fill, check_units, console, notes=None):
    """Profiles of measured logs, with the loader's report printed (and its changes appended
    to ``notes``)."""
    from ebus_env.io.measured import load_log

    vmax = params[model.param_index("vehicle_body.max_speed_kmh")] \
        if model.has_effect("vehicle_body") else None
    profiles = []
    for path in paths:
        log = load_log(path, model.dt_s, columns=columns, gaps=gaps, fill=fill,
                       check_units=check_units, max_speed_kmh=vmax, max_accel_mps2=4.0)
        profiles += log.profiles
        if notes is not None:
            notes += log.report.changes
        for line in log.report.changes:
            console.print(f"[dim]loader ({Path(path).name}):[/] {line}", highlight=False)
        for line in log.report.warnings + log.report.ignored:
            console.print(f"[yellow]loader ({Path(path).name}):[/] {line}", highlight=False)
    return profiles


def _run(fn):
    """Run a command body, printing user errors without a traceback."""
    try:
        return fn()
    except EbusError as exc:
        _console().print(f"[bold red]error:[/] {exc}", highlight=False)
        raise typer.Exit(2) from None


@app.command()
def simulate(
    bus: BusOpt = "12m",
    cycle: Annotated[str | None, typer.Option(help="Cycle name (see `ebus cycles`) or CSV")] = None,
    measured: Annotated[Path | None, typer.Option(help="Measured log (CSV/Parquet) to replay")] = None,
    hours: Annotated[float, typer.Option(help="Length of the cycle day [h]")] = 13.5,
    mean_speed_kmh: Annotated[float | None, typer.Option(
        help="Scale the cycle to this mean speed [km/h]")] = None,
    ambient_degc: Annotated[float | None, typer.Option(help="Ambient for cycle days [degC]")] = None,
    soc_start_pct: Annotated[float | None, typer.Option(help="Initial SoC [%]")] = None,
    load: Annotated[str | None, typer.Option(
        help="Passenger load: driver, half, full (the paper's categories) or a fraction 0-1")]
    = None,
    with_: WithOpt = None,
    without: WithoutOpt = None,
    set_: SetOpt = None,
    overlay: OverlayOpt = None,
    columns: Annotated[str | None, typer.Option(
        help="Column map preset for --measured (configs/logs), e.g. bmw_i3_tum")] = None,
    gaps: Annotated[str, typer.Option(help="Gaps in --measured: error, split, hold, interpolate")]
    = "error",
    fill: Annotated[str, typer.Option(help="Missing values: error or interpolate")] = "error",
    no_unit_check: Annotated[bool, typer.Option(help="Skip the m/s-vs-km/h and SoC-unit checks")]
    = False,
    dt_s: Annotated[float, typer.Option("--dt", help="Time step [s]")] = 0.1,
    out: Annotated[Path | None, typer.Option(help="Write the trace (.parquet or .csv)")] = None,
    plot: Annotated[Path | None, typer.Option(help="Plot speed, power, SoC, cabin (PNG)")] = None,
    json_path: Annotated[Path | None, typer.Option("--json", help="Write the summary as JSON")]
    = None,
):
    """Run a bus through a cycle day or a measured log and print the energy table."""
    _run(lambda: _simulate(bus, cycle, measured, hours, mean_speed_kmh, ambient_degc,
                           soc_start_pct, load, with_, without, set_, overlay, columns, gaps,
                           fill, not no_unit_check, dt_s, out, plot, json_path))


def _load_frac(load: str) -> float:
    from ebus_env.config import LOAD_CATEGORIES
    from ebus_env.errors import ConfigError

    if load in LOAD_CATEGORIES:
        return LOAD_CATEGORIES[load]
    try:
        return float(load)
    except ValueError:
        raise ConfigError(f"--load: '{load}' is none of {', '.join(LOAD_CATEGORIES)} "
                          "and not a fraction.") from None


def _simulate(bus_name, cycle, measured, hours, mean_speed_kmh, ambient_degc, soc_start_pct,
              load, with_, without, set_, overlay, columns, gaps, fill, check_units, dt_s, out,
              plot, json_path):
    from ebus_env.config import load_bus
    from ebus_env.errors import ConfigError
    from ebus_env.report import summary_tables, write_json
    from ebus_env.simulate import run_profiles

    console = _console()
    if (cycle is None) == (measured is None):
        if cycle is None and measured is None:
            cycle = "sort2"
        else:
            raise ConfigError("Give either --cycle or --measured, not both.")
    bus = load_bus(bus_name, with_=_split(with_), without=_split(without), overlays=overlay or [])
    t0 = time.perf_counter()
    model = bus.build(dt_s)
    overrides = _overrides(set_)
    if load is not None:
        overrides["passenger_load.load_frac"] = _load_frac(load)
    params = model.param_vector(overrides)
    record = out is not None or plot is not None or measured is not None
    compile_s = model.compile(record)
    if measured is not None:
        profiles = _load_logs([measured], model, params, columns, gaps, fill, check_units, console)
    else:
        from ebus_env.cycles import service_day

        profiles = [service_day(cycle, hours, dt_s, bus.service, mean_speed_kmh, ambient_degc)]
        for line in profiles[0].notes:
            console.print(f"[dim]cycle:[/] {line}", highlight=False)
    soc_start = None if soc_start_pct is None else soc_start_pct / 100.0
    if soc_start is None and measured is None:
        soc_start = bus.service.soc_start_pct / 100.0
    run = run_profiles(model, profiles, params, soc_start, record)
    summary = run.summary
    summary["compile_or_load_s"] = compile_s
    title = f"{bus.name} on {run.label}"
    figures, breakdown = summary_tables(summary, title)
    console.print(figures)
    console.print(breakdown)
    console.print(f"[dim]model built and loaded in {time.perf_counter() - t0 - summary['wall_time_s']:.2f} s"
                  f" (compile/cache {compile_s:.2f} s); simulated in "
                  f"{1e3 * summary['wall_time_s']:.1f} ms[/]", highlight=False)
    if json_path:
        write_json(summary, json_path)
        console.print(f"summary -> {json_path}")
    if out:
        frame = run.trace_frame()
        if out.suffix == ".csv":
            frame.to_csv(out, index=False)
        else:
            frame.to_parquet(out, index=False)
        console.print(f"trace ({len(frame)} rows x {frame.shape[1]} signals) -> {out}")
    if plot:
        from ebus_env.plotting import plot_trace

        plot_trace(run.results[0], plot)
        if len(run.results) > 1:
            console.print("[yellow]plot shows the first segment only[/]")
        console.print(f"plot -> {plot}")


@app.command()
def calibrate(
    logs: Annotated[list[Path] | None, typer.Argument(
        help="Measured log(s) with SoC (CSV/Parquet)")] = None,
    bus: BusOpt = "12m",
    params: Annotated[str | None, typer.Option(
        help="Free parameters, comma-separated qualified names (default: the paper's seven)")]
    = None,
    fix: Annotated[list[str] | None, typer.Option(
        help="Known value: effect.param=value (repeatable)")] = None,
    range_: Annotated[list[str] | None, typer.Option(
        "--range", help="Prior range: effect.param=low:high, narrowing its bounds (repeatable)")]
    = None,
    windowed: Annotated[bool, typer.Option(help="Windowed (online) tuning")] = False,
    validate: Annotated[list[Path] | None, typer.Option(
        help="Validation log(s): scored with the fitted parameters, never tuned on")] = None,
    seed: Annotated[int, typer.Option(help="Random seed of iSOPT")] = 0,
    population: Annotated[int | None, typer.Option(help="iSOPT population (default 11)")] = None,
    iterations: Annotated[int | None, typer.Option(help="iSOPT iterations (default 50)")] = None,
    categorical_load: Annotated[bool, typer.Option(
        help="Passenger load only driver / half / full (the paper's categories)")] = False,
    config: Annotated[str | None, typer.Option(
        help="Calibration config (configs/calibration/NAME.yaml or a path)")] = None,
    with_: WithOpt = None,
    without: WithoutOpt = None,
    overlay: OverlayOpt = None,
    columns: Annotated[str | None, typer.Option(help="Column map preset, e.g. bmw_i3_tum")]
    = None,
    gaps: Annotated[str, typer.Option(help="Gaps: error, split, hold, interpolate")] = "error",
    fill: Annotated[str, typer.Option(help="Missing values: error or interpolate")] = "error",
    no_unit_check: Annotated[bool, typer.Option(help="Skip the unit checks")] = False,
    sparse: Annotated[bool, typer.Option(
        help="The logs are sparse (speed, distance, SoC every few minutes)")] = False,
    sparse_cycle: Annotated[str, typer.Option(help="Cycle that fills sparse intervals")] = "sort2",
    out: Annotated[Path | None, typer.Option(help="Write the fitted values as a bus overlay")]
    = None,
    json_path: Annotated[Path | None, typer.Option("--json", help="Write the results as JSON")]
    = None,
    plot: Annotated[Path | None, typer.Option(help="Plot simulated vs measured SoC")] = None,
    history: Annotated[Path | None, typer.Option(help="Write the convergence history (CSV)")]
    = None,
    fleet: Annotated[Path | None, typer.Option(
        help="Calibrate each log of this folder on its own: a per-log parameter table with "
             "outliers flagged (--out table.csv or .parquet)")] = None,
    use_ray: Annotated[bool, typer.Option("--ray", help="With --fleet: one Ray task per log")]
    = False,
    address: Annotated[str | None, typer.Option(help="With --fleet: the Ray cluster's host:port")]
    = None,
):
    """Fit the model's uncertain parameters to measured SoC (iSOPT, offline or windowed)."""
    if fleet is not None:
        from ebus_env.study.calibration import fleet_command

        _run(lambda: fleet_command(fleet, bus, columns, params, seed, population, iterations,
                                   use_ray, address, out, _console()))
        return

    def body():
        if not logs:
            from ebus_env.errors import ConfigError

            raise ConfigError("Give the measured log(s) to calibrate on, or --fleet FOLDER.")
        _calibrate(logs, bus, params, fix, range_, windowed, validate, seed, population,
                   iterations, categorical_load, config, with_, without, overlay, columns, gaps,
                   fill, not no_unit_check, sparse, sparse_cycle, out, json_path, plot, history)

    _run(body)


def _ranges(items: list[str] | None) -> dict[str, tuple[float, float]]:
    from ebus_env.errors import ConfigError

    out = {}
    for item in items or []:
        try:
            name, value = item.split("=", 1)
            low, high = (float(x) for x in value.split(":"))
        except ValueError:
            raise ConfigError(f"--range needs effect.param=low:high, got '{item}'.") from None
        out[name.strip()] = (low, high)
    return out


def _calibrate(logs, bus_name, params, fix, range_, windowed, validate, seed, population,
               iterations, categorical_load, config, with_, without, overlay, columns, gaps,
               fill, check_units, sparse, sparse_cycle, out, json_path, plot, history):
    from dataclasses import replace

    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from ebus_env.calibration import calibrate as run_calibration
    from ebus_env.calibration.settings import load_calibration_config
    from ebus_env.config import load_bus
    from ebus_env.report import calibration_tables, write_json

    console = _console()
    cfg = load_calibration_config(config)
    bus = load_bus(bus_name, with_=_split(with_), without=_split(without), overlays=overlay or [])
    model = bus.build()
    fixed = {**cfg.fixed, **_overrides(fix)}
    base = model.param_vector(fixed)
    if sparse:
        from ebus_env.io.sparse import load_sparse_log

        vmax = base[model.param_index("vehicle_body.max_speed_kmh")]
        loaded = [load_sparse_log(p, model.dt_s, cycle=sparse_cycle, columns=columns,
                                  max_speed_kmh=vmax) for p in [*logs, *(validate or [])]]
        for path, log in zip([*logs, *(validate or [])], loaded, strict=True):
            for line in log.report.changes:
                console.print(f"[dim]sparse ({Path(path).name}):[/] {line}", highlight=False)
        profiles = [log.profile for log in loaded[:len(logs)]]
        check = [log.profile for log in loaded[len(logs):]]
    else:
        profiles = _load_logs(logs, model, base, columns, gaps, fill, check_units, console)
        check = _load_logs(validate or [], model, base, columns, gaps, fill, check_units,
                           console)
    free = _split([params]) if params else cfg.params
    settings = replace(cfg.isopt, seed=seed, **({"population": population} if population else {}),
                       **({"iterations": iterations} if iterations else {}))
    model.compile(sample=True)
    total = settings.iterations if not windowed else None
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(),
                  TextColumn("{task.completed}/{task.total}"),
                  TextColumn("best cost {task.fields[best]:.5f}"),
                  TextColumn("{task.fields[evals]} evaluations"),
                  TimeElapsedColumn(), console=console, transient=False) as bar:
        task = bar.add_task("windows" if windowed else "iSOPT", total=total, best=float("nan"),
                            evals=0)

        def progress(i, best, evals):
            bar.update(task, completed=i, best=best, evals=evals)

        result = run_calibration(
            model, profiles, free, {**cfg.ranges, **_ranges(range_)}, fixed, settings,
            validate=check or None, windowed=windowed,
            categorical_load=categorical_load or cfg.categorical_load, progress=progress,
            window_settings=cfg.windows, polish_starts=None if windowed else cfg.polish_starts)
    for line in result.notes:
        console.print(f"[yellow]note:[/] {line}", highlight=False)
    for line in result.warnings:
        console.print(f"[yellow]warning:[/] {line}", highlight=False)
    params_table, fit_table = calibration_tables(result)
    console.print(params_table)
    console.print(fit_table)
    console.print(f"[dim]{result.method}: {result.evaluations} evaluations, "
                  f"{result.simulated_steps / 1e6:.1f} M bus-steps, {result.wall_time_s:.1f} s[/]",
                  highlight=False)
    if result.interrupted:
        console.print("[bold yellow]Interrupted: the values above are the best found so far.[/]")
    if out:
        result.write_overlay(out)
        console.print(f"overlay -> {out}  (ebus simulate --bus {bus_name} --overlay {out})")
    if json_path:
        write_json(result.to_json(), json_path)
        console.print(f"results -> {json_path}")
    if plot:
        result.plot(plot)
        history_png = plot.with_name(plot.stem + "_history" + plot.suffix)
        result.plot_history(history_png)
        written = [plot, history_png]
        if result.determinacy:
            written.append(plot.with_name(plot.stem + "_determinacy" + plot.suffix))
            result.plot_determinacy(written[-1])
        console.print(f"plots -> {', '.join(map(str, written))}")
    if history:
        import pandas as pd

        pd.DataFrame({"iteration": range(len(result.history.best_cost)),
                      "evaluations": result.history.evaluations,
                      "best_cost": result.history.best_cost}).to_csv(history, index=False)
        console.print(f"history -> {history}")


@app.command()
def diagnose(
    logs: Annotated[list[Path], typer.Argument(help="Measured log(s) with SoC (CSV/Parquet)")],
    bus: BusOpt = "12m",
    with_: WithOpt = None,
    without: WithoutOpt = None,
    overlay: OverlayOpt = None,
    calibrate: Annotated[bool, typer.Option(
        help="Calibrate the paper's parameters on the calibration blocks first")] = False,
    add: Annotated[list[str] | None, typer.Option(
        help="Error ladder: add this effect and re-calibrate (repeatable, in order; "
             "my_effects.py:Name for your own)")] = None,
    html: Annotated[Path | None, typer.Option(help="Write the report as one HTML file")]
    = None,
    json_path: Annotated[Path | None, typer.Option("--json", help="Write the report as JSON")]
    = None,
    window_s: Annotated[float | None, typer.Option(
        help="Window length [s] (default: 300 from SoC, 60 from current x voltage)")] = None,
    config: Annotated[str | None, typer.Option(
        help="Calibration config for --calibrate/--add (configs/calibration/NAME.yaml)")] = None,
    seed: Annotated[int, typer.Option(help="Random seed of iSOPT")] = 0,
    columns: Annotated[str | None, typer.Option(help="Column map preset, e.g. bmw_i3_tum")]
    = None,
    gaps: Annotated[str, typer.Option(help="Gaps: error, split, hold, interpolate")] = "error",
    fill: Annotated[str, typer.Option(help="Missing values: error or interpolate")] = "error",
    no_unit_check: Annotated[bool, typer.Option(help="Skip the unit checks")] = False,
):
    """Where the model fails against measurements, and which effect is missing.

    Shows the error before and after adding each effect (--add), re-calibrated each time."""
    _run(lambda: _diagnose(logs, bus, with_, without, overlay, calibrate, add, html,
                           json_path, window_s, config, seed, columns, gaps, fill,
                           not no_unit_check))


def _diagnose(logs, bus_name, with_, without, overlay, calibrate, add, html, json_path,
              window_s, config, seed, columns, gaps, fill, check_units):
    from dataclasses import replace

    from ebus_env.calibration.settings import load_calibration_config
    from ebus_env.config import load_bus
    from ebus_env.diagnostics import diagnose as run_diagnosis
    from ebus_env.diagnostics.report import console_tables

    console = _console()
    cfg = load_calibration_config(config)
    bus = load_bus(bus_name, with_=_split(with_), without=_split(without), overlays=overlay or [])
    model = bus.build()
    notes: list[str] = []
    profiles = _load_logs(logs, model, model.params, columns, gaps, fill, check_units, console,
                          notes)
    with console.status("diagnosing") as status:
        result = run_diagnosis(bus, profiles, calibrate=calibrate, add=_split(add),
                               window_s=window_s, settings=replace(cfg.isopt, seed=seed),
                               polish_starts=cfg.polish_starts, loader_notes=notes,
                               progress=lambda text: status.update(text))
    for table in console_tables(result):
        console.print(table)
    style = "bold green" if result.verdict else "bold"
    console.print(f"[{style}]{result.sentence}[/]", highlight=False)
    console.print(f"[dim]{result.timings['total_s']:.1f} s[/]", highlight=False)
    if html:
        result.write_html(html)
        console.print(f"report -> {html}")
    if json_path:
        result.write_json(json_path)
        console.print(f"results -> {json_path}")


@app.command()
def cycles():
    """List the shipped driving cycles."""

    def body():
        from rich.table import Table

        from ebus_env.cycles import CYCLES, load_cycle

        table = Table(title="driving cycles (data/cycles)")
        for col in ("name", "duration s", "distance km", "mean km/h", "max km/h", "description"):
            table.add_column(col)
        for name in CYCLES:
            c = load_cycle(name)
            table.add_row(name, f"{c.duration_s:.0f}", f"{c.distance_km:.2f}",
                          f"{c.mean_speed_kmh:.1f}", f"{c.speed_kmh.max():.1f}", c.description)
        _console().print(table)

    _run(body)


@app.command()
def effects(
    bus: Annotated[str | None, typer.Option("--bus", "-b", help="Show this bus's values")] = None,
    with_: WithOpt = None,
):
    """List the effects with their parameters (default or the bus's value, unit, bounds)."""

    def body():
        from rich.markup import escape

        from ebus_env.config import load_bus, resolve_effect
        from ebus_env.effects.base import registered_effects

        for item in _split(with_):
            resolve_effect(item)
        values, in_model = {}, None
        if bus:
            model = load_bus(bus, with_=_split(with_)).build()
            values = dict(zip(model.param_names, model.params, strict=True))
            in_model = {e.name for e in model.effects}
        console = _console()
        console.print(f"[bold]effects{f' of bus {bus}' if bus else ''}[/]  (parameter, value, "
                      "unit, bounds, meaning)")
        for name, eff in sorted(registered_effects().items(), key=lambda kv: (kv[1].role, kv[0])):
            if in_model is not None and name not in in_model:
                continue
            summary = escape((eff.doc or "").strip().split("\n")[0])
            console.print(f"\n[bold cyan]{name}[/]  [dim]{eff.role}[/]  {summary}",
                          soft_wrap=True, highlight=False)
            for p in eff.params:
                value = values.get(f"{name}.{p.name}", p.default)
                console.print(f"    {p.name:30s} {value:>10g} {p.unit:8s} "
                              f"[{p.bounds[0]:g}, {p.bounds[1]:g}]  {p.description}",
                              soft_wrap=True, highlight=False, markup=False)

    _run(body)


@app.command()
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
    = Path("report/evaluate"),
):
    """Score policies on the same held-out days: energy, grid load, comfort, delay."""

    def body():
        from ebus_env.agents.evaluate import evaluate as run
        from ebus_env.agents.evaluate import print_sheet
        from ebus_env.agents.ppo import load_policy

        console = _console()
        sheet = run([load_policy(spec) for spec in policy], env, episodes=episodes,
                    **_env_overrides(set_))
        print_sheet(sheet, console)
        for path in sheet.write(out):
            console.print(f"[bold green]->[/] {path}")

    _run(body)


def _env_overrides(items: list[str] | None) -> dict:
    import yaml

    from ebus_env.errors import ConfigError

    out = {}
    for item in items or []:
        if "=" not in item:
            raise ConfigError(f"--set needs key=value, got '{item}'.")
        key, value = item.split("=", 1)
        out[key.strip()] = yaml.safe_load(value)
    return out


@app.command()
def train(
    config: Annotated[Path | None, typer.Option(help="PPO config (configs/agents/ppo.yaml)")]
    = None,
    steps: Annotated[int | None, typer.Option(help="Total env steps (overrides the config)")]
    = None,
    seed: Annotated[int | None, typer.Option(help="Seed (overrides the config)")] = None,
    out: Annotated[Path, typer.Option(help="Folder for the agent, checkpoints, TensorBoard")]
    = Path("runs/ppo"),
):
    """Train PPO on EBus-v0's native vector env (stable-baselines3)."""

    def body():
        from ebus_env.agents.ppo import PPOConfig
        from ebus_env.agents.ppo import train as run

        overrides = {k: v for k, v in (("total_steps", steps), ("seed", seed)) if v is not None}
        cfg = PPOConfig.load(config, **overrides)
        path = run(cfg, out, progress=False)
        done = json.loads((path / "training.json").read_text())
        _console().print(f"[bold green]agent ->[/] {path / 'model.zip'} ({done['steps']:,} "
                         f"steps in {done['wall_s']:.0f} s)")

    _run(body)


@app.command()
def demo(
    out: Annotated[Path, typer.Option(help="Folder for the report")] = Path("report"),
):
    """The main job on bundled data: simulate bus days and measured trips, write a report."""

    def body():
        from ebus_env.demo import run_demo

        path = run_demo(out, console=_console())
        _console().print(f"[bold green]report ->[/] {path}")

    _run(body)


@app.command()
def study(
    study_file: Annotated[Path, typer.Argument(help="Study YAML (configs/studies/)")],
    out: Annotated[Path, typer.Option(help="Folder for rows/, summary.csv, report.html")] = Path(
        "study"),
    resume: Annotated[bool, typer.Option(help="Skip the scenarios already in --out")] = False,
    use_ray: Annotated[bool, typer.Option("--ray", help="Run the scenarios on Ray")] = False,
    address: Annotated[str | None, typer.Option(help="Join the Ray cluster at host:port")] = None,
    workers: Annotated[int | None, typer.Option(
        help="Threads in this process, or CPUs of a local Ray runtime (default: every CPU)")] = None,
):
    """A fleet study: charging options x strategies over seeded days, by cost and grid load."""

    def body():
        from ebus_env.study.command import study_command

        path = study_command(study_file, out, resume, use_ray, address, workers, _console())
        _console().print(f"[bold green]report ->[/] {path}")

    _run(body)


def main():  # pragma: no cover
    sys.exit(app())


if __name__ == "__main__":  # pragma: no cover
    main()
