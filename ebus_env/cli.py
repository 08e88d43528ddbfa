"""Command line: ``ebus simulate``, ``calibrate``, ``diagnose``, ``cycles``, ``effects``,
``demo``, and the commands installed packages register (``train``, ``evaluate`` of ``agents``)."""

from __future__ import annotations

import itertools
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import typer

from ebus_env.depot.depot_command import register as _register_depot
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
StartOpt = Annotated[str | None, typer.Option(
    "--start-time", help="Clock time of the log's first row, HH:MM, for a log without "
                         "date-times (else 00:00)")]


@dataclass(frozen=True)
class BusChoice:
    """The bus of a command: ``--bus``, ``--with``, ``--without``, ``--overlay``."""

    name: str
    with_: list[str] | None = None
    without: list[str] | None = None
    overlays: list[Path] | None = None

    def load(self):
        """The :class:`~ebus_env.config.BusConfig`, effects added and removed, overlays merged."""
        from ebus_env.config import load_bus

        return load_bus(self.name, with_=_split(self.with_), without=_split(self.without),
                        overlays=self.overlays or [])

    def files(self, bus) -> list[Path]:
        """The files this choice reads: the bus config, the overlays, the effect files."""
        return _inputs([bus.path], self.overlays, effects=self.with_)

    def options(self) -> str:
        """This choice as command-line options (``--bus 12m --without cabin_hvac ...``)."""
        return " ".join([f"--bus {self.name}", *(f"--with {w}" for w in self.with_ or []),
                         *(f"--without {w}" for w in self.without or []),
                         *(f"--overlay {o}" for o in self.overlays or [])])


@dataclass(frozen=True)
class LogHandling:
    """How measured logs are read: ``--columns``, ``--gaps``, ``--fill``, ``--no-unit-check``,
    ``--start-time``."""

    columns: str | None = None
    gaps: str = "error"
    fill: str = "error"
    check_units: bool = True
    start_time: str | None = None

    @property
    def start_h(self) -> float | None:
        return None if self.start_time is None else _clock_h(self.start_time)


def _clock_h(text: str) -> float:
    """``HH:MM`` or ``HH:MM:SS`` as hours after midnight."""
    from ebus_env.errors import ConfigError

    parts = text.split(":")
    try:
        if not 2 <= len(parts) <= 3:
            raise ValueError
        h, m, sec = (int(p) for p in parts + ["0"] * (3 - len(parts)))
    except ValueError:
        raise ConfigError(f"--start-time needs HH:MM (e.g. 07:30), got '{text}'.") from None
    if not (0 <= h <= 23 and 0 <= m <= 59 and 0 <= sec <= 59):
        raise ConfigError(f"--start-time {text} is not a time of day: give HH:MM with HH "
                          "0-23 and MM 0-59.")
    return h + m / 60 + sec / 3600


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
        key = key.strip()
        if key in out:
            raise ConfigError(f"--set {key} is given twice ({out[key]:g} and {value}): keep "
                              "one.")
        try:
            out[key] = float(value)
        except ValueError:
            raise ConfigError(f"--set {key}: '{value}' is not a number.") from None
    return out


def _load_logs(paths, model, params, handling: LogHandling, console, notes=None):
    """Profiles of measured logs, with the loader's report printed (and its changes appended
    to ``notes``)."""
    from ebus_env.io.measured import load_log

    vmax = params[model.param_index("vehicle_body.max_speed_kmh")] \
        if model.has_effect("vehicle_body") else None
    start_h = handling.start_h
    profiles = []
    for path in paths:
        log = load_log(path, model.dt_s, columns=handling.columns, gaps=handling.gaps,
                       fill=handling.fill, check_units=handling.check_units, max_speed_kmh=vmax,
                       max_accel_mps2=4.0, start_h=start_h)
        profiles += log.profiles
        if notes is not None:
            notes += log.report.changes
        _print_report(log.report, path, "loader", console)
    return profiles


