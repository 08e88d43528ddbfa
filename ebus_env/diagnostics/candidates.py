"""Candidate explanations of the missing power, and their signatures along the measured trip.

* **Missing effects**: every built-in contribution the model lacks, and every slot effect
  that refines the one in its slot (``regen_soc_limit`` for ``regen_cutoff``). Its signature
  is the battery power the model with it draws minus what the model draws, per window; shared
  parameters keep the model's values. Effects are rarely linear in their strength (a pack
  that starts warm is not a weaker cold pack), so each gets signatures at its default and at
  ``GRID`` values of its first strength parameter across its range, in one batched run. A
  user's effects named for the error ladder are candidates too.
* **Parameters** of the effects in the model: the change of battery power when a parameter
  moves by +10 % of its range (all in one batched run).

A candidate that changes nothing along this trip (its inputs are not in the log, say) is set
aside with the reason.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ebus_env.config import BusConfig
from ebus_env.diagnostics.residual import window_power
from ebus_env.effects.base import Effect, registered_effects
from ebus_env.errors import EbusError
from ebus_env.signals import SLOTS

PARAM_STEP = 0.10  # of the range
VISIBLE_W = 1.0  # a signature below this everywhere changes nothing here
GRID = 9  # strength values across the range, besides the default


@dataclass
class Candidate:
    name: str  # effect registry name, or qualified parameter name
    kind: str  # "missing effect", "refinement" or "parameter"
    signatures_w: np.ndarray  # (K, n_windows) extra battery power per window [W]
    strengths: np.ndarray | None = None  # (K,) value of the strength parameter per signature
    effect: Effect | None = None
    bus: BusConfig | None = None
    step: float = 0.0  # parameter candidates: the change of the parameter
    chosen: int = 0  # the signature that fits best (the default until attribution picks)

    @property
    def signature_w(self) -> np.ndarray:
        return self.signatures_w[self.chosen]

    @property
    def strength_param(self) -> str | None:
        if self.effect is None or not self.effect.strength_params:
            return None
        return f"{self.effect.name}.{self.effect.strength_params[0]}"


def variant(bus: BusConfig, eff: Effect) -> tuple[BusConfig, str] | None:
    """The bus with ``eff`` added, or in the slot of the effect it refines, and the kind of
    candidate; None when the bus has it or it does not refine what the bus has."""
    if eff.sink is not None:
        return None if eff.name in bus.contributions else (bus.with_effect(eff), "missing effect")
    current = bus.slots.get(eff.slot, SLOTS[eff.slot].default)
    if eff.refines is None or current != eff.refines:
        return None
    return bus.with_effect(eff), "refinement"


def model_with(bus: BusConfig, dt_s: float, values: dict):
    """Build a bus's model and its parameter vector with ``values`` carried over."""
    model = bus.build(dt_s)
    return model, model.param_vector(model.carry_over(values))


def strength_rows(model, params: np.ndarray, name: str | None, values) -> tuple[
        np.ndarray, np.ndarray | None]:
    """Parameter rows with the strength parameter ``name`` at each of ``values`` (the model's
    own row alone when there is none)."""
    if name is None:
        return params[None, :], None
    i = model.param_index(name)
    rows = np.tile(params, (len(values), 1))
    rows[:, i] = values
    return rows, np.asarray(values, float)


def effect_candidates(bus: BusConfig, dt_s: float, values: dict, profiles, windows, basis,
                      energy_j, base_power: np.ndarray, extra: tuple[Effect, ...] = (),
                      progress=None):
    """Signatures of every built-in effect the bus lacks, and of the ``extra`` ones (a
    user's); returns (candidates, set aside)."""
    candidates, aside = [], []
    pool = {e.name: e for e in registered_effects().values() if e.builtin}
    pool.update({e.name: e for e in extra})
    for eff in sorted(pool.values(), key=lambda e: e.name):
        found = variant(bus, eff)
        if found is None:
            continue
        changed, kind = found
        try:
            model, params = model_with(changed, dt_s, values)
        except EbusError as exc:
            aside.append({"effect": eff.name, "why": f"cannot be added to this bus: {exc}"})
            continue
        if progress:
            progress(eff.name)
        found = Candidate(eff.name, kind, np.zeros((1, len(windows))), effect=eff, bus=changed)
        name = found.strength_param
        grid = None
        if name is not None:
            i = model.param_index(name)
            grid = np.concatenate([[params[i]], np.linspace(*model.bounds[i], GRID)])
        rows, found.strengths = strength_rows(model, params, name, grid)
        found.signatures_w = window_power(model, profiles, rows, windows, basis, energy_j) \
            - base_power
        if np.max(np.abs(found.signatures_w)) < VISIBLE_W:
            aside.append({"effect": eff.name, "why": "changes nothing along this trip (are its "
                                                     "inputs in the log?)"})
            continue
        candidates.append(found)
    return candidates, aside


