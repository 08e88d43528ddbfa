"""Run a model over one or more profiles (segments of a log split at its gaps) and combine;
:func:`simulate_bus` does the whole of ``ebus simulate``: inputs read, the day run, outputs
written."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ebus_env.bus_choice import BusChoice
from ebus_env.config import LOAD_CATEGORIES, BusConfig
from ebus_env.cycles import service_day
from ebus_env.errors import ConfigError
from ebus_env.inputs import check
from ebus_env.io.log_reading import LogReading

if TYPE_CHECKING:
    from rich.console import Console

_ADDITIVE = ("distance_km", "duration_h", "battery_energy_kwh", "consumed_energy_kwh",
             "grid_energy_kwh", "charging_time_h", "wall_time_s", "battery_shortfall_kwh",
             "battery_limited_s", "stranded_h")


@dataclass
class Run:
    """Results of consecutive segments and their combined summary."""

    results: list
    summary: dict

    @property
    def label(self) -> str:
        name = self.results[0].profile.name
        return name if len(self.results) == 1 else f"{name} ({len(self.results)} segments)"

    def trace_frame(self):
        """Traces of all segments, one after the other, with a ``segment`` column; ``time_s``
        is the log's own time (a gap between segments stays a gap)."""
        import pandas as pd

        frames = []
        for i, result in enumerate(self.results):
            frame = result.trace_frame()
            frame["time_s"] += result.profile.start_s
            frame.insert(1, "segment", i)
            frames.append(frame)
        return pd.concat(frames, ignore_index=True)


def combine(summaries: list[dict], results: list) -> dict:
    """One summary for consecutive segments (sums, extremes, first/last SoC, pooled errors)."""
    if len(summaries) == 1:
        return summaries[0]
    out = dict(summaries[0])
    for key in _ADDITIVE:
        if any(key in s for s in summaries):
            out[key] = sum(s.get(key, 0.0) for s in summaries)
    out["breakdown_kwh"] = {k: sum(s["breakdown_kwh"][k] for s in summaries)
                            for k in summaries[0]["breakdown_kwh"]}
    out["kwh_per_km"] = out["consumed_energy_kwh"] / out["distance_km"] \
        if out["distance_km"] > 0 else float("nan")
    out["soc_end_pct"] = summaries[-1]["soc_end_pct"]
    out["soc_min_pct"] = min(s["soc_min_pct"] for s in summaries)
    out["peak_grid_kw"] = max(s["peak_grid_kw"] for s in summaries)
    out["max_behind_m"] = max(s["max_behind_m"] for s in summaries)
    stranded = [i for i, s in enumerate(summaries) if "stranded_at_h" in s]
    if stranded:  # where the first segment to strand did, in the log's time and distance
        i = stranded[0]
        out["stranded_at_h"] = summaries[i]["stranded_at_h"] + results[i].profile.start_s / 3600
        out["stranded_at_km"] = summaries[i]["stranded_at_km"] + sum(
            s["distance_km"] for s in summaries[:i])
    errors = [r.soc_error_samples() for r in results]
    errors = [e for e in errors if e is not None]
    if errors:
        err = np.concatenate([e[0] for e in errors])
        span = max(e[1] for e in errors)
        out["soc_rmse_pct"] = float(np.sqrt(np.mean(err**2)))
        out["soc_nrmse"] = out["soc_rmse_pct"] / span if span > 0 else float("nan")
        out["soc_max_abs_error_pct"] = float(np.max(np.abs(err)))
        out["soc_end_error_pct"] = summaries[-1].get("soc_end_error_pct", float("nan"))
    out["segments"] = len(summaries)
    return out


def run_profiles(model, profiles, params=None, soc_start=None, record=True) -> Run:
    """Simulate each profile in turn (each from its own measured SoC unless ``soc_start``, a
    fraction 0-1)."""
    if soc_start is not None:
        check("soc_start_pct", 100.0 * soc_start, "soc_start (as percent)")
    results = [model.simulate(p, params, soc_start if i == 0 else None, record=record)
               for i, p in enumerate(profiles)]
    return Run(results, combine([r.summary() for r in results], results))


