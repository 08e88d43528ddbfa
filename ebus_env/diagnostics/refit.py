"""The bus re-calibrated with a candidate's effect, and whether that names it: shared by the
stages that settle what the attribution left open (stage 7, a strength at a bound; stage 9,
a tie; stage 10, no library effect).
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from ebus_env.diagnostics.candidates import AT_BOUND
from ebus_env.diagnostics.ladder import Rung, local_rung, revisit
from ebus_env.diagnostics.stage04_residual import Residual
from ebus_env.diagnostics.stage06_attribution import Attributed, attributed_strength, ranked_with

if TYPE_CHECKING:
    from ebus_env.diagnostics.diagnosis_run import DiagnosisRun


def refit_with(ctx: DiagnosisRun, candidate, start: dict) -> Rung:
    """The bus re-calibrated with ``candidate``'s effect: a local search (no iSOPT iterations)
    from ``start``, the effect's strength scanned across its range first, every parameter the
    calibration frees (and the strength) free together, the model run in full."""
    return local_rung(candidate.bus, [candidate.effect], ctx.profiles, ctx.blocks,
                      ctx.settings, f"+ {candidate.name}", start, candidate.model, ctx.freedom)


def refit_ends(c, rung: Rung, first_rung: Rung, res: Residual,
               curve) -> tuple[float, float, str | None]:
    """Where the bus re-calibrated with candidate ``c`` (:func:`refit_with`) ends: the
    effect's strength, the energy it adds over the log there (``curve``:
    :func:`~ebus_env.diagnostics.candidates.energy_curve`), and why that is no verdict; None
    where it is one: the strength inside its range, away from both bounds (``AT_BOUND``),
    more energy than the log resolves, and a held-out NRMSE below the calibrated bus's."""
    name = c.strength_param
    value = float(rung.values[name])
    low, high = c.model.bounds[c.model.param_index(name)]
    before, after = first_rung.held_out["nrmse"], rung.held_out["nrmse"]
    energy_kwh = float(np.interp(value, *curve)) if len(curve) else float("nan")
    inside = low + AT_BOUND * (high - low) < value < high - AT_BOUND * (high - low)
    if inside and after < before and abs(energy_kwh) >= res.resolution_kwh():
        return value, energy_kwh, None
    ends = ("at a bound too" if not inside else
            f"where it adds {energy_kwh:.2g} kWh, less than the log resolves"
            if after < before else
            f"and the held-out NRMSE rises from {before:.3g} to {after:.3g}")
    return value, energy_kwh, f"the bus ends at {name} = {value:.4g}, {ends}"


def refit_against_best(ctx: DiagnosisRun, c, rung: Rung,
                       curve) -> tuple[float, float, str | None, Rung]:
    """:func:`refit_ends`, judged against the calibrated bus at its best: where the
    re-calibration with ``c`` is a verdict, the calibrated bus is searched again from where
    it ended, the effect left out (:func:`~ebus_env.diagnostics.ladder.revisit`), and judged
    against that where it fits better. A re-calibration moves every parameter, and part of
    its fall can be a better valley of the others, not the effect. Returns refit_ends's
    three and the bus it was judged against."""
    first_rung, res = ctx.first_rung, ctx.res
    value, energy_kwh, not_so = refit_ends(c, rung, first_rung, res, curve)
    if not_so is not None:
        return value, energy_kwh, not_so, first_rung
    base = revisit(first_rung, rung, ctx.profiles, ctx.blocks, ctx.settings, ctx.freedom)
    if base is first_rung:
        return value, energy_kwh, None, first_rung
    value, energy_kwh, not_so = refit_ends(c, rung, base, res, curve)
    if not_so is not None:
        not_so += searched_again(base, first_rung, c.name)
    return value, energy_kwh, not_so, base


def searched_again(base: Rung, first_rung: Rung, name: str) -> str:
    """What a reason adds where a re-calibration was judged against the calibrated bus
    searched again (:func:`refit_against_best`)."""
    if base is first_rung:
        return ""
    return (f" (against the calibrated bus searched again from where the re-calibration "
            f"ended, without {name}: it fits better there, held-out NRMSE "
            f"{first_rung.held_out['nrmse']:.3g} -> {base.held_out['nrmse']:.3g})")

def named_by_refit(ctx: DiagnosisRun, c, rung: Rung, value: float, energy_kwh: float,
                   why: str) -> Attributed:
    """``ctx.found`` with ``c``'s effect named, as the bus re-calibrated with it (``rung``)
    ends: its strength the attribution's estimate
    (:func:`~ebus_env.diagnostics.stage06_attribution.attributed_strength`) widened to take
    in the re-calibrated ``value``."""
    found = ctx.found
    strength, _ = attributed_strength(c, ctx.res, ctx.by_name, ctx.nuisance, ctx.blocks,
                                      ctx.profiles)
    strength = replace(strength, value={c.strength_param: value}, at_bound=False,
                       energy_kwh=energy_kwh).taking_in_value(value)
    explained = next(x for x in found.ranked if x.name == c.name)
    return replace(found, verdict=c.name, why=why, strength=strength,
                   verdict_w=explained.fit_w,
                   ranking=ranked_with(found.ranking, c.name, strength),
                   status="re-calibrated", refit=rung)

