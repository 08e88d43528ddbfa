"""Stage 2, reference day: a normal day of the same bus, calibrated as a suspect day is, and
what its model misses (:mod:`ebus_env.diagnostics.normal_day`); the bus takes the reference
day's parameters, and the diagnosis becomes relative to that day.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ebus_env.config import BusConfig
from ebus_env.diagnostics import attribution
from ebus_env.diagnostics.ladder import calibrate_rung, split_blocks
from ebus_env.diagnostics.normal_day import Reference, measure_reference
from ebus_env.diagnostics.stage04_residual import residual_stage
from ebus_env.errors import LogError

if TYPE_CHECKING:
    from ebus_env.diagnostics.diagnosis_run import DiagnosisRun


def run(ctx: DiagnosisRun) -> None:
    """``ctx.normal``: the reference day ``ctx.reference`` measured (given so, or calibrated
    here, timed as ``reference_s`` from the start), and ``ctx.bus`` with its overlay; nothing
    without a reference day."""
    normal = ctx.reference if isinstance(ctx.reference, Reference) else None
    if normal is None and ctx.reference:
        ctx.say("calibrating the reference day")
        normal = reference_stage(ctx.bus, list(ctx.reference), ctx.window_s, ctx.settings,
                                 ctx.polish_starts, ctx.freedom)
        ctx.timings["reference_s"] = ctx.elapsed_s()
    if normal is not None:
        ctx.bus = ctx.bus.overlay(normal.overlay(), "the reference day")
    ctx.normal = normal


def reference_stage(bus: BusConfig, profiles, window_s=None, settings=None, polish_starts=None,
                    freedom=None) -> Reference:
    """The reference day calibrated as a suspect day is, and what its model misses (see
    :mod:`ebus_env.diagnostics.normal_day`)."""
    dt_s = profiles[0].dt_s
    model = bus.build(dt_s)
    rung = calibrate_rung(bus, [], profiles, *split_blocks(profiles), dt_s, settings,
                          polish_starts, model=model, freedom=freedom)
    res = residual_stage(model, profiles, rung.values, window_s)
    if res.usable.sum() < attribution.MIN_WINDOWS:  # its per-mode gap would rest on a few
        raise LogError(f"The reference day has {int(res.usable.sum())} usable window(s) of "
                       f"{res.window_s:.0f} s: too few to say what the model misses on a normal "
                       f"day (at least {attribution.MIN_WINDOWS})",
                       path=", ".join(p.name for p in profiles),
                       fix="give a longer normal day of the same bus (several hours)")
    return measure_reference(model, profiles, rung, res)
