"""Stage 11, the error ladder: the held-out NRMSE of the model before, and after the verdict's
effect or the effects the user adds (:func:`~ebus_env.diagnostics.ladder.error_ladder`), each
re-calibrated, and the runs behind the report's plots; the verdict's strength widened to take
in where the re-calibrated bus ends.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from ebus_env.diagnostics.ladder import Freedom, error_ladder, fit_on_blocks
from ebus_env.diagnostics.power_stage import held_out_falls as power_falls
from ebus_env.diagnostics.refit import refit_with
from ebus_env.diagnostics.stage06_attribution import Attributed, ranked_with

if TYPE_CHECKING:
    from ebus_env.diagnostics.diagnosis_run import DiagnosisRun


@dataclass
class Fits:
    """NRMSE before and after, the ladder, and the runs behind the plots."""

    nrmse: dict
    ladder: list
    runs: list
    after_runs: list
    after_values: dict = field(default_factory=dict)  # the model after: its values, re-fitted


def run(ctx: DiagnosisRun) -> None:
    """Fill ``ctx.fits``: the held-out NRMSE of the model before, and after the verdict's
    effect (or the error ladder of ``ctx.add``), each re-calibrated; with a calibration, of
    the model as configured too (``configured``: whether calibrating on the calibration
    blocks helped on the others). Then ``ctx.found``'s strength :func:`with_refit`. In the
    power domain the fall after each effect is that of the held-out missing power
    (``nrmse["power_held_out_fall"]``), and the SoC ladder of ``ctx.add`` runs only with a
    calibration."""
    profiles, blocks, res, found, first_rung = (ctx.profiles, ctx.blocks, ctx.res, ctx.found,
                                                ctx.first_rung)
    model, values, verdict = res.model, res.values, found.verdict
    before_cal, before_held = fit_on_blocks(model, values, profiles, *blocks)
    nrmse = {"before": _errors(before_cal, before_held),
             "blocks": f"{sum(map(np.sum, blocks[0].scored))} calibration and "
                       f"{sum(map(np.sum, blocks[1].scored))} held-out blocks, the SoC "
                       "restarting from the measured one at each"}
    if first_rung is not None:
        configured = (ctx.freedom or Freedom()).on(model).fixed  # what a user set is kept
        nrmse["configured"] = _errors(*fit_on_blocks(model, configured, profiles, *blocks))
    runs = [model.simulate(p, res.params, record_every=res.every) for p in profiles]
    after_model, after_values, ladder = None, {}, []
    if ctx.add and (ctx.domain == "soc" or first_rung is not None):
        ctx.say("error ladder")
        ladder = error_ladder(ctx.bus, profiles, ctx.add, ctx.dt_s, ctx.settings,
                              ctx.polish_starts, first_rung, blocks,
                              progress=lambda n: ctx.say(f"calibrating {n}"),
                              estimates={verdict: found.estimate} if verdict else None,
                              freedom=ctx.freedom)
        after_model, after_values = ladder[-1].model, ladder[-1].values
        nrmse["after_is"] = f"the last rung of the error ladder ({ladder[-1].label})"
    elif verdict in ctx.by_name and ctx.domain == "soc":  # not one named from the voltage alone
        best = ctx.by_name[verdict]
        after_model, after_values = best.model, {**values, **found.estimate}
        nrmse["after_is"] = f"+ {verdict} at its estimated strength (fitted on calibration blocks)"
        if first_rung is not None:
            # the calibrated parameters absorbed part of the effect: re-fit them with it
            # (done already where the strength was settled so, stages 7, 9 and 10)
            rung = found.refit
            if rung is None:
                ctx.say(f"re-fitting with {verdict}")
                rung = refit_with(ctx, best, after_values)
            after_values = rung.values
            nrmse["after_is"] += ", the parameters then re-fitted locally (Levenberg-Marquardt)"
    if first_rung is not None and not ladder:
        ladder = [first_rung]
    after_runs = []
    if after_model is not None:
        a_cal, a_held = fit_on_blocks(after_model, after_values, profiles, *blocks)
        nrmse["after"] = _errors(a_cal, a_held)
        after_params = after_model.param_vector(after_model.carry_over(after_values))
        after_runs = [after_model.simulate(p, after_params, record_every=res.every)
                      for p in profiles]
    if ctx.power is not None:
        nrmse["power_held_out_fall"] = power_falls(ctx.power)
    ctx.fits = Fits(nrmse, ladder, runs, after_runs, after_values)
    ctx.found = with_refit(found, after_values)


def with_refit(found: Attributed, after_values: dict) -> Attributed:
    """The verdict's strength, its intervals widened to take in the strength the bus
    re-calibrated with the effect ends at (:meth:`Strength.taking_in_value`)."""
    strength = found.strength
    name = next(iter(strength.value), None)
    if found.verdict is None or name not in after_values:
        return found
    strength = strength.taking_in_value(float(after_values[name]))
    return replace(found, strength=strength,
                   ranking=ranked_with(found.ranking, found.verdict, strength))


def _errors(cal: dict, held: dict) -> dict:
    """A model's errors on the calibration and held-out blocks (the counted charge's too, on
    a log of the pack's current)."""
    out = {"calibration": cal["nrmse"], "held_out": held["nrmse"],
           "rmse_calibration_pct": cal["rmse_pct"], "rmse_held_out_pct": held["rmse_pct"]}
    if "charge_nrmse" in held:
        out |= {"charge_calibration": cal["charge_nrmse"], "charge_held_out": held["charge_nrmse"]}
    return out