def load_frac(load: str | float) -> float:
    """A passenger load as ``passenger_load.load_frac``: one of the paper's categories
    (``driver``, ``half``, ``full``: :data:`~ebus_env.config.LOAD_CATEGORIES`) or a fraction
    0-1."""
    if isinstance(load, str) and load in LOAD_CATEGORIES:
        return LOAD_CATEGORIES[load]
    try:
        value = float(load)
    except ValueError:
        raise ConfigError(f"--load: '{load}' is none of {', '.join(LOAD_CATEGORIES)} "
                          "and not a fraction.") from None
    check("load_frac", value, "--load")
    return value


@dataclass
class Simulation:
    """What :func:`simulate_bus` ran and wrote.

    Attributes
    ----------
    bus
        The bus config that ran.
    run
        The run: its results (one per segment of a log split at its gaps) and its summary.
    setup_s
        Wall time to build and load the model and read its inputs [s].
    compile_s
        Of that, the time to compile the step loop or load it from the cache [s].
    json_path, trace_path, plot_path
        The files written (None: not asked for).
    trace_shape
        Rows and columns of the trace written.
    """

    bus: BusConfig
    run: Run
    setup_s: float
    compile_s: float
    json_path: Path | None = None
    trace_path: Path | None = None
    plot_path: Path | None = None
    trace_shape: tuple[int, int] | None = None

    @property
    def summary(self) -> dict:
        """The day's figures (see :meth:`~ebus_env.model.results.SimulationResult.summary`)."""
        return self.run.summary

    @property
    def title(self) -> str:
        return f"{self.bus.name} on {self.run.label}"