def parameter_candidates(model, params: np.ndarray, profiles, windows, basis, energy_j,
                         base_power: np.ndarray) -> list[Candidate]:
    """Signatures of +10 % of range on every parameter of the model (one batched run)."""
    rows, steps = [], []
    for i, name in enumerate(model.param_names):
        low, high = model.bounds[i]
        step = PARAM_STEP * (high - low)
        if step <= 0:
            continue
        if params[i] + step > high:
            step = -step
        row = params.copy()
        row[i] += step
        rows.append(row)
        steps.append((name, step))
    power = window_power(model, profiles, np.array(rows), windows, basis, energy_j)
    out = []
    for (name, step), p in zip(steps, power, strict=True):
        signature = (p - base_power) * np.sign(step)  # the effect of raising the parameter
        if np.max(np.abs(signature)) >= VISIBLE_W:
            out.append(Candidate(name, "parameter", signature[None, :], step=step))
    return out


def estimate_strength(candidate: Candidate, dt_s: float, values: dict, profiles, windows,
                      basis, energy_j, base_power: np.ndarray, missing_w: np.ndarray,
                      weight: np.ndarray, fit: np.ndarray,
                      nuisance: np.ndarray | None = None) -> tuple[dict, np.ndarray]:
    """The value of the effect's first strength parameter at which the effect's extra power
    best matches the missing power on the ``fit`` windows (weighted least squares, the
    ``nuisance`` columns, calibrated parameters' signatures, free to re-adjust): the best of
    the candidate's signatures, then a finer grid around it, refined by a parabola through
    the best three points. Returns ({name: value}, or {} for an effect without a strength
    parameter; the nuisance coefficients there)."""
    name = candidate.strength_param
    n_other = 0 if nuisance is None else nuisance.shape[1]
    if name is None:
        return {}, np.zeros(n_other)
    sw = np.sqrt(weight[fit])
    others = np.zeros((int(fit.sum()), 0)) if nuisance is None else nuisance[fit] * sw[:, None]

    def solve(signatures):
        out, coef = [], []
        for s in signatures:
            r = (missing_w[fit] - s[fit]) * sw
            gamma = np.linalg.lstsq(others, r, rcond=None)[0] if n_other else np.zeros(0)
            r = r - others @ gamma
            out.append(float(r @ r))
            coef.append(gamma)
        return np.array(out), coef

    def sse(signatures):
        return solve(signatures)[0]

    coarse = np.sort(np.unique(candidate.strengths))
    k = int(np.argmin(sse(candidate.signatures_w[[list(candidate.strengths).index(v)
                                                   for v in coarse]])))
    low, high = coarse[max(k - 1, 0)], coarse[min(k + 1, len(coarse) - 1)]
    model, params = model_with(candidate.bus, dt_s, values)
    fine = np.linspace(low, high, GRID)
    rows, _ = strength_rows(model, params, name, fine)
    cost, gammas = solve(window_power(model, profiles, rows, windows, basis, energy_j)
                         - base_power)
    j = int(np.argmin(cost))
    best = fine[j]
    if 0 < j < len(fine) - 1:
        a, b, c = cost[j - 1], cost[j], cost[j + 1]
        if a - 2 * b + c > 0:
            best = fine[j] + 0.5 * (a - c) / (a - 2 * b + c) * (fine[1] - fine[0])
    return {name: float(np.clip(best, low, high))}, gammas[j]