def _print_report(report, path, who: str, console) -> None:
    """A loader's report: its changes (dim), then its warnings and ignored columns."""
    from rich.markup import escape

    for line in report.changes:
        console.print(f"[dim]{who} ({Path(path).name}):[/] {escape(line)}", highlight=False,
                      soft_wrap=True)
    for line in report.warnings + report.ignored:
        console.print(f"[yellow]{who} ({Path(path).name}):[/] {escape(line)}", highlight=False,
                      soft_wrap=True)


def _refuse_same_log(option: str, given, logs, role: str, why: str) -> None:
    """Refuse a log of ``option`` that is one of ``logs`` (``role``) or a copy of it."""
    from ebus_env.errors import ConfigError
    from ebus_env.outputs import same_bytes, same_file

    for other, log in itertools.product(given or [], logs):
        if Path(other).exists() and Path(log).exists() and (
                same_file(Path(other), Path(log)) or same_bytes(other, log)):
            raise ConfigError(f"{option} {other} is {role} ({log}) or a copy of it: {why}. "
                              "Fix: give a log of another day.")


def _refuse_twice(logs) -> None:
    """Refuse a log given twice (or with a copy of it): its windows would count twice."""
    for i, log in enumerate(logs):
        _refuse_same_log("log", logs[i + 1:], [log], "a log given already", "each day's windows "
                         "would count twice and its errors look more certain than they are")


def _inputs(*groups, effects=()) -> list[Path]:
    """The files a command reads: the paths given, and the file of each ``file.py:Name``."""
    files = [Path(item.split(":", 1)[0]) for item in _split(list(effects or []))
             if ".py" in item.split(":", 1)[0]]
    return [Path(p) for group in groups for p in group or [] if p is not None] + files


def _config_file(config: str | None) -> Path | None:
    """The calibration config file that ``--config`` names (None for the defaults)."""
    from ebus_env.config import find_config

    return None if config is None else find_config(config, kind="calibration")


def _check_outputs(outputs, inputs: list[Path]) -> None:
    """Check each ``(path, option, suffixes)`` output given (see :func:`check_output`)."""
    from ebus_env.outputs import check_output

    for path, option, suffixes in outputs:
        if path is not None:
            check_output(path, option, suffixes, inputs)


def _write(path: Path, writer) -> None:
    """Call ``writer(tmp)`` on a temporary file beside ``path``, then rename it to ``path``."""
    from ebus_env.outputs import atomic

    with atomic(path) as tmp:
        writer(tmp)


def _run(fn):
    """Run a command body, printing user errors without a traceback and input warnings
    (:class:`~ebus_env.errors.InputWarning`) as they come."""
    import warnings

    from rich.markup import escape

    from ebus_env.errors import InputWarning

    console = _console()
    original = warnings.showwarning
    shown: set = set()

    def show(message, category, *args, **kwargs):
        if issubclass(category, InputWarning):
            key = getattr(message, "key", str(message))
            if key not in shown:  # a value checked where it is read and where it is used
                shown.add(key)
                console.print(f"[yellow]warning:[/] {escape(str(message))}", highlight=False,
                              soft_wrap=True)
        else:
            original(message, category, *args, **kwargs)

    with warnings.catch_warnings():
        warnings.simplefilter("always", InputWarning)
        warnings.showwarning = show
        try:
            return fn()
        except EbusError as exc:
            console.print(f"[bold red]error:[/] {escape(str(exc))}", highlight=False,
                          soft_wrap=True)
            raise typer.Exit(2) from None


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
    columns: Annotated[str | None, typer.Option(
        help="Column map preset for --measured (configs/logs), e.g. bmw_i3_tum")] = None,
    gaps: Annotated[str, typer.Option(help="Gaps in --measured: error, split, hold, interpolate")]
    = "error",
    fill: Annotated[str, typer.Option(help="Missing values: error or interpolate")] = "error",
    no_unit_check: Annotated[bool, typer.Option(
        "--no-unit-check", help="Skip the m/s-vs-km/h and SoC-unit checks")] = False,
    start_time: StartOpt = None,
    dt_s: Annotated[float, typer.Option("--dt", help="Time step [s]")] = 0.1,
    out: Annotated[Path | None, typer.Option(help="Write the trace (.parquet or .csv)")] = None,
    plot: Annotated[Path | None, typer.Option(help="Plot speed, power, SoC, cabin (PNG)")] = None,
    json_path: Annotated[Path | None, typer.Option("--json", help="Write the summary as JSON")]
    = None,
):
    """Run a bus through a cycle day or a measured log and print the energy table."""
    _run(lambda: _simulate(
        BusChoice(bus, with_, without, overlay),
        LogHandling(columns, gaps, fill, not no_unit_check, start_time),
        cycle=cycle, measured=measured, hours=hours, mean_speed_kmh=mean_speed_kmh,
        ambient_degc=ambient_degc, soc_start_pct=soc_start_pct, load=load, set_=set_, dt_s=dt_s,
        out=out, plot=plot, json_path=json_path))


