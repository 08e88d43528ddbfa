"""The diagnosis's result: the :class:`Diagnosis` the report shows (``to_json``, ``text``,
``write_html``), made of what the stages of :mod:`ebus_env.diagnostics.pipeline` built
(:func:`diagnosis_of`), and its one-sentence verdict.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ebus_env.diagnostics import deciding, residual
from ebus_env.diagnostics.ladder import Rung, as_effect
from ebus_env.diagnostics.power_stage import since_of
from ebus_env.units import with_unit

if TYPE_CHECKING:
    from ebus_env.diagnostics.diagnosis_run import DiagnosisRun


@dataclass
class Diagnosis:
    """Everything the report shows (``to_json`` for the machine-readable part)."""

    bus: str
    logs: list[str]
    basis: str
    window_s: float
    verdict: str | None
    sentence: str
    why: str
    to_decide: str  # what to log where the log leaves the question open, or ""
    significance: float  # of the missing power above noise, in standard deviations
    status: str  # "named", "too few windows", "noise", "outside library", "tie", "parameter",
    # "implausible", "voltage" (named from the resistance the logged voltage shows),
    # "re-calibrated" (named at the strength the bus re-calibrated with the effect ends at)
    mode_clue: str | None  # the operating mode where the power is missing
    ranking: list[dict]
    parameters: list[dict]
    selected: list[str]
    set_aside: list[dict]
    modes: list[dict]
    bins: dict[str, list[dict]]
    worst_windows: list[dict]
    clues: list[dict]
    data_issues: list[dict]
    excluded_windows: int
    nrmse: dict
    calibration: dict | None
    ladder: list[Rung]
    timings: dict
    reference: dict | None  # the normal day the missing power is relative to
    resistance: dict | None  # the pack's resistance the logged voltage shows (voltage.py)
    # arrays behind the plots
    windows: residual.Windows = field(repr=False)
    missing_w: np.ndarray = field(repr=False)
    noise_w: np.ndarray = field(repr=False)
    usable: np.ndarray = field(repr=False)
    verdict_w: np.ndarray | None = field(repr=False)  # missing power the verdict's fit predicts
    runs: list = field(repr=False)  # free-running model, each profile
    after_runs: list = field(repr=False)  # the model "after" (nrmse["after_is"])
    anchored: list = field(repr=False)  # the window-anchored runs
    after_label: str = ""
    domain: str = "soc"  # "power": BMS logs read second by second; "soc": SoC windows
    days: list[str] = field(default_factory=list)  # each day's date (or log), power domain
    since: str | None = None  # the day the verdict (or a load outside the library) acts from
    since_interval: list[str] | None = None  # the days it may have started on (90 %)
    logger_lag_s: float | None = None  # power domain: where a logged second starts [s]
    bus_fit: list[dict] | None = None  # power domain: the bus's parameters its logs give

    @property
    def range_ends(self) -> dict[str, str]:
        """The calibrated parameters the data press against an end of the range searched
        (see :meth:`~ebus_env.calibration.calibrate.CalibrationResult.pressing`)."""
        return (self.calibration or {}).get("at_range_end", {})

    @property
    def named(self) -> dict | None:
        """The verdict's row of the ranking (its estimate, interval and energy), or None."""
        return next((r for r in self.ranking if r["effect"] == self.verdict), None)

    @property
    def pack_note(self) -> str:
        """What the logged voltage says about the pack's resistance, or "" (no voltage)."""
        return self.resistance["finding"] if self.resistance else ""

    @property
    def unmet_demand_s(self) -> float:
        """Seconds in which the calibrated model's pack could not give the power the logged
        speed needs (its cell voltage floor, an empty pack): the model fell behind the log."""
        return float(sum(run.summary()["battery_limited_s"] for run in self.runs))

    @property
    def unmet_note(self) -> str:
        """The log's speed the model could not follow for want of battery power, or ""."""
        unmet = self.unmet_demand_s
        return (f"For {unmet:.0f} s the model's pack could not give the power the logged speed "
                "needs (its cell voltage floor or an empty pack): the missing power there is "
                "the model falling behind, not a missing effect." if unmet > 0.5 else "")

    @property
    def decide_note(self) -> str:
        """What would decide the question the log leaves open (:mod:`.deciding`), or ""."""
        return f"What would decide it: {self.to_decide}" if self.to_decide else ""

    @property
    def caution(self) -> str:
        """What the calibrated parameters at an end of their range mean, or ""."""
        ends = self.range_ends
        if not ends:
            return ""
        return (f"The calibration pressed {len(ends)} parameter(s) against an end of the range "
                f"searched ({', '.join(f'{n} at its {side} end' for n, side in ends.items())}): "
                "the bus lies outside those ranges (widen them with a calibration config's "
                "ranges), or they take up power the model lacks; read the missing power with "
                "that in mind.")

    def to_json(self) -> dict:
        keys = ("bus", "logs", "basis", "window_s", "verdict", "sentence", "why", "to_decide",
                "significance", "status", "mode_clue", "ranking", "parameters", "selected",
                "set_aside", "modes", "bins", "worst_windows", "clues", "data_issues",
                "excluded_windows", "nrmse", "calibration", "reference", "resistance",
                "timings", "domain", "days", "since", "since_interval", "logger_lag_s",
                "bus_fit")
        out = {k: getattr(self, k) for k in keys}
        out["ladder"] = [r.to_json() for r in self.ladder]
        out["unmet_demand_s"] = self.unmet_demand_s
        return _plain(out)

    def write_json(self, path) -> None:
        import json
        from pathlib import Path

        Path(path).write_text(json.dumps(self.to_json(), indent=2, allow_nan=False) + "\n")

    def write_html(self, path) -> None:
        from ebus_env.diagnostics.report import write_html

        write_html(self, path)

    def text(self) -> str:
        from ebus_env.diagnostics.report import text_report

        return text_report(self)


