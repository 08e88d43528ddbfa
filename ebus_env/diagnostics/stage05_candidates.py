"""Stage 5, candidates: what each registered effect the model lacks, and each parameter of the
effects it has, would add to the missing power window by window (its signature,
:mod:`ebus_env.diagnostics.candidates`); the user's effects to add are among them. On a log
whose voltage shows the pack's resistance changing, which candidate reproduces the change
(:func:`~ebus_env.diagnostics.voltage.explain_change`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from ebus_env.config import BusConfig
from ebus_env.diagnostics.candidates import (
    effect_candidates,
    parameter_candidates,
    window_signatures,
)
from ebus_env.diagnostics.ladder import as_effect
from ebus_env.diagnostics.stage04_residual import Residual
from ebus_env.diagnostics.voltage import explain_change

if TYPE_CHECKING:
    from ebus_env.diagnostics.diagnosis_run import DiagnosisRun


def run(ctx: DiagnosisRun) -> None:
    """Fill ``ctx.candidates``, ``ctx.by_name`` and ``ctx.aside`` (effects set aside, and
    why), and what explains the change of ``ctx.check``."""
    ctx.say("signatures of the candidate effects")
    res, check = ctx.res, ctx.check
    ctx.candidates, ctx.aside = candidate_stage(ctx.bus, res, ctx.profiles, ctx.add, ctx.say,
                                                ctx.held)
    ctx.by_name = {c.name: c for c in ctx.candidates}
    if check is not None and check.changes:
        check.explained_by = explain_change(check, ctx.profiles, res.anchored, res.windows,
                                            res.usable, ctx.candidates)


def candidate_stage(bus: BusConfig, res: Residual, profiles, add: Sequence, say,
                    held: dict | None = None) -> tuple[list, list[dict]]:
    """Signatures of the missing effects (the user's named for the ladder among them) and of
    the model's parameters; each effect candidate keeps its built model. ``held``: known
    values, those of an added effect among them."""
    user = tuple(e for e in map(as_effect, add) if not e.builtin)
    dt_s = profiles[0].dt_s
    values = {**res.values, **(held or {})}
    signatures_of = window_signatures(profiles, res.windows, res.basis, res.energy_j,
                                      res.base_power_w)
    candidates, aside = effect_candidates(bus, dt_s, values, signatures_of, user,
                                          progress=lambda n: say(f"  {n}"), runs=res.anchored)
    candidates += parameter_candidates(res.model, res.params, profiles, res.windows, res.basis,
                                       res.energy_j, res.base_power_w)
    return candidates, aside