def simulate_bus(bus: str | Path | BusChoice = "12m", *, cycle: str | None = None,
                 measured: str | Path | None = None, hours: float | None = None,
                 mean_speed_kmh: float | None = None, ambient_degc: float | None = None,
                 soc_start_pct: float | None = None, load: str | float | None = None,
                 params: dict[str, float] | None = None, reading: LogReading | None = None,
                 dt_s: float = 0.1, out: str | Path | None = None, plot: str | Path | None = None,
                 json_path: str | Path | None = None,
                 console: Console | None = None) -> Simulation:
    """Run a bus through a cycle day or a measured log, and write its trace, plot and figures
    (``ebus simulate``).

    Every input is checked and every output path refused before the run when it would
    overwrite an input; each output is written through a temporary file.

    Parameters
    ----------
    bus
        Config name or path, or a :class:`~ebus_env.bus_choice.BusChoice` (effects added and
        removed, overlays merged).
    cycle
        A shipped cycle (``ebus cycles``) or a cycle CSV, run as a service day of ``hours``
        with the bus's layovers and charging (the default: ``sort2``).
    measured
        A measured log (CSV or Parquet) to replay on its own speed, ambient, grade, charging
        and passengers, compared with its SoC; instead of ``cycle``.
    hours, mean_speed_kmh, ambient_degc
        Shape the cycle day: its length [h] (13.5), the cycle scaled to a mean speed [km/h],
        the ambient [degC] (default: the bus's service).
    soc_start_pct
        Initial SoC [%] (default: a cycle day's service, a log's first measured SoC).
    load
        Passenger load: ``driver``, ``half``, ``full`` or a fraction 0-1.
    params
        Parameter values by qualified name (``{"aero_drag.drag_coef": 0.6}``).
    reading
        How the log is read (:class:`~ebus_env.io.log_reading.LogReading`).
    dt_s
        Time step [s].
    out, plot, json_path
        The 10 Hz trace (``.parquet`` or ``.csv``), a plot of speed, power, SoC and cabin
        (``.png``, ``.svg``, ``.pdf``), the figures as JSON.
    console
        A rich Console told what happens (the loader's changes, notes, warnings); None:
        nothing is said.

    Returns
    -------
    Simulation
        The run, its figures (``.summary``) and the files written.

    Examples
    --------
    >>> day = simulate_bus("12m", cycle="sort2", hours=1.0)        # doctest: +SKIP
    >>> day.summary["kwh_per_km"]                                  # doctest: +SKIP
    """
    from ebus_env.bus_choice import input_files
    from ebus_env.outputs import (
        JSON_SUFFIXES,
        PLOT_SUFFIXES,
        TABLE_SUFFIXES,
        check_outputs,
        write_json,
        write_with,
    )

    choice, reading = BusChoice.of(bus), reading or LogReading()
    out, plot, json_path = (None if p is None else Path(p) for p in (out, plot, json_path))
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
    config = choice.load()
    cycle_file = Path(cycle) if cycle is not None and Path(cycle).is_file() else None
    check_outputs([(out, "--out", TABLE_SUFFIXES), (plot, "--plot", PLOT_SUFFIXES),
                   (json_path, "--json", JSON_SUFFIXES)],
                  choice.files(config) + input_files([measured, cycle_file]))
    t0 = time.perf_counter()
    model = config.build(dt_s)
    overrides = dict(params or {})
    if load is not None:
        if "passenger_load.load_frac" in overrides:
            raise ConfigError("--load and --set passenger_load.load_frac both set the passenger "
                              "load: keep one.")
        overrides["passenger_load.load_frac"] = load_frac(load)
    vector = model.param_vector(overrides)
    record = out is not None or plot is not None or measured is not None
    compile_s = model.compile(record)
    if measured is not None:
        profiles = reading.load([measured], model, vector, console)
        counted = all(np.isfinite(p.channels.get("passenger_count", [np.nan])).all()
                      for p in profiles)
        if counted and "passenger_load.load_frac" in overrides:
            _say(console, "[yellow]note:[/] the log counts the passengers on board, which the "
                 "model uses: the passenger load set by --load or --set "
                 "passenger_load.load_frac acts on nothing")
    else:
        profiles = [service_day(cycle, hours, dt_s, config.service, mean_speed_kmh,
                                ambient_degc)]
        for line in profiles[0].notes:
            _say(console, f"[dim]cycle:[/] {line}")
    soc_start = None if soc_start_pct is None else soc_start_pct / 100.0
    if soc_start is None and measured is None:
        soc_start = config.service.soc_start_pct / 100.0
    run = run_profiles(model, profiles, vector, soc_start, record)
    summary = run.summary
    setup_s = time.perf_counter() - t0 - summary["wall_time_s"]
    if soc_start is None and "soc_frac" not in profiles[0].measured:
        _say(console, f"[yellow]note:[/] the log has no SoC: the battery started at "
             f"{summary['soc_start_pct']:.1f} %, the model's initial state; set it "
             "with --soc-start-pct", soft_wrap=True)
    if "stranded_at_h" in summary:  # the BMS opened an empty pack away from a charger
        _say(console, f"[yellow]warning:[/] the pack ran empty {summary['stranded_at_h']:.2f} h "
             f"into the run, at {summary['stranded_at_km']:.2f} km: the BMS opened it "
             f"and the bus stood {summary['stranded_h']:.2f} h, its loads off. Start "
             "fuller (--soc-start-pct) or charge more.", soft_wrap=True)
    summary["compile_or_load_s"] = compile_s
    done = Simulation(config, run, setup_s, compile_s, json_path, out, plot)
    if json_path:
        write_json(summary, json_path)
    if out:
        frame = run.trace_frame()
        write_with(out, (lambda tmp: frame.to_csv(tmp, index=False))
                   if out.suffix.lower() == ".csv" else
                   (lambda tmp: frame.to_parquet(tmp, index=False)))
        done.trace_shape = frame.shape
    if plot:
        from ebus_env.plotting import plot_trace

        write_with(plot, lambda tmp: plot_trace(run.results[0], tmp))
    return done


def _say(console: Console | None, text: str, soft_wrap: bool = False) -> None:
    if console is not None:
        console.print(text, highlight=False, soft_wrap=soft_wrap)
