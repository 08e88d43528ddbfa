"""Summaries for people (a table) and for programs (JSON)."""

from __future__ import annotations

import json
import math
from pathlib import Path

from ebus_env.outputs import write_text
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


def _clean(value):
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if hasattr(value, "item"):
        return _clean(value.item())
    return value


def write_json(data: dict, path: str | Path) -> None:
    """JSON with NaN/inf written as null."""
    write_text(path, json.dumps(_clean(data), indent=2) + "\n")


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
