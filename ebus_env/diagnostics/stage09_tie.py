"""Stage 9, a tie: two effects the attribution cannot tell apart, told apart by
re-calibrating the bus with each in turn (:func:`~ebus_env.diagnostics.refit.refit_with`).

The attribution's windows see the effects' shapes, with the calibrated parameters moving
back one step; the re-calibration runs the model in full with every parameter free, so
a shape that fitted the windows only by an implausible strength, or by what the other
parameters had taken up, ends at a bound or lowers no error there. An effect is named
where it alone is a verdict by :func:`~ebus_env.diagnostics.refit.refit_ends` and the bus
re-calibrated with it also predicts the held-out blocks better than the bus re-calibrated
with the other: both conditions, since a rival can end just inside the bound margin and
fit as well, and the first alone would then name it. A strength
a user holds is not re-fitted, and such a pair stays a tie.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

from ebus_env.diagnostics.candidates import energy_curve
from ebus_env.diagnostics.ladder import Freedom
from ebus_env.diagnostics.refit import (
    named_by_refit,
    refit_against_best,
    refit_with,
    searched_again,
)

if TYPE_CHECKING:
    from ebus_env.diagnostics.diagnosis_run import DiagnosisRun


def run(ctx: DiagnosisRun) -> None:
    """``ctx.found``'s tie (needs a calibration) broken: one effect named
    ("re-calibrated"), or what each re-calibration showed added to ``why``."""
    found, first_rung, by_name = ctx.found, ctx.first_rung, ctx.by_name
    if found.status != "tie" or first_rung is None:
        return
    pair = [by_name[r["effect"]] for r in found.ranking[:2]]
    fixed = (ctx.freedom or Freedom()).fixed
    if len(pair) < 2 or any(c.strength_param is None or c.strength_param in fixed
                            for c in pair):
        return
    ends = {}  # name: (rung, strength, energy, why it is no verdict)
    for c in pair:
        ctx.say(f"re-calibrating with {c.name}")
        rung = refit_with(ctx, c, first_rung.values)
        curve = energy_curve(c.strengths, c.signatures_w, ctx.res.windows)
        ends[c.name] = (rung, *refit_against_best(ctx, c, rung, curve))
    verdicts = [name for name, end in ends.items() if end[3] is None]
    told = "; re-calibrated with each, every parameter free: "
    if len(verdicts) != 1:
        told += ("both are verdicts" if verdicts else
                 "; ".join(f"with {name} {end[3]}" for name, end in ends.items()))
        ctx.found = replace(found, why=found.why + told)
        return
    a, = verdicts
    b = next(name for name in ends if name != a)
    (rung_a, value, energy_kwh, _, base), (rung_b, _, _, not_b, _) = ends[a], ends[b]
    held_a, held_b = rung_a.held_out["nrmse"], rung_b.held_out["nrmse"]
    if held_a >= held_b:
        told += (f"only {a} is a verdict, but the bus with {b} predicts the held-out blocks "
                 f"as well (NRMSE {held_b:.3g} against {held_a:.3g})")
        ctx.found = replace(found, why=found.why + told)
        return
    why = (f"{found.why}; re-calibrated with each, every parameter free, the bus with {a} ends "
           f"at {by_name[a].strength_param} = {value:.4g}, inside the range, and predicts the "
           f"held-out blocks best (NRMSE {base.held_out['nrmse']:.3g} calibrated, "
           f"{held_a:.3g} with {a}, {held_b:.3g} with {b}"
           f"{searched_again(base, first_rung, a)}); with {b} {not_b}")
    ctx.found = named_by_refit(ctx, by_name[a], rung_a, value, energy_kwh, why)