def _load_frac(load: str) -> float:
    from ebus_env.config import LOAD_CATEGORIES
    from ebus_env.errors import ConfigError
    from ebus_env.inputs import check

    if load in LOAD_CATEGORIES:
        return LOAD_CATEGORIES[load]
    try:
        value = float(load)
    except ValueError:
        raise ConfigError(f"--load: '{load}' is none of {', '.join(LOAD_CATEGORIES)} "
                          "and not a fraction.") from None
    check("load_frac", value, "--load")
    return value


def _simulate(choice: BusChoice, handling: LogHandling, *, cycle, measured, hours,
              mean_speed_kmh, ambient_degc, soc_start_pct, load, set_, dt_s, out, plot,
              json_path):
    import numpy as np

    from ebus_env.console import summary_tables, write_json
    from ebus_env.errors import ConfigError
    from ebus_env.inputs import check
    from ebus_env.outputs import JSON_SUFFIXES, PLOT_SUFFIXES, TABLE_SUFFIXES
    from ebus_env.simulate import run_profiles

    console = _console()
    if soc_start_pct is not None:
        check("soc_start_pct", soc_start_pct, "--soc-start-pct")
    if (cycle is None) == (measured is None):
        if cycle is None and measured is None:
            cycle = "sort2"
        else:
            raise ConfigError("Give either --cycle or --measured, not both.")
    day_options = {"--hours": hours, "--mean-speed-kmh": mean_speed_kmh,
                   "--ambient-degc": ambient_degc}
    given = [option for option, value in day_options.items() if value is not None]
    if measured is not None and given:
        raise ConfigError(f"{', '.join(given)} shape(s) a cycle day; a measured log keeps its "
                          "own length, speeds and ambient. Fix: drop them, or use --cycle.")
    hours = 13.5 if hours is None else hours
    bus = choice.load()
    cycle_file = Path(cycle) if cycle is not None and Path(cycle).is_file() else None
    _check_outputs([(out, "--out", TABLE_SUFFIXES), (plot, "--plot", PLOT_SUFFIXES),
                    (json_path, "--json", JSON_SUFFIXES)],
                   choice.files(bus) + _inputs([measured, cycle_file]))
    t0 = time.perf_counter()
    model = bus.build(dt_s)
    overrides = _overrides(set_)
    if load is not None:
        if "passenger_load.load_frac" in overrides:
            raise ConfigError("--load and --set passenger_load.load_frac both set the passenger "
                              "load: keep one.")
        overrides["passenger_load.load_frac"] = _load_frac(load)
    params = model.param_vector(overrides)
    record = out is not None or plot is not None or measured is not None
    compile_s = model.compile(record)
    if measured is not None:
        profiles = _load_logs([measured], model, params, handling, console)
        counted = all(np.isfinite(p.channels.get("passenger_count", [np.nan])).all()
                      for p in profiles)
        if counted and "passenger_load.load_frac" in overrides:
            console.print("[yellow]note:[/] the log counts the passengers on board, which the "
                          "model uses: the passenger load set by --load or --set "
                          "passenger_load.load_frac acts on nothing", highlight=False)
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
    if soc_start is None and "soc_frac" not in profiles[0].measured:
        console.print(f"[yellow]note:[/] the log has no SoC: the battery started at "
                      f"{summary['soc_start_pct']:.1f} %, the model's initial state; set it "
                      "with --soc-start-pct", highlight=False, soft_wrap=True)
    if "stranded_at_h" in summary:  # the BMS opened an empty pack away from a charger
        console.print(f"[yellow]warning:[/] the pack ran empty {summary['stranded_at_h']:.2f} h "
                      f"into the run, at {summary['stranded_at_km']:.2f} km: the BMS opened it "
                      f"and the bus stood {summary['stranded_h']:.2f} h, its loads off. Start "
                      "fuller (--soc-start-pct) or charge more.", highlight=False,
                      soft_wrap=True)
    summary["compile_or_load_s"] = compile_s
    title = f"{bus.name} on {run.label}"
    figures, breakdown = summary_tables(summary, title)
    console.print(figures)
    console.print(breakdown)
    console.print(f"[dim]model built and loaded in {time.perf_counter() - t0 - summary['wall_time_s']:.2f} s"
                  f" (compile/cache {compile_s:.2f} s); simulated in "
                  f"{1e3 * summary['wall_time_s']:.1f} ms[/]", highlight=False)
    if json_path:
        _write(json_path, lambda tmp: write_json(summary, tmp))
        console.print(f"summary -> {json_path}")
    if out:
        frame = run.trace_frame()
        if out.suffix.lower() == ".csv":
            _write(out, lambda tmp: frame.to_csv(tmp, index=False))
        else:
            _write(out, lambda tmp: frame.to_parquet(tmp, index=False))
        console.print(f"trace ({len(frame)} rows x {frame.shape[1]} signals) -> {out}")
    if plot:
        from ebus_env.plotting import plot_trace

        _write(plot, lambda tmp: plot_trace(run.results[0], tmp))
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
    charge: Annotated[bool, typer.Option(
        help="Fit the charge counted from the logs' battery current beside the SoC (a BMS "
             "log: it resolves the charge far below the SoC's steps)")] = False,
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
    no_unit_check: Annotated[bool, typer.Option("--no-unit-check",
                                                help="Skip the unit checks")] = False,
    start_time: StartOpt = None,
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
        from ebus_env.study.fleet_calibration import fleet_command

        # what a fleet calibration does not take: refused, not ignored
        unused = {"LOGS": logs, "--with": with_, "--without": without, "--overlay": overlay,
                  "--fix": fix, "--range": range_, "--windowed": windowed, "--charge": charge,
                  "--validate": validate, "--categorical-load": categorical_load,
                  "--config": config, "--gaps": gaps != "error", "--fill": fill != "error",
                  "--no-unit-check": no_unit_check, "--start-time": start_time,
                  "--sparse": sparse, "--json": json_path, "--plot": plot, "--history": history}

        def fleet_body():
            given = [name for name, value in unused.items() if value]
            if given:
                from ebus_env.errors import ConfigError

                raise ConfigError(f"--fleet calibrates each log of the folder with --bus, "
                                  f"--columns, --params, --seed, --population, --iterations, "
                                  f"--out, --ray and --address only; it does not take "
                                  f"{', '.join(given)}. Fix: leave "
                                  f"{'it' if len(given) == 1 else 'them'} out, or calibrate "
                                  "the logs one by one.")
            fleet_command(fleet, bus, columns, params, seed, population, iterations, use_ray,
                          address, out, _console())

        _run(fleet_body)
        return

    def body():
        if not logs:
            from ebus_env.errors import ConfigError

            raise ConfigError("Give the measured log(s) to calibrate on, or --fleet FOLDER.")
        _calibrate(
            logs, BusChoice(bus, with_, without, overlay),
            LogHandling(columns, gaps, fill, not no_unit_check, start_time), params=params, fix=fix,
            range_=range_, windowed=windowed, charge=charge, validate=validate, seed=seed,
            population=population, iterations=iterations, categorical_load=categorical_load,
            config=config, sparse=sparse,
            sparse_cycle=sparse_cycle, out=out, json_path=json_path, plot=plot, history=history)

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
        if not low < high:  # NaN fails too
            raise ConfigError(f"--range {item}: low must be below high.")
        out[name.strip()] = (low, high)
    return out


