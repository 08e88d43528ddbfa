"""Stage 8, voltage: on a log whose voltage shows the pack's resistance changing, the effect
that reproduces the change (:func:`~ebus_env.diagnostics.voltage.explain_change`, stage 5)
becomes the verdict where the missing power names none: the two signals are independent,
and the voltage sees a pack's temperature (a few per cent of the energy, spread like a load)
far more sharply than the power does. A verdict of the power's stands; the report's note on
the pack says what the voltage adds.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

from ebus_env.diagnostics.candidates import energy_curve, fitted_strength
from ebus_env.diagnostics.stage06_attribution import ranked_with

if TYPE_CHECKING:
    from ebus_env.diagnostics.diagnosis_run import DiagnosisRun


def run(ctx: DiagnosisRun) -> None:
    """``ctx.found`` named by the voltage (status "voltage") where it has no verdict and
    ``ctx.check`` names the effect that reproduces the resistance's change."""
    found, check = ctx.found, ctx.check
    best = check.best if check is not None else None
    if best is None or found.verdict is not None:
        return
    c = ctx.by_name[best.effect]
    strength = fitted_strength(best.parameter, best.value, best.interval,
                               energy_curve(c.strengths, c.signatures_w, ctx.res.windows))
    why = (f"the missing power alone named no effect ({found.why}); the logged voltage shows "
           f"the pack's resistance changing over the log, and {best.effect} reproduces "
           f"{100 * best.explained:.0f} % of the change")
    ctx.found = replace(found, verdict=best.effect, why=why, strength=strength,
                        verdict_w=c.signatures_w[best.index],
                        ranking=ranked_with(found.ranking, best.effect, strength),
                        status="voltage")
