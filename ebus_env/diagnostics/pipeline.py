"""Diagnosis of a model against a measured log: where it fails, which effect is missing, what
kind of effect to write when the library lacks it, which deviations are data problems, and how
the error falls as effects are added.

:func:`diagnose` builds one run context (:class:`~ebus_env.diagnostics.diagnosis_run.DiagnosisRun`)
and passes it through the stages below, in this order; each is a module with a
``run(ctx)`` that reads what the stages before it built and writes its own part:

1. ``stage01_intake``: the inputs checked; the effects to add resolved; the logs split into
   calibration and held-out blocks.
2. ``stage02_reference``: a normal day of the same bus calibrated and measured; the bus takes
   its parameters (only with ``reference``).
3. ``stage03_calibration``: the bus's model built and, where asked, calibrated on the
   calibration blocks (rung 0).
4. ``stage04_residual``: the battery power the model misses, window by window, data problems
   and the start-up left out; the pack's resistance the logged voltage shows.
5. ``stage05_candidates``: the signatures of the effects the model lacks and of its
   parameters; which of them reproduces a change of the pack's resistance.
6. ``stage06_attribution``: which signature explains the missing power on held-out windows,
   the verdict and its strength, where the power is missing, and the clues.
7. ``stage07_bound``: a verdict withdrawn for a strength at a bound, settled by re-calibrating
   the bus with the effect.
8. ``stage08_voltage``: no verdict from the power: the effect the logged voltage names.
9. ``stage09_tie``: a tie of two effects broken by re-calibrating the bus with each.
10. ``stage10_outside``: no library effect: the bus re-calibrated with the one ranked first,
    named where the held-out error falls consistently.
11. ``stage11_ladder``: the held-out NRMSE before and after the verdict's effect, or the error
    ladder of the effects added, and the runs behind the plots.

On BMS logs (the pack's current and voltage on every row) :mod:`~ebus_env.diagnostics.power_stage`
takes the place of stages 5-10: the missing power second by second, every bus-to-bus parameter
fitted to the logged power, each candidate decided by a held-out test, and on several days of
one bus from which day an effect acts (``domain`` chooses).

:func:`~ebus_env.diagnostics.diagnosis_result.diagnosis_of` then makes the
:class:`~ebus_env.diagnostics.diagnosis_result.Diagnosis`; its ``to_json``, ``text`` and
``write_html`` give the report. Stages 7-10 need a calibration and settle, each, one way the
attribution can leave a day open (a strength at a bound, no verdict, a tie, no library effect);
the re-calibration they share is :mod:`ebus_env.diagnostics.refit`.
"""

from __future__ import annotations

from collections.abc import Sequence

from ebus_env.config import BusConfig
from ebus_env.diagnostics import (
    power_stage,
    stage01_intake,
    stage02_reference,
    stage03_calibration,
    stage04_residual,
    stage05_candidates,
    stage06_attribution,
    stage07_bound,
    stage08_voltage,
    stage09_tie,
    stage10_outside,
    stage11_ladder,
)
from ebus_env.diagnostics.diagnosis_result import Diagnosis, diagnosis_of
from ebus_env.diagnostics.diagnosis_run import DiagnosisRun
from ebus_env.diagnostics.ladder import Freedom
from ebus_env.diagnostics.normal_day import Reference


def diagnose(bus: BusConfig, profiles: Sequence, *, calibrate: bool = False,
             add: Sequence = (), window_s: float | None = None, settings=None,
             polish_starts: int | None = None, loader_notes: Sequence[str] = (),
             progress=None, freedom: Freedom | None = None,
             reference: Sequence | Reference | None = None, domain: str = "soc"
             ) -> Diagnosis:
    """Diagnose ``bus`` against measured ``profiles``, in the stages of the module docstring.

    ``calibrate`` fits the paper's parameters on the calibration blocks first (see
    :mod:`ebus_env.diagnostics.ladder`); ``add`` lists effects for the error ladder (each
    added and re-calibrated in turn). ``freedom`` changes what the calibrations fit and holds
    known values (calibrated or not). ``reference``, the profiles of a normal day of the same
    bus (or the :class:`Reference`
    :func:`~ebus_env.diagnostics.stage02_reference.reference_stage` made of them), makes the
    diagnosis relative to that day (:mod:`ebus_env.diagnostics.normal_day`; it implies
    ``calibrate``). ``progress`` is called with a line of text as each long step starts.
    ``domain``: ``"soc"`` (the default) reads the logs in SoC windows, ``"power"`` BMS logs
    second by second (:mod:`.power_stage`), ``"auto"`` the power domain where every log has
    the pack's current and voltage and no reference day is given. ``profiles`` may be
    several days of one bus, each keeping its date: in the power domain the bus's own
    parameters are fitted across them and each effect is tried from each day on too.
    ``timings`` of the result: ``reference_s`` and ``calibration_s`` from the start, the
    others each its own part.
    """
    ctx = DiagnosisRun(bus, profiles, calibrate=calibrate, add=add, window_s=window_s,
                       settings=settings, polish_starts=polish_starts,
                       loader_notes=loader_notes, progress=progress, freedom=freedom,
                       reference=reference, domain=domain)
    stage01_intake.run(ctx)
    stage02_reference.run(ctx)
    stage03_calibration.run(ctx)
    with ctx.timed("residual_s"):
        stage04_residual.run(ctx)
    if ctx.domain == "power":
        with ctx.timed("attribution_s"):
            power_stage.run(ctx)  # stages 5-10 in the power domain
    else:
        with ctx.timed("candidates_s"):
            stage05_candidates.run(ctx)
        with ctx.timed("attribution_s"):
            stage06_attribution.run(ctx)
            stage07_bound.run(ctx)  # 7-10: each settles only what the stages before left open
            stage08_voltage.run(ctx)
            stage09_tie.run(ctx)
            stage10_outside.run(ctx)
    with ctx.timed("fit_s"):
        stage11_ladder.run(ctx)
    ctx.timings["total_s"] = ctx.elapsed_s()
    return diagnosis_of(ctx)