def _calibrate(logs, choice: BusChoice, handling: LogHandling, *, params, fix, range_, windowed,
               charge, validate, seed, population, iterations, categorical_load, config, sparse,
               sparse_cycle, out, json_path, plot, history):
    from dataclasses import replace

    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from ebus_env.calibration import calibrate as run_calibration
    from ebus_env.calibration.problem import require_soc
    from ebus_env.calibration.settings import load_calibration_config
    from ebus_env.console import calibration_tables, write_json
    from ebus_env.inputs import check
    from ebus_env.outputs import JSON_SUFFIXES, PLOT_SUFFIXES, YAML_SUFFIXES

    console = _console()
    for name, value in (("population", population), ("iterations", iterations)):
        if value is not None:
            check(name, value, f"--{name}")
    _refuse_twice(logs)
    _refuse_same_log("--validate", validate, logs, "a log the fit is tuned on", "a "
                     "validation log scores the fit on a day it was not tuned on")
    cfg = load_calibration_config(config)
    bus = choice.load()
    plots = [] if plot is None else [plot, plot.with_name(plot.stem + "_history" + plot.suffix),
                                     plot.with_name(plot.stem + "_determinacy" + plot.suffix)]
    _check_outputs([(out, "--out", YAML_SUFFIXES), (json_path, "--json", JSON_SUFFIXES),
                    (history, "--history", (".csv",)), *((p, "--plot", PLOT_SUFFIXES) for p in plots)],
                   choice.files(bus) + _inputs(logs, validate, [_config_file(config)]))
    model = bus.build()
    fixed = {**cfg.fixed, **_overrides(fix)}
    base = model.param_vector(fixed)
    if sparse:
        from ebus_env.io.sparse import load_sparse_log

        vmax = base[model.param_index("vehicle_body.max_speed_kmh")]
        loaded = [load_sparse_log(p, model.dt_s, cycle=sparse_cycle, columns=handling.columns,
                                  max_speed_kmh=vmax, start_h=handling.start_h)
                  for p in [*logs, *(validate or [])]]
        for path, log in zip([*logs, *(validate or [])], loaded, strict=True):
            _print_report(log.report, path, "sparse", console)
        profiles = [log.profile for log in loaded[:len(logs)]]
        check = [log.profile for log in loaded[len(logs):]]
    else:
        profiles = _load_logs(logs, model, base, handling, console)
        check = _load_logs(validate or [], model, base, handling, console)
    for profile in check:  # before the compile and the search, not after them
        require_soc(profile, "a validation log is scored on it")
    free = _split([params]) if params else cfg.params
    for name in free or ():  # an unknown name fails here, before the compile and progress bar
        model.param_index(name)
    settings = replace(cfg.isopt, seed=seed,
                       **({} if population is None else {"population": population}),
                       **({} if iterations is None else {"iterations": iterations}))
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
            validate=check or None, windowed=windowed, charge=charge,
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
        command = f"ebus simulate {choice.options()} --overlay {out}"
        _write(out, lambda tmp: result.write_overlay(tmp, command))
        console.print(f"overlay -> {out}  ({command})")
    if json_path:
        _write(json_path, lambda tmp: write_json(result.to_json(), tmp))
        console.print(f"results -> {json_path}")
    if plot:
        _write(plots[0], result.plot)
        _write(plots[1], result.plot_history)
        written = plots[:2]
        if result.determinacy:
            _write(plots[2], result.plot_determinacy)
            written = plots
        console.print(f"plots -> {', '.join(map(str, written))}")
    if history:
        import pandas as pd

        frame = pd.DataFrame({"iteration": range(len(result.history.best_cost)),
                              "evaluations": result.history.evaluations,
                              "best_cost": result.history.best_cost})
        _write(history, lambda tmp: frame.to_csv(tmp, index=False))
        console.print(f"history -> {history}")


