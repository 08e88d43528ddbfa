"""Stage 7, a strength at a bound: a verdict the attribution withdrew because its strength
ends at a bound of its parameter, settled by re-calibrating the bus with the effect.

The attribution lets the calibrated parameters move back by one step of their linear
signatures (:data:`~ebus_env.diagnostics.attribution.NUISANCE_STEPS`). Where they had
taken up much of the effect (a cabin's steady load in the auxiliary base load, its
losses in the pack's resistance), that is too little: the strength left to fit lands
at a bound. The bus re-calibrated with the effect (every parameter free together and
the model run in full; a local search from the calibrated values, the effect's strength
scanned across its range first) decides (:func:`~ebus_env.diagnostics.refit.refit_ends`):
where it is a verdict, the effect is named at that strength, its interval reaching back to
the attribution's. Otherwise the verdict stays withdrawn, and the reason says where the
re-calibration ended.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

from ebus_env.diagnostics.ladder import Freedom
from ebus_env.diagnostics.refit import refit_against_best, refit_with, searched_again
from ebus_env.diagnostics.stage06_attribution import ranked_with

if TYPE_CHECKING:
    from ebus_env.diagnostics.diagnosis_run import DiagnosisRun


def run(ctx: DiagnosisRun) -> None:
    """``ctx.found`` with a strength at a bound settled (needs a calibration; a strength a
    user knows is not re-fitted): the effect named ("re-calibrated"), or the reason it is
    not added to ``why``."""
    found, first_rung = ctx.found, ctx.first_rung
    if found.at_bound is None or first_rung is None:
        return
    c = ctx.by_name[found.at_bound]
    name = c.strength_param
    if name in (ctx.freedom or Freedom()).fixed:  # a strength a user knows is not re-fitted
        return
    ctx.say(f"re-calibrating with {c.name}")
    rung = refit_with(ctx, c, first_rung.values)
    value, energy_kwh, not_so, base = refit_against_best(ctx, c, rung,
                                                         found.strength.energy_curve)
    if not_so:
        ctx.found = replace(found, why=f"{found.why}; re-calibrated with {c.name}, every "
                                       f"parameter free, {not_so}")
        return
    bound = next(iter(found.strength.value.values()))
    strength = replace(found.strength, value={name: value}, at_bound=False,
                       energy_kwh=energy_kwh).taking_in_value(value)
    explained = next(a for a in found.ranked if a.name == c.name)
    why = (f"it explains {100 * explained.explained:.0f} % of the missing battery power on "
           f"held-out windows at a strength the attribution puts at a bound ({name} = "
           f"{bound:.4g}, the calibrated parameters moving back one step); re-calibrated with "
           f"it, every parameter free, the bus ends at {value:.4g}, inside the range, and the "
           f"held-out NRMSE falls from {base.held_out['nrmse']:.3g} to "
           f"{rung.held_out['nrmse']:.3g}{searched_again(base, first_rung, c.name)}")
    ctx.found = replace(found, verdict=c.name, why=why, strength=strength,
                        verdict_w=explained.fit_w,
                        ranking=ranked_with(found.ranking, c.name, strength),
                        status="re-calibrated", refit=rung)
