"""Stage 8, voltage: on a log whose voltage shows the pack's resistance changing, the effect
that reproduces the change (:func:`~ebus_env.diagnostics.voltage.explain_change`, stage 5)
becomes the verdict where the missing power names none: the two signals are independent,
and the voltage sees a pack's temperature (a few per cent of the energy, spread like a load)
far more sharply than the power does. On several days, a resistance that rose from a day on
and stayed names the library's ageing from that day (a weak cell group). A verdict of the
power's stands; the report's note on the pack says what the voltage adds.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

from ebus_env.diagnostics.candidates import Strength, energy_curve, fitted_strength
from ebus_env.diagnostics.log_days import service_days
from ebus_env.diagnostics.power_path import FORM_SPREAD
from ebus_env.diagnostics.stage06_attribution import ranked_with
from ebus_env.diagnostics.voltage import AGEING, ages, step_strength

if TYPE_CHECKING:
    from ebus_env.diagnostics.diagnosis_run import DiagnosisRun


def run(ctx: DiagnosisRun) -> None:
    """``ctx.found`` named by the voltage (status "voltage") where it has no verdict and
    ``ctx.check`` shows the resistance rising from a day on (the library's ageing from that
    day) or names the effect that reproduces its change."""
    found, check = ctx.found, ctx.check
    if check is not None and check.step is not None and found.verdict is None \
            and ages(ctx.bus):
        named_from_rise(ctx)
        return
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


def named_from_rise(ctx: DiagnosisRun) -> None:
    """``ctx.found`` named the library's ageing from the day the resistance rose (on several
    days; :func:`~ebus_env.diagnostics.voltage.resistance_step`)."""
    found, step = ctx.found, ctx.check.step
    day_of, _ = service_days(ctx.profiles)
    plain = step_strength(step, ctx.check, ctx.res.model, ctx.profiles, day_of, FORM_SPREAD)
    strength = Strength(plain["parameters"],
                        {k: tuple(v) for k, v in plain["interval"].items()},
                        energy_kwh=plain["energy_kwh"],
                        energy_interval_kwh=tuple(plain["energy_interval_kwh"]))
    why = (f"the missing power alone named no effect ({found.why}); "
           + step.why(ctx.days[step.since_day]))
    ranking = found.ranking
    if not any(r["effect"] == AGEING for r in ranking):
        nan = float("nan")  # not a candidate of the missing power: the voltage's alone
        ranking = [{"effect": AGEING, "kind": "missing effect", "explained_fraction": nan,
                    "explained_band": [nan, nan], "parameters": {}, "interval": {}},
                   *ranking]
    ctx.found = replace(found, verdict=AGEING, why=why, strength=strength, verdict_w=None,
                        ranking=ranked_with(ranking, AGEING, strength), status="voltage",
                        clue=None)  # the pack, not an operating mode