def _plain(value):
    """JSON-safe copy: numpy scalars to Python, NaN/inf to None."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def _sentence(found, effect, model, since: str | None = None, power: bool = False) -> str:
    verdict = found.verdict
    start = f"From {since} on, " if since else ""
    if found.status in ("outside library", "too few windows"):
        why = start + found.why if start else found.why[:1].upper() + found.why[1:]
        return f"{why}."  # "no library effect explains ..."
    if verdict is None:
        return f"No missing effect is supported by the data: {found.why}."
    top = next((a for a in found.ranking if a["effect"] == verdict), None)
    title = effect.title if start else effect.title[:1].upper() + effect.title[1:]
    text = start + (
        f"{title} ({verdict}): {found.why}" if found.status in ("voltage", "re-calibrated")
        or power else
        f"{title} ({verdict}) explains {100 * top['explained_fraction']:.0f} % "
        "of the missing battery power on held-out windows")

    def shown(value):
        return f"{value:.3g}" if abs(value) < 100 else f"{value:.0f}"  # not 4.91e+03

    strength = found.strength
    for name, value in strength.value.items():
        info = model.param_info(name)
        low, high = strength.interval[name]
        text += (f"; {name.split('.', 1)[1]} about {with_unit(shown(value), info.unit)} "
                 f"(90 % interval {shown(low)} to {shown(high)})")
    if strength.value:
        low, high = strength.energy_interval_kwh
        text += (f"; it adds about {strength.energy_kwh:.3g} kWh to the log's energy use "
                 f"(90 % interval {low:.3g} to {high:.3g})")
    return text + "."


def diagnosis_of(ctx: DiagnosisRun) -> Diagnosis:
    """The :class:`Diagnosis` of a run whose stages have all run."""
    res, found, fits, known = ctx.res, ctx.found, ctx.fits, ctx.known
    verdict, first_rung, normal, check = found.verdict, ctx.first_rung, ctx.normal, ctx.check
    if ctx.power is not None and ctx.power.resistance is not None:
        check = ctx.power.resistance  # with the effects the power path tried
    since, since_interval = since_of(ctx.power, ctx.days) if ctx.power else (None, None)
    step = check.step if check is not None else None
    if ctx.power is None and found.status == "voltage" and step is not None:
        since = ctx.days[step.since_day]  # the library's ageing from the day it rose
        since_interval = [ctx.days[d] for d in step.since_days]
    if ctx.power is not None:  # the power path's bus: the model the strength is a value of
        effect = as_effect(verdict) if verdict else None
        model = ctx.power.model if effect is None else ctx.bus.with_effect(
            effect).build(ctx.dt_s)
    elif verdict in ctx.by_name:
        effect, model = ctx.by_name[verdict].effect, ctx.by_name[verdict].model
    else:  # none, or named from the voltage without a candidate of the missing power
        effect = as_effect(verdict) if verdict else None
        model = ctx.model if effect is None else ctx.bus.with_effect(effect).build(ctx.dt_s)
    sentence = _sentence(found, effect, model, since, ctx.power is not None)
    return Diagnosis(
        bus=ctx.bus.name, logs=[p.name for p in ctx.profiles], basis=res.basis,
        window_s=res.window_s, verdict=verdict, sentence=sentence, why=found.why,
        to_decide=deciding.to_decide(found.status, [r["effect"] for r in found.ranking],
                                     ctx.profiles),
        significance=found.significance, status=found.status, mode_clue=found.clue,
        ranking=found.ranking, parameters=found.parameters,
        selected=found.selected, set_aside=ctx.aside, modes=found.modes, bins=found.bins,
        worst_windows=found.worst, clues=found.clues, data_issues=res.issues,
        excluded_windows=res.excluded, nrmse=fits.nrmse,
        calibration={**first_rung.calibration_result.to_json(), "fixed": known}
        if first_rung else None,
        reference=normal.to_json() if normal else None,
        resistance=check.to_json() if check else None,
        ladder=fits.ladder, timings=ctx.timings, windows=res.windows, missing_w=res.missing_w,
        noise_w=res.noise_w, usable=res.usable, verdict_w=found.verdict_w, runs=fits.runs,
        after_runs=fits.after_runs, anchored=res.anchored,
        after_label="model " + " ".join(r.label for r in fits.ladder[1:]) if ctx.add else
        f"model + {verdict}", domain=ctx.domain, days=ctx.days, since=since,
        since_interval=since_interval,
        logger_lag_s=ctx.power.logger_lag_s if ctx.power else None,
        bus_fit=ctx.power.bus_table if ctx.power else None)