@app.command()
def diagnose(
    logs: Annotated[list[Path], typer.Argument(help="Measured log(s) with SoC (CSV/Parquet)")],
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
    json_path: Annotated[Path | None, typer.Option("--json", help="Write the report as JSON")]
    = None,
    window_s: Annotated[float | None, typer.Option(
        help="Window length [s] (default: 300; on a log of the pack's current shorter, down "
             "to 60, so that a short trip still has 50)")] = None,
    soc_only: Annotated[bool, typer.Option(
        "--soc-only", help="Diagnose from SoC alone where the log has the pack's current "
        "too (see docs/validation.md: run both)")] = False,
    config: Annotated[str | None, typer.Option(
        help="Calibration config for --calibrate/--add (configs/calibration/NAME.yaml): its "
             "params free in place of the paper's, its ranges, fixed values and iSOPT "
             "settings")] = None,
    seed: Annotated[int, typer.Option(help="Random seed of iSOPT")] = 0,
    columns: Annotated[str | None, typer.Option(help="Column map preset, e.g. bmw_i3_tum")]
    = None,
    gaps: Annotated[str, typer.Option(help="Gaps: error, split, hold, interpolate")] = "error",
    fill: Annotated[str, typer.Option(help="Missing values: error or interpolate")] = "error",
    no_unit_check: Annotated[bool, typer.Option("--no-unit-check",
                                                help="Skip the unit checks")] = False,
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
    _run(lambda: _diagnose(
        logs, BusChoice(bus, with_, without, overlay),
        LogHandling(columns, gaps, fill, not no_unit_check, start_time), calibrate=calibrate, add=add,
        html=html, json_path=json_path, window_s=window_s, config=config, seed=seed, set_=set_,
        soc_only=soc_only, reference=reference))


def _diagnose(logs, choice: BusChoice, handling: LogHandling, *, calibrate, add, html, json_path,
              window_s, config, seed, set_, soc_only=False, reference=None):
    from dataclasses import replace

    from ebus_env.calibration.settings import load_calibration_config
    from ebus_env.diagnostics import diagnose as run_diagnosis
    from ebus_env.diagnostics.ladder import Freedom, as_effect, check_known
    from ebus_env.diagnostics.report import console_tables
    from ebus_env.errors import LogError
    from ebus_env.inputs import check
    from ebus_env.outputs import HTML_SUFFIXES, JSON_SUFFIXES

    console = _console()
    if window_s is not None:
        check("window_s", window_s, "--window-s")
    cfg = load_calibration_config(config)
    bus = choice.load()
    overrides = _overrides(set_)
    # unknown names and values out of bounds fail here (a --set value may be one of an
    # effect --add adds)
    check_known(bus, [as_effect(a) for a in _split(add)], Freedom(fixed=overrides))
    present = {n.partition(".")[0] for n in bus.build().param_names}
    params: dict = {}
    for key, value in overrides.items():
        effect_name, param = key.split(".", 1)
        if effect_name in present:  # the added effects take theirs when they are added
            params.setdefault(effect_name, {})[param] = value
    if params:  # as an overlay, so that every model the diagnosis builds has them
        bus = bus.overlay({"params": params}, "--set")
    _check_outputs([(html, "--html", HTML_SUFFIXES), (json_path, "--json", JSON_SUFFIXES)],
                   choice.files(bus) + _inputs([*logs, *(reference or [])], [_config_file(config)],
                                               effects=add))
    _refuse_twice(logs)
    _refuse_same_log("--reference", reference, logs, "the log being diagnosed", "the "
                     "reference is a normal day of the same bus, which the model is compared "
                     "against")
    model = bus.build()
    notes: list[str] = []
    profiles = _load_logs(logs, model, model.params, handling, console, notes)
    normal = _load_logs(reference, model, model.params, handling, console) \
        if reference else []
    if soc_only:
        from ebus_env.diagnostics.residual import PACK_SIGNALS

        profiles = [p.without_measured(*PACK_SIGNALS) for p in profiles]
        normal = [p.without_measured(*PACK_SIGNALS) for p in normal]
    without_soc = sorted({p.name for p in [*profiles, *normal] if "soc_frac" not in p.measured})
    if without_soc:
        raise LogError(f"diagnose compares simulated with measured SoC, and the log(s) "
                       f"{', '.join(without_soc)} have none", fix="give logs with a soc_pct "
                       "(or soc_frac) column, or map it with --columns")
    with console.status("diagnosing") as status:
        result = run_diagnosis(bus, profiles, calibrate=calibrate, add=_split(add),
                               window_s=window_s, settings=replace(cfg.isopt, seed=seed),
                               polish_starts=cfg.polish_starts, loader_notes=notes,
                               progress=lambda text: status.update(text),
                               freedom=Freedom.of(cfg, overrides), reference=normal or None)
    for table in console_tables(result):
        console.print(table)
    style = "bold green" if result.verdict else "bold"
    console.print(f"[{style}]{result.sentence}[/]", highlight=False)
    for note in (result.pack_note, result.unmet_note, result.decide_note):
        if note:
            console.print(note, highlight=False)
    if result.caution:
        console.print(f"[yellow]{result.caution}[/]", highlight=False)
    console.print(f"[dim]{result.timings['total_s']:.1f} s[/]", highlight=False)
    if html:
        _write(html, result.write_html)
        console.print(f"report -> {html}")
    if json_path:
        _write(json_path, result.write_json)
        console.print(f"results -> {json_path}")


@app.command()
def cycles():
    """List the shipped driving cycles."""

    def body():
        from rich.table import Table

        from ebus_env.cycles import CYCLES, load_cycle

        table = Table(title="driving cycles (data/cycles)")
        table.add_column("name", no_wrap=True, overflow="fold")  # a name is typed: never cut
        for col in ("duration s", "distance km", "mean km/h", "max km/h", "description"):
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
def demo(
    out: Annotated[Path, typer.Option(help="Folder for the report")] = Path("report"),
):
    """The main job on bundled data: simulate bus days and measured trips, write a report."""

    def body():
        from ebus_env.demo import BMW_DIR, run_demo
        from ebus_env.diagnostics.hidden import OUT_DIR
        from ebus_env.outputs import check_folder

        # not into the folders of the logs it reads: a report is no shipped data
        check_folder(out, "--out", inputs=[*BMW_DIR.glob("*.csv"), *OUT_DIR.glob("*.csv.gz")])
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


def _add_installed_commands() -> None:
    """Commands of other installed packages: each entry point of the group
    ``ebus_env.commands`` is a function ``register(app)`` (the top-level ``agents`` package adds
    ``train`` and ``evaluate``). ``ebus_env`` names no package above it."""
    from importlib.metadata import entry_points

    for entry in entry_points(group="ebus_env.commands"):
        try:
            entry.load()(app)
        except ImportError as exc:  # a broken plug-in must not take `ebus simulate` down
            print(f"ebus: commands of {entry.value} not loaded ({exc}).", file=sys.stderr)


_add_installed_commands()
_register_depot(app, _run)


def main():  # pragma: no cover
    sys.exit(app())


if __name__ == "__main__":  # pragma: no cover
    main()
