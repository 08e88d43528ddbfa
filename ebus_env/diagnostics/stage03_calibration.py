"""Stage 3, calibration: the bus's model built, and where asked (``calibrate``, an error
ladder, a reference day) its parameters fitted on the calibration blocks: rung 0 of the
error ladder (:func:`~ebus_env.diagnostics.ladder.calibrate_rung`), the bus as given.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ebus_env.diagnostics.ladder import Freedom, calibrate_rung

if TYPE_CHECKING:
    from ebus_env.diagnostics.diagnosis_run import DiagnosisRun


def run(ctx: DiagnosisRun) -> None:
    """Fill ``ctx.model``, ``ctx.first_rung`` (None uncalibrated; timed as
    ``calibration_s`` from the start), ``ctx.known`` (the values the model holds) and
    ``ctx.nuisance`` (the calibrated parameters)."""
    ctx.model = model = ctx.bus.build(ctx.dt_s)
    if ctx.normal is not None:  # the reference day's parameters held, calibrated around them
        ctx.freedom, ctx.calibrate = ctx.normal.freedom(model, ctx.freedom), True
    if ctx.calibrate or ctx.add:
        ctx.say("calibrating the model as given")
        ctx.first_rung = calibrate_rung(ctx.bus, [], ctx.profiles, *ctx.blocks, ctx.dt_s,
                                        ctx.settings, ctx.polish_starts, model=model,
                                        freedom=ctx.freedom)
        ctx.timings["calibration_s"] = ctx.elapsed_s()
    ctx.known = (ctx.freedom or Freedom()).on(model).fixed
    ctx.nuisance = tuple(ctx.first_rung.calibration_result.free) if ctx.first_rung else ()
