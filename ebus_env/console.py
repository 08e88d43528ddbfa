"""Summaries for people (tables, and what each command prints of its result) and for programs
(JSON)."""

from __future__ import annotations

import math

from ebus_env.outputs import write_json  # noqa: F401  (here too: summaries for programs)
from ebus_env.units import shown_unit

TERM_LABELS = {  # the model's own energy terms; an effect's term takes the effect's label
    "traction": "traction (motor at wheels)",
    "regen_recovered": "inertia recovered by regen",
    "inertia_net": "kinetic energy (net change)",
    "friction_brake": "friction-brake loss",
    "drivetrain_loss": "drivetrain loss",
    "battery_ohmic_loss": "battery ohmic loss",
    "coulombic_loss": "battery coulombic loss",
    "charging": "charging (DC into the bus)",
    "charger_loss": "charger loss",
}


def breakdown_label(key: str) -> str:
    """Label of an energy-breakdown term: the model's own (``TERM_LABELS``) or, for an
    effect's contribution, the effect's (:attr:`Effect.title`)."""
    from ebus_env.effects.base import registered_effects

    if key in TERM_LABELS:
        return TERM_LABELS[key]
    effects = registered_effects()
    return effects[key].title if key in effects else key

FIGURES = [
    ("distance_km", "distance", "km", 2),
    ("duration_h", "duration", "h", 2),
    ("battery_energy_kwh", "energy drawn from the battery (net)", "kWh", 2),
    ("consumed_energy_kwh", "energy used (battery + charger)", "kWh", 2),
    ("kwh_per_km", "consumption", "kWh/km", 3),
    ("soc_start_pct", "SoC start", "%", 1),
    ("soc_end_pct", "SoC end", "%", 1),
    ("soc_min_pct", "SoC minimum", "%", 1),
    ("peak_grid_kw", "peak grid power", "kW", 1),
    ("grid_energy_kwh", "grid energy", "kWh", 2),
    ("charging_time_h", "time on chargers", "h", 2),
    ("max_behind_m", "largest lag behind the reference", "m", 1),
    ("soc_rmse_pct", "SoC RMSE vs measured", "%-pts", 2),
    ("soc_nrmse", "SoC NRMSE (range-normalised)", "1", 3),
    ("soc_max_abs_error_pct", "SoC max |error|", "%-pts", 2),
    ("soc_end_error_pct", "SoC error at the end", "%-pts", 2),
    ("battery_shortfall_kwh", "power the pack could not deliver", "kWh", 3),
    ("battery_limited_s", "time the pack's limits held traction back", "s", 1),
    ("stranded_at_h", "pack empty (stranded) after", "h", 2),
    ("stranded_at_km", "... at the distance", "km", 2),
    ("wall_time_s", "simulation wall time", "s", 4),
    ("wall_time_no_trace_s", "simulation wall time, no trace recorded", "s", 4),
    ("build_s", "model build and compile (or load from the cache)", "s", 2),
]

ONLY_WHEN_SOME = {"battery_limited_s"}  # a figure that is zero on most runs, shown when not


def summary_tables(summary: dict, title: str = ""):
    """Two rich tables: the figures, and the energy breakdown by effect."""
    from rich.table import Table

    figures = Table(title=title or None, show_header=True, header_style="bold")
    figures.add_column("figure")
    figures.add_column("value", justify="right")
    figures.add_column("unit")
    for key, label, unit, digits in FIGURES:
        if key in summary and summary[key] is not None and not _nan(summary[key]) and not (
                key in ONLY_WHEN_SOME and summary[key] == 0):
            figures.add_row(label, f"{summary[key]:.{digits}f}", shown_unit(unit))
    breakdown = Table(title="energy breakdown", show_header=True, header_style="bold")
    breakdown.add_column("effect")
    breakdown.add_column("kWh", justify="right")
    breakdown.add_column("kWh/km", justify="right")
    distance = summary.get("distance_km") or float("nan")
    for key, value in summary["breakdown_kwh"].items():
        per_km = value / distance if distance and distance > 0 else float("nan")
        breakdown.add_row(breakdown_label(key), f"{value:.2f}", f"{per_km:.3f}")
    return figures, breakdown


def _nan(value) -> bool:
    return isinstance(value, float) and math.isnan(value)


FIT_ROWS = [
    ("nrmse", "NRMSE (paper eq. 1)", "1", 4),
    ("rmse_pct", "RMSE", "%-pts SoC", 3),
    ("max_abs_error_pct", "max |error|", "%-pts SoC", 3),
    ("correlation", "Pearson correlation", "1", 4),
    ("final_soc_error_pct", "final-SoC error", "%-pts SoC", 3),
    ("energy_error_pct", "energy error", "%", 2),
    ("battery_limited_s", "the log's speed unmet: the pack's limits held traction back", "s", 1),
]
CHARGE_ROWS = [  # a fit of the charge a log's current counts, beside the SoC (--charge)
    ("charge_nrmse", "NRMSE of the counted charge", "1", 4),
    ("cost", "cost: rms of the two NRMSE", "1", 4),
]


