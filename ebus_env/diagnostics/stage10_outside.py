"""Stage 10, outside the library: a day the attribution leaves outside the library,
re-calibrated with the effect it ranks first (:func:`~ebus_env.diagnostics.refit.refit_with`).

The attribution's windows see an effect's shape with the calibrated parameters moving
back one step; where they had taken up most of it (a cabin's steady load in the
auxiliary base load), too little is left in the windows to name it. The bus
re-calibrated with the effect, every parameter free, is named where it is a verdict by
:func:`~ebus_env.diagnostics.refit.refit_ends` and its held-out error falls consistently:
by :data:`MIN_HELD_OUT_FALL` at least in :data:`~ebus_env.diagnostics.attribution.CONFIDENCE`
of the resamples of the held-out blocks (:func:`held_out_fall`). A day with nothing wrong
ends there too: one more free parameter lowers the error a little on every block, or much on
one. A strength a user holds is not re-fitted.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from ebus_env.diagnostics import attribution
from ebus_env.diagnostics.candidates import energy_curve
from ebus_env.diagnostics.ladder import Freedom, block_errors
from ebus_env.diagnostics.refit import (
    named_by_refit,
    refit_against_best,
    refit_with,
    searched_again,
)

if TYPE_CHECKING:
    from ebus_env.diagnostics.diagnosis_run import DiagnosisRun

MIN_HELD_OUT_FALL = 0.1
"""The fall of the held-out SoC RMSE that must hold in most resamples of the held-out blocks
before an effect the attribution left out is named by re-calibrating the bus with it
(:func:`run`): one more free parameter lowers the error of a day with nothing
wrong a little too, so the bar sits above what such a day gains (docs/diagnostics.md, "The
diagnosis's constants")."""


def held_out_fall(before: np.ndarray, after: np.ndarray) -> float:
    """The fall of the held-out SoC RMSE that holds in :data:`~attribution.CONFIDENCE` of
    the resamples of the held-out blocks (``before`` and ``after``: each block's sum of
    squared errors, :func:`~ebus_env.diagnostics.ladder.block_errors`; the same blocks drawn
    for both): a fall that one block makes, the others not, is no fall."""
    counts = attribution.block_draws(len(before), block=1)
    falls = 1.0 - np.sqrt(counts @ after / np.maximum(counts @ before, 1e-300))
    return float(np.quantile(falls, 1.0 - attribution.CONFIDENCE))


def run(ctx: DiagnosisRun) -> None:
    """``ctx.found`` outside the library (needs a calibration) re-calibrated with the effect
    it ranks first: that effect named ("re-calibrated"), or why not added to ``why``."""
    found, first_rung, res = ctx.found, ctx.first_rung, ctx.res
    if found.status != "outside library" or first_rung is None or not found.ranking:
        return
    c = ctx.by_name[found.ranking[0]["effect"]]
    if c.strength_param is None or c.strength_param in (ctx.freedom or Freedom()).fixed:
        return
    ctx.say(f"re-calibrating with {c.name}")
    rung = refit_with(ctx, c, first_rung.values)
    curve = energy_curve(c.strengths, c.signatures_w, res.windows)
    value, energy_kwh, not_so, base = refit_against_best(ctx, c, rung, curve)
    told = f"; re-calibrated with {c.name}, every parameter free, "
    if not_so:
        ctx.found = replace(found, why=found.why + told + not_so)
        return
    before, after = base.held_out["nrmse"], rung.held_out["nrmse"]
    held_out = ctx.blocks[1]
    fall = held_out_fall(block_errors(res.model, base.values, ctx.profiles, held_out),
                         block_errors(c.model, rung.values, ctx.profiles, held_out))
    falls = (f"the held-out NRMSE falls from {before:.3g} to {after:.3g}"
             f"{searched_again(base, first_rung, c.name)}; the fall that holds "
             f"in {100 * attribution.CONFIDENCE:.0f} % of the resamples of the held-out blocks "
             f"is {100 * fall:.0f} %")
    if fall < MIN_HELD_OUT_FALL:
        ctx.found = replace(found, why=(
            f"{found.why}{told}the bus ends at {c.strength_param} = {value:.4g}, inside the "
            f"range, and {falls}, less than {100 * MIN_HELD_OUT_FALL:.0f} % (one more free "
            "parameter lowers it on a day with nothing wrong too)"))
        return
    explained = next(x for x in found.ranked if x.name == c.name)
    why = (f"on held-out windows, with the calibrated parameters moving back one step, no "
           f"library effect explains enough of the missing power (best: {c.name}, "
           f"{100 * explained.explained:.0f} %){told}the bus ends at {c.strength_param} = "
           f"{value:.4g}, inside the range, and {falls}")
    ctx.found = named_by_refit(ctx, c, rung, value, energy_kwh, why)
