"""``ebus calibrate`` as one function: read the logs, fit the bus with iSOPT (a progress bar on
the console), write the overlay, the results, the plots and the convergence history."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

from ebus_env.bus_choice import BusChoice, input_files, split_names
from ebus_env.calibration.calibrate import CalibrationResult, calibrate
from ebus_env.calibration.isopt import Progress
from ebus_env.calibration.problem import require_soc
from ebus_env.calibration.settings import calibration_config_file, load_calibration_config
from ebus_env.inputs import check
from ebus_env.io.log_reading import LogReading, refuse_same_log, refuse_twice, say_report
from ebus_env.outputs import (
    JSON_SUFFIXES,
    PLOT_SUFFIXES,
    YAML_SUFFIXES,
    check_outputs,
    write_json,
    write_with,
)

if TYPE_CHECKING:
    from rich.console import Console


@dataclass
class LogCalibration:
    """What :func:`calibrate_logs` fitted and wrote.

    Attributes
    ----------
    result
        The fit: values, determinacy, fit and validation figures, history.
    overlay, overlay_command
        The bus overlay written with the fitted values (None: not asked for), and the command
        that uses it.
    json_path, history
        The results as JSON and the convergence history (CSV) written (None: not asked for).
    plots
        The plots written: the fit, its history and, when the fit reports determinacy, the
        parameters' determinacy.
    """

    result: CalibrationResult
    overlay: Path | None = None
    overlay_command: str | None = None
    json_path: Path | None = None
    history: Path | None = None
    plots: list[Path] = field(default_factory=list)


def calibrate_logs(logs: Sequence[str | Path], bus: str | Path | BusChoice = "12m", *,
                   validate: Sequence[str | Path] | None = (),
                   free: str | list[str] | None = None, fixed: dict[str, float] | None = None,
                   ranges: dict[str, tuple[float, float]] | None = None, windowed: bool = False,
                   charge: bool = False, seed: int = 0, population: int | None = None,
                   iterations: int | None = None, categorical_load: bool = False,
                   config: str | Path | None = None, reading: LogReading | None = None,
                   sparse: bool = False, sparse_cycle: str = "sort2",
                   out: str | Path | None = None, json_path: str | Path | None = None,
                   plot: str | Path | None = None, history: str | Path | None = None,
                   console: Console | None = None) -> LogCalibration:
    """Fit a bus's uncertain parameters to the SoC of measured logs and write the results
    (``ebus calibrate``).

    Inputs are checked and outputs refused (one that would overwrite an input) before the
    search; each output is written through a temporary file. The fit itself is
    :func:`~ebus_env.calibration.calibrate.calibrate`.

    Parameters
    ----------
    logs
        Measured logs with SoC (CSV or Parquet) the fit is tuned on.
    bus
        Config name or path, or a :class:`~ebus_env.bus_choice.BusChoice`.
    validate
        Logs scored with the fitted values, never tuned on.
    free
        Free parameters by qualified name (a list or comma list; default: the config's, else
        the paper's seven).
    fixed
        Known values by qualified name, held (over the config's ``fixed``).
    ranges
        Prior ranges ``{name: (low, high)}`` narrowing the declared bounds.
    windowed
        Windowed (online) tuning in place of one offline search.
    charge
        Fit the charge counted from the logs' battery current beside the SoC.
    seed, population, iterations
        iSOPT's seed, population and iterations (default: the config's).
    categorical_load
        Passenger load only driver, half or full (the paper's categories).
    config
        Calibration config (``configs/calibration/NAME.yaml`` or a path).
    reading
        How the logs are read (:class:`~ebus_env.io.log_reading.LogReading`).
    sparse, sparse_cycle
        The logs are sparse (speed, distance and SoC every few minutes), their intervals
        filled with this cycle.
    out, json_path, plot, history
        The fitted values as a bus overlay (``.yaml``), the results as JSON, the plots (PNG,
        SVG, PDF; ``NAME_history`` and ``NAME_determinacy`` beside it) and the convergence
        history (``.csv``).
    console
        A rich Console told what happens (the loader's changes, a progress bar); None:
        nothing is said.

    Returns
    -------
    LogCalibration
        The fit (``.result``) and the files written.
    """
    choice, reading = BusChoice.of(bus), reading or LogReading()
    logs, validate = [Path(p) for p in logs], [Path(p) for p in validate or ()]
    out, json_path, plot, history = (None if p is None else Path(p)
                                     for p in (out, json_path, plot, history))
    for name, value in (("population", population), ("iterations", iterations)):
        if value is not None:
            check(name, value, f"--{name}")
    refuse_twice(logs)
    refuse_same_log("--validate", validate, logs, "a log the fit is tuned on", "a "
                    "validation log scores the fit on a day it was not tuned on")
    cfg = load_calibration_config(config)
    config_bus = choice.load()
    plots = [] if plot is None else [plot, plot.with_name(plot.stem + "_history" + plot.suffix),
                                     plot.with_name(plot.stem + "_determinacy" + plot.suffix)]
    check_outputs([(out, "--out", YAML_SUFFIXES), (json_path, "--json", JSON_SUFFIXES),
                   (history, "--history", (".csv",)), *((p, "--plot", PLOT_SUFFIXES)
                                                        for p in plots)],
                  choice.files(config_bus) + input_files(logs, validate,
                                                         [calibration_config_file(config)]))
    model = config_bus.build()
    fixed = {**cfg.fixed, **(fixed or {})}
    base = model.param_vector(fixed)
    if sparse:
        from ebus_env.io.sparse import load_sparse_log

        vmax = base[model.param_index("vehicle_body.max_speed_kmh")]
        loaded = [load_sparse_log(p, model.dt_s, cycle=sparse_cycle, columns=reading.columns,
                                  max_speed_kmh=vmax, start_h=reading.start_h)
                  for p in [*logs, *validate]]
        for path, log in zip([*logs, *validate], loaded, strict=True):
            say_report(log.report, path, "sparse", console)
        profiles = [log.profile for log in loaded[:len(logs)]]
        scored = [log.profile for log in loaded[len(logs):]]
    else:
        profiles = reading.load(logs, model, base, console)
        scored = reading.load(validate, model, base, console)
    for profile in scored:  # before the compile and the search, not after them
        require_soc(profile, "a validation log is scored on it")
    free = split_names([free] if isinstance(free, str) else free) if free else cfg.params
    for name in free or ():  # an unknown name fails here, before the compile and progress bar
        model.param_index(name)
    settings = replace(cfg.isopt, seed=seed,
                       **({} if population is None else {"population": population}),
                       **({} if iterations is None else {"iterations": iterations}))
    model.compile(sample=True)
    with _progress_bar(console, "windows" if windowed else "iSOPT",
                       None if windowed else settings.iterations) as progress:
        result = calibrate(
            model, profiles, free, {**cfg.ranges, **(ranges or {})}, fixed, settings,
            validate=scored or None, windowed=windowed, charge=charge,
            categorical_load=categorical_load or cfg.categorical_load, progress=progress,
            window_settings=cfg.windows, polish_starts=None if windowed else cfg.polish_starts)
    done = LogCalibration(result, json_path=json_path, history=history)
    if out:
        done.overlay, done.overlay_command = out, f"ebus simulate {choice.options()} --overlay {out}"
        write_with(out, lambda tmp: result.write_overlay(tmp, done.overlay_command))
    if json_path:
        write_json(result.to_json(), json_path)
    if plot:
        write_with(plots[0], result.plot)
        write_with(plots[1], result.plot_history)
        done.plots = plots[:2]
        if result.determinacy:
            write_with(plots[2], result.plot_determinacy)
            done.plots = plots
    if history:
        import pandas as pd

        frame = pd.DataFrame({"iteration": range(len(result.history.best_cost)),
                              "evaluations": result.history.evaluations,
                              "best_cost": result.history.best_cost})
        write_with(history, lambda tmp: frame.to_csv(tmp, index=False))
    return done


@contextlib.contextmanager
def _progress_bar(console: Console | None, title: str, total: int | None
                  ) -> Iterator[Progress | None]:
    """A progress callback ``(iteration, best cost, evaluations)`` drawing a bar on
    ``console`` (None: no bar, no callback)."""
    if console is None:
        yield None
        return
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(TextColumn("[bold]{task.description}"), BarColumn(),
                  TextColumn("{task.completed}/{task.total}"),
                  TextColumn("best cost {task.fields[best]:.5f}"),
                  TextColumn("{task.fields[evals]} evaluations"),
                  TimeElapsedColumn(), console=console, transient=False) as bar:
        task = bar.add_task(title, total=total, best=float("nan"), evals=0)

        def progress(i: int, best: float, evals: int) -> None:
            bar.update(task, completed=i, best=best, evals=evals)

        yield progress