def calibration_tables(result):
    """Two rich tables: fitted parameters (how well determined), and the fit."""
    from rich.table import Table

    from ebus_env.calibration.calibrate import RANGE_END

    params = Table(title="fitted parameters", header_style="bold")
    for col in ("parameter", "value", "unit", "bounds", "determined by the data", "at an end"):
        params.add_column(col)
    ends = result.pressing()
    for name in result.free:
        low, high = result.bounds[name]
        d = result.determinacy.get(name)
        how = "" if d is None else f"{d.status}: {d.low:.4g} .. {d.high:.4g}"
        if d is not None and d.partners:
            how += f" (trades off with {', '.join(d.partners)})"
        params.add_row(name, f"{result.values[name]:.4g}", shown_unit(result.units[name]),
                       f"[{low:g}, {high:g}]", how, RANGE_END.get(ends.get(name), ""))
    fit = Table(title="fit of SoC", header_style="bold")
    fit.add_column("figure")
    fit.add_column("calibration", justify="right")
    if result.validation:
        fit.add_column("validation", justify="right")
    fit.add_column("unit")
    for key, label, unit, digits in FIT_ROWS + (CHARGE_ROWS if "cost" in result.fit else []):
        row = [label, f"{result.fit.get(key, float('nan')):.{digits}f}"]
        if result.validation:
            row.append(f"{result.validation.get(key, float('nan')):.{digits}f}")
        fit.add_row(*row, shown_unit(unit))
    return params, fit


def print_simulation(done, console) -> None:
    """What ``ebus simulate`` prints of a :class:`~ebus_env.simulate.Simulation`: the figures,
    the energy breakdown, the timings, and the files written."""
    summary = done.summary
    for table in summary_tables(summary, done.title):
        console.print(table)
    console.print(f"[dim]model built and loaded in {done.setup_s:.2f} s (compile/cache "
                  f"{done.compile_s:.2f} s); simulated in {1e3 * summary['wall_time_s']:.1f} "
                  "ms[/]", highlight=False)
    if done.json_path:
        console.print(f"summary -> {done.json_path}")
    if done.trace_path:
        rows, columns = done.trace_shape
        console.print(f"trace ({rows} rows x {columns} signals) -> {done.trace_path}")
    if done.plot_path:
        if len(done.run.results) > 1:
            console.print("[yellow]plot shows the first segment only[/]")
        console.print(f"plot -> {done.plot_path}")


def print_calibration(done, console) -> None:
    """What ``ebus calibrate`` prints of a
    :class:`~ebus_env.calibration.calibrate_logs.LogCalibration`: the fit's notes, the
    fitted parameters, the fit, and the files written."""
    result = done.result
    for line in result.notes:
        console.print(f"[yellow]note:[/] {line}", highlight=False)
    for line in result.warnings:
        console.print(f"[yellow]warning:[/] {line}", highlight=False)
    for table in calibration_tables(result):
        console.print(table)
    console.print(f"[dim]{result.method}: {result.evaluations} evaluations, "
                  f"{result.simulated_steps / 1e6:.1f} M bus-steps, {result.wall_time_s:.1f} s[/]",
                  highlight=False)
    if result.interrupted:
        console.print("[bold yellow]Interrupted: the values above are the best found so far.[/]")
    if done.overlay:
        console.print(f"overlay -> {done.overlay}  ({done.overlay_command})")
    if done.json_path:
        console.print(f"results -> {done.json_path}")
    if done.plots:
        console.print(f"plots -> {', '.join(map(str, done.plots))}")
    if done.history:
        console.print(f"history -> {done.history}")


def print_diagnosis(done, console) -> None:
    """What ``ebus diagnose`` prints of a
    :class:`~ebus_env.diagnostics.diagnose_logs.LogDiagnosis`: the report's tables, its
    sentence and notes, and the files written."""
    from ebus_env.diagnostics.report import console_tables

    result = done.result
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
    if done.html:
        console.print(f"report -> {done.html}")
    if done.json_path:
        console.print(f"results -> {done.json_path}")


def cycles_table():
    """The shipped driving cycles as a rich table (``ebus cycles``)."""
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
    return table


def print_effects(console, bus: str | None = None, with_=()) -> None:
    """The registered effects with their parameters: default (or ``bus``'s value with the
    effects ``with_`` added), unit, bounds, meaning (``ebus effects``)."""
    from rich.markup import escape

    from ebus_env.bus_choice import split_names
    from ebus_env.config import load_bus, resolve_effect
    from ebus_env.effects.base import registered_effects

    for item in split_names(with_):
        resolve_effect(item)
    values, in_model = {}, None
    if bus:
        model = load_bus(bus, with_=split_names(with_)).build()
        values = dict(zip(model.param_names, model.params, strict=True))
        in_model = {e.name for e in model.effects}
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
