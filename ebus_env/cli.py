"""Command line: ``ebus simulate``, ``calibrate``, ``diagnose``, ``study``, ``cycles``,
``effects``, ``demo``, and the commands other modules and installed packages register
(``train``, ``evaluate`` of ``agents``).

Each command parses its options and calls one library function that does the work (it is the
Python API too): :func:`~ebus_env.simulate.simulate_bus`,
:func:`~ebus_env.calibration.calibrate_logs.calibrate_logs`,
:func:`~ebus_env.diagnostics.diagnose_logs.diagnose_logs`,
:func:`~ebus_env.study.command.run_study_file`, :func:`~ebus_env.demo.run_demo`; then it prints
the result that function returns (:mod:`ebus_env.console`). Options that several commands
share are declared once, in :mod:`ebus_env.cli_options`. Only typer and that module are imported
here at the top, so that ``ebus --help`` starts quickly: a command imports its work when it runs.

Adding commands (one line here each, so that branches merge cleanly):

- a module of this package: give it ``register(app)``, which adds its commands
  (``app.command()(fn)``) or a group of them (``app.add_typer(group, name="twin")``); import at
  its top only typer, the standard library and :mod:`ebus_env.cli_options` (whose
  :func:`~ebus_env.cli_options.run_command` runs a command body: an error as one line, exit 2);
  and name the module in ``COMMAND_MODULES`` below;
- another installed package: name its ``register`` in the entry-point group
  ``ebus_env.commands`` of its ``pyproject.toml`` (``agents`` adds ``train`` and ``evaluate``).
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path
from typing import Annotated

import typer

from ebus_env.cli_options import (
    BusOpt,
    ColumnsOpt,
    FillOpt,
    GapsOpt,
    JsonOpt,
    NoUnitCheckOpt,
    OverlayOpt,
    SeedOpt,
    SetOpt,
    StartOpt,
    WithOpt,
    WithoutOpt,
    console,
    parse_ranges,
    parse_settings,
    refuse_unused,
    run_command,
)

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="Lo-Fi electric-bus model: simulate, calibrate, diagnose; train and evaluate "
                       "ECO policies.")

# Modules of this package that add commands, each through its register(app): one a line.
COMMAND_MODULES: tuple[str, ...] = (
    "ebus_env.depot.depot_command",  # ebus depot
    "ebus_env.twin.twin_command",  # ebus twin
)

_run, _console = run_command, console  # the names command modules imported from here before


def _bus(name, with_, without, overlay):
    """The bus options as a :class:`~ebus_env.bus_choice.BusChoice`."""
    from ebus_env.bus_choice import BusChoice

    return BusChoice(name, with_, without, overlay)


def _reading(columns, gaps, fill, no_unit_check, start_time):
    """The log options as a :class:`~ebus_env.io.log_reading.LogReading`."""
    from ebus_env.io.log_reading import LogReading

    return LogReading(columns, gaps, fill, not no_unit_check, start_time)


@app.command()
def simulate(
    bus: BusOpt = "12m",
    cycle: Annotated[str | None, typer.Option(help="Cycle name (see `ebus cycles`) or CSV")] = None,
    measured: Annotated[Path | None, typer.Option(help="Measured log (CSV/Parquet) to replay")] = None,
    hours: Annotated[float | None, typer.Option(
        help="Length of the cycle day [h] (default 13.5)")] = None,
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
    columns: ColumnsOpt = None,
    gaps: GapsOpt = "error",
    fill: FillOpt = "error",
    no_unit_check: NoUnitCheckOpt = False,
    start_time: StartOpt = None,
    dt_s: Annotated[float, typer.Option("--dt", help="Time step [s]")] = 0.1,
    out: Annotated[Path | None, typer.Option(help="Write the trace (.parquet or .csv)")] = None,
    plot: Annotated[Path | None, typer.Option(help="Plot speed, power, SoC, cabin (PNG)")] = None,
    json_path: JsonOpt = None,
):
    """Run a bus through a cycle day or a measured log and print the energy table."""

    def body():
        from ebus_env.console import print_simulation
        from ebus_env.simulate import simulate_bus

        shown = console()
        print_simulation(simulate_bus(
            _bus(bus, with_, without, overlay), cycle=cycle, measured=measured, hours=hours,
            mean_speed_kmh=mean_speed_kmh, ambient_degc=ambient_degc,
            soc_start_pct=soc_start_pct, load=load, params=parse_settings(set_),
            reading=_reading(columns, gaps, fill, no_unit_check, start_time), dt_s=dt_s,
            out=out, plot=plot, json_path=json_path, console=shown), shown)

    run_command(body)


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
    charge: Annotated[bool, typer.Option(
        help="Fit the charge counted from the logs' battery current beside the SoC (a BMS "
             "log: it resolves the charge far below the SoC's steps)")] = False,
    validate: Annotated[list[Path] | None, typer.Option(
        help="Validation log(s): scored with the fitted parameters, never tuned on")] = None,
    seed: SeedOpt = 0,
    population: Annotated[int | None, typer.Option(help="iSOPT population (default 11)")] = None,
    iterations: Annotated[int | None, typer.Option(help="iSOPT iterations (default 50)")] = None,
    categorical_load: Annotated[bool, typer.Option(
        help="Passenger load only driver / half / full (the paper's categories)")] = False,
    config: Annotated[str | None, typer.Option(
        help="Calibration config (configs/calibration/NAME.yaml or a path)")] = None,
    with_: WithOpt = None,
    without: WithoutOpt = None,
    overlay: OverlayOpt = None,
    columns: ColumnsOpt = None,
    gaps: GapsOpt = "error",
    fill: FillOpt = "error",
    no_unit_check: NoUnitCheckOpt = False,
    start_time: StartOpt = None,
    sparse: Annotated[bool, typer.Option(
        help="The logs are sparse (speed, distance, SoC every few minutes)")] = False,
    sparse_cycle: Annotated[str, typer.Option(help="Cycle that fills sparse intervals")] = "sort2",
    out: Annotated[Path | None, typer.Option(help="Write the fitted values as a bus overlay")]
    = None,
    json_path: JsonOpt = None,
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

    def fleet_body():
        from ebus_env.study.fleet_calibration import calibrate_fleet, print_fleet

        # what a fleet calibration does not take: refused, not ignored
        refuse_unused({
            "LOGS": logs, "--with": with_, "--without": without, "--overlay": overlay,
            "--fix": fix, "--range": range_, "--windowed": windowed, "--charge": charge,
            "--validate": validate, "--categorical-load": categorical_load, "--config": config,
            "--gaps": gaps != "error", "--fill": fill != "error", "--no-unit-check": no_unit_check,
            "--start-time": start_time, "--sparse": sparse, "--json": json_path, "--plot": plot,
            "--history": history},
            "--fleet calibrates each log of the folder with --bus, --columns, --params, --seed, "
            "--population, --iterations, --out, --ray and --address only",
            "calibrate the logs one by one")
        shown, table_path = console(), out or Path("fleet_params.csv")
        table = calibrate_fleet(
            fleet, bus, table_path, columns=columns, free=params, seed=seed,
            population=population, iterations=iterations, use_ray=use_ray, address=address,
            say=lambda line: shown.print(line, highlight=False))
        print_fleet(table, bus, table_path, shown)

    def body():
        from ebus_env.calibration.calibrate_logs import calibrate_logs
        from ebus_env.console import print_calibration
        from ebus_env.errors import ConfigError

        if not logs:
            raise ConfigError("Give the measured log(s) to calibrate on, or --fleet FOLDER.")
        shown = console()
        print_calibration(calibrate_logs(
            logs, _bus(bus, with_, without, overlay), validate=validate, free=params,
            fixed=parse_settings(fix, "--fix"), ranges=parse_ranges(range_),
            windowed=windowed, charge=charge, seed=seed, population=population,
            iterations=iterations, categorical_load=categorical_load, config=config,
            reading=_reading(columns, gaps, fill, no_unit_check, start_time), sparse=sparse,
            sparse_cycle=sparse_cycle, out=out, json_path=json_path, plot=plot,
            history=history, console=shown), shown)

    run_command(body if fleet is None else fleet_body)


@app.command()
def diagnose(
    logs: Annotated[list[Path], typer.Argument(
        help="Measured log(s) with SoC (CSV/Parquet), or a folder of them: several days of "
             "one bus")],
    bus: BusOpt = "12m",
    with_: WithOpt = None,
    without: WithoutOpt = None,
    overlay: OverlayOpt = None,
    calibrate: Annotated[bool, typer.Option(
        help="Calibrate on the calibration blocks first: the paper's parameters and the "
             "bus-to-bus ones (mass, C_rr, aux base, drivetrain efficiency, cell capacity and "
             "resistance)")] = False,
    add: Annotated[list[str] | None, typer.Option(
        help="Error ladder: add this effect and re-calibrate (repeatable, in order; "
             "my_effects.py:Name for your own)")] = None,
    html: Annotated[Path | None, typer.Option(help="Write the report as one HTML file")]
    = None,
    json_path: JsonOpt = None,
    window_s: Annotated[float | None, typer.Option(
        help="Window length [s] (default: 300; on a log of the pack's current shorter, down "
             "to 60, so that a short trip still has 50)")] = None,
    soc_only: Annotated[bool, typer.Option(
        "--soc-only", help="Diagnose from SoC alone where the log has the pack's current "
        "too (see docs/validation.md: run both)")] = False,
    domain: Annotated[str, typer.Option(
        help="soc: SoC windows; power: the bus fitted to the pack's power, BMS logs (the "
             "pack's current and voltage) second by second and SoC-only logs by the charge "
             "the SoC counts in each 5-min window, several days of a bus with the day a "
             "change started; auto: power on BMS logs")] = "soc",
    config: Annotated[str | None, typer.Option(
        help="Calibration config for --calibrate/--add (configs/calibration/NAME.yaml): its "
             "params free in place of the paper's, its ranges, fixed values and iSOPT "
             "settings")] = None,
    seed: SeedOpt = 0,
    columns: ColumnsOpt = None,
    gaps: GapsOpt = "error",
    fill: FillOpt = "error",
    no_unit_check: NoUnitCheckOpt = False,
    start_time: StartOpt = None,
    set_: Annotated[list[str] | None, typer.Option(
        "--set", help="A known parameter value, effect.param=value (repeatable): held in "
                      "--calibrate and --add")] = None,
    reference: Annotated[list[Path] | None, typer.Option(
        help="A log of a normal day of the same bus (repeatable): calibrated first, the "
             "diagnosis then says what the day misses beyond it (implies --calibrate)")]
    = None,
):
    """Where the model fails against measurements, and which effect is missing.

    Shows the error before and after adding each effect (--add), re-calibrated each time."""

    def body():
        from ebus_env.console import print_diagnosis
        from ebus_env.diagnostics.diagnose_logs import diagnose_logs

        shown = console()
        print_diagnosis(diagnose_logs(
            logs, _bus(bus, with_, without, overlay), calibrate=calibrate, add=add or (),
            known=parse_settings(set_), reference=reference, window_s=window_s,
            soc_only=soc_only, domain=domain, config=config, seed=seed,
            reading=_reading(columns, gaps, fill, no_unit_check, start_time), html=html,
            json_path=json_path, console=shown), shown)

    run_command(body)


@app.command()
def cycles():
    """List the shipped driving cycles."""

    def body():
        from ebus_env.console import cycles_table

        console().print(cycles_table())

    run_command(body)


@app.command()
def effects(
    bus: Annotated[str | None, typer.Option("--bus", "-b", help="Show this bus's values")] = None,
    with_: WithOpt = None,
):
    """List the effects with their parameters (default or the bus's value, unit, bounds)."""

    def body():
        from ebus_env.console import print_effects

        print_effects(console(), bus, with_)

    run_command(body)


@app.command()
def demo(
    out: Annotated[Path, typer.Option(help="Folder for the report")] = Path("report"),
):
    """The main job on bundled data: simulate bus days and measured trips, write a report."""

    def body():
        from ebus_env.demo import run_demo

        shown = console()
        shown.print(f"[bold green]report ->[/] {run_demo(out, console=shown)}")

    run_command(body)


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
        from ebus_env.study.command import print_study, run_study_file

        shown = console()
        done = run_study_file(study_file, out, resume=resume, use_ray=use_ray, address=address,
                              workers=workers, console=shown)
        print_study(done, shown)
        shown.print(f"[bold green]report ->[/] {done.report}")

    run_command(body)


def _add_commands() -> None:
    """The commands of ``COMMAND_MODULES``, then those of other installed packages: each entry
    point of the group ``ebus_env.commands`` is a function ``register(app)``. ``ebus_env``
    names no package above it."""
    from importlib.metadata import entry_points

    for name in COMMAND_MODULES:
        importlib.import_module(name).register(app)
    for entry in entry_points(group="ebus_env.commands"):
        try:
            entry.load()(app)
        except ImportError as exc:  # a broken plug-in must not take `ebus simulate` down
            print(f"ebus: commands of {entry.value} not loaded ({exc}).", file=sys.stderr)


_add_commands()


def main():  # pragma: no cover
    sys.exit(app())


if __name__ == "__main__":  # pragma: no cover
    main()
