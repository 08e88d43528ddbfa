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
aside with the reason; so is a stateless effect whose every driver holds one value along the
log (passenger mass where the log has no passenger counts and the bus assumes a constant
load): it adds a constant to its sink, a heavier bus or a larger base load, which is a
parameter of the model, not a missing effect.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ebus_env.config import BusConfig
from ebus_env.diagnostics.attribution import NUISANCE_STEPS
from ebus_env.diagnostics.boxlsq import refit_sse
from ebus_env.diagnostics.residual import channel, window_power
from ebus_env.effects.base import Effect, registered_effects
from ebus_env.errors import EbusError
from ebus_env.signals import SLOTS

PARAM_STEP = 0.10  # of the range
VISIBLE_W = 1.0  # a signature below this everywhere changes nothing here
GRID = 9  # strength values across the range, besides the default
SAME_AS = {"mass_kg": "a heavier bus (its curb mass)", "dc_load_w": "a larger auxiliary base load",
           "road_force_n": "more rolling resistance"}
"""The parameter that adds a constant to a sink, as a user knows it."""


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
    model: object = None  # the bus's built model (effects), shared by the later stages
    params: np.ndarray | None = None  # its parameter vector with the diagnosed values

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


def shape_settings(model, eff: Effect) -> list[dict[str, float]]:
    """Each declared value of each of ``eff``'s shape parameters (one at a time, qualified
    names) other than the model's own and inside its bounds: the settings to try its
    strengths at besides the model's."""
    out = []
    for name, values in eff.shape_params.items():
        qualified = f"{eff.name}.{name}"
        i = model.param_index(qualified)
        low, high = model.bounds[i]
        out += [{qualified: v} for v in values if low <= v <= high and v != model.params[i]]
    return out


def constant_drivers(eff: Effect, runs) -> bool:
    """Whether ``eff`` has no state and each of its drivers holds one value along the recorded
    ``runs`` of the bus (a driver they do not record counts as varying)."""
    if eff.states or not eff.drivers or not runs:
        return False
    for name in eff.drivers:
        values = []
        for r in runs:
            if name in r.model.trace_names:
                values.append(r.trace(name))
            elif name in r.profile.channels:
                values.append(channel(r, name))
            else:
                return False
        v = np.concatenate(values)
        v = v[np.isfinite(v)]
        if v.size and np.ptp(v) > 0.0:
            return False
    return True


def effect_candidates(bus: BusConfig, dt_s: float, values: dict, signatures_of,
                      extra: tuple[Effect, ...] = (), progress=None, runs=()):
    """Signatures of every built-in effect the bus lacks, and of the ``extra`` ones (a
    user's); returns (candidates, set aside). ``signatures_of(model, rows)`` gives the extra
    power of parameter ``rows`` of a model with the effect, per unit of the diagnosis (a
    SoC log's windows, :func:`window_signatures`; a BMS log's bins). ``runs``: recorded runs
    of the bus along the log, to set aside a built-in effect whose drivers they hold
    constant."""
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
        found = Candidate(eff.name, kind, np.zeros((1, 0)), effect=eff, bus=changed,
                          model=model, params=params)
        name = found.strength_param
        grid = None
        if name is not None:
            i = model.param_index(name)
            grid = np.concatenate([[params[i]], np.linspace(*model.bounds[i], GRID)])
        rows, found.strengths = strength_rows(model, params, name, grid)
        found.signatures_w = signatures_of(model, rows)
        if np.max(np.abs(found.signatures_w)) < VISIBLE_W:
            aside.append({"effect": eff.name, "why": "changes nothing along this trip (are its "
                                                     "inputs in the log?)"})
            continue
        if eff.builtin and eff.sink is not None and constant_drivers(eff, runs):
            aside.append({"effect": eff.name, "why": (
                f"its inputs ({', '.join(eff.drivers)}) hold one value along this log, so it "
                f"adds a constant {eff.sink}: {SAME_AS.get(eff.sink, 'a parameter of the bus')} "
                "does the same; log them to test it")})
            continue
        candidates.append(found)
    return candidates, aside


def window_signatures(profiles, windows, basis, energy_j, base_power: np.ndarray):
    """``signatures_of`` for :func:`effect_candidates` on a SoC log's windows: each row's
    window power less the bus's."""
    def signatures_of(model, rows):
        return window_power(model, profiles, rows, windows, basis, energy_j) - base_power
    return signatures_of


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


@dataclass
class Strength:
    """The verdict's strength: value, 5-95 % bootstrap interval, whether the fit wants a value
    beyond a bound of its parameter (then the shape fits but the strength is implausible),
    and the energy the effect adds to the log's use at that strength, with its interval."""

    value: dict  # {qualified name: value}, {} for an effect without a strength parameter
    interval: dict  # {qualified name: (low, high)}
    at_bound: bool = False  # the data want a strength beyond a bound
    energy_kwh: float = float("nan")  # what the effect at that strength adds over the log
    energy_interval_kwh: tuple[float, float] = (float("nan"), float("nan"))
    # (strengths, kWh): the energy the effect adds over the log at each fitted strength
    energy_curve: tuple = field(default=(), repr=False, compare=False)

    def taking_in(self, other: Strength) -> Strength:
        """This estimate, its interval widened to take in ``other``'s, the same fit on other
        windows of the log (the held-out blocks). The bootstrap spreads only the sampling of
        windows; where two estimates from disjoint windows disagree beyond it, the effect's or
        the bus's form differs from the measured one's, and that sets the doubt."""
        def union(a, b):
            return (min(a[0], b[0]), max(a[1], b[1]))

        interval = {name: union(band, other.interval[name]) if name in other.interval else band
                    for name, band in self.interval.items()}
        return replace(self, interval=interval, energy_interval_kwh=union(
            self.energy_interval_kwh, other.energy_interval_kwh))

    def taking_in_value(self, value: float) -> Strength:
        """This estimate, its interval widened to take in ``value``, the strength the bus
        re-calibrated with the effect ends at (every parameter free together, the model
        run in full, where the attribution re-adjusts the calibrated parameters' linear
        signatures): where the two fits disagree, the doubt reaches that far."""
        if not self.value:
            return self
        (name, (low, high)), = self.interval.items()
        interval = {name: (min(low, value), max(high, value))}
        energy_low, energy_high = self.energy_interval_kwh
        if self.energy_curve:
            energy = float(np.interp(value, *self.energy_curve))
            energy_low, energy_high = min(energy_low, energy), max(energy_high, energy)
        return replace(self, interval=interval, energy_interval_kwh=(energy_low, energy_high))

    def least_energy_kwh(self) -> float:
        """The least energy, in the direction of the estimate, that the effect adds anywhere in
        its interval: min(s E_low, s E_high, |E|) with s = sign(E). Where it lies within the
        log's resolution, the data cannot tell the effect from none (an effect without a
        strength, whose energy is not estimated: infinite)."""
        if not np.isfinite(self.energy_kwh):
            return float("inf")
        sign = np.sign(self.energy_kwh)
        ends = [sign * e for e in self.energy_interval_kwh if np.isfinite(e)]
        return float(min([abs(self.energy_kwh), *ends]))


AT_BOUND = 0.02  # of the range


def _vertex(x: np.ndarray, cost: np.ndarray) -> np.ndarray:
    """Per row of ``cost`` (over the sorted grid ``x``), the minimum refined by the parabola
    through the best point and its neighbours."""
    at = np.argmin(cost, axis=1)
    j = np.clip(at, 1, len(x) - 2)
    rows = np.arange(len(cost))
    x1, x2, x3 = x[j - 1], x[j], x[j + 1]
    y1, y2, y3 = cost[rows, j - 1], cost[rows, j], cost[rows, j + 1]
    num = (x2 - x1) ** 2 * (y2 - y3) - (x2 - x3) ** 2 * (y2 - y1)
    den = (x2 - x1) * (y2 - y3) - (x2 - x3) * (y2 - y1)
    best = x[at]
    curved = (den < 0) & (at == j)  # an inner minimum, not a maximum, a line or an end
    vertex = x2 - 0.5 * num / np.where(curved, den, -1.0)
    return np.where(curved, np.clip(vertex, x1, x3), best)


def estimate_strength(candidate: Candidate, profiles, windows, basis, energy_j,
                      base_power: np.ndarray, missing_w: np.ndarray, weight: np.ndarray,
                      fit: np.ndarray, nuisance: np.ndarray | None = None,
                      draws: np.ndarray | None = None) -> Strength:
    """The value of the effect's first strength parameter at which the effect's extra power
    best matches the missing power on the ``fit`` windows (weighted least squares, the
    ``nuisance`` columns, calibrated parameters' signatures, free to re-adjust by
    ``NUISANCE_STEPS``): the best of
    the candidate's signatures, then a finer grid around it, refined by a parabola through
    the best three points. The interval repeats the fit on each bootstrap draw (``draws``:
    counts per fit window, see :func:`~ebus_env.diagnostics.attribution.block_draws`) over
    the candidate's and the fine signatures, and takes the 5 and 95 % quantiles."""
    name = candidate.strength_param
    if name is None:
        return Strength({}, {})
    sw = np.sqrt(weight[fit])
    others = np.zeros((int(fit.sum()), 0)) if nuisance is None else nuisance[fit] * sw[:, None]
    counts = np.ones((1, int(fit.sum())))

    def sse(signatures, counts=counts):
        """(draws, signatures) weighted SSE, the nuisance columns re-fitted in each draw."""
        residuals = (missing_w[fit] - np.asarray(signatures)[:, fit]) * sw
        return refit_sse(others, residuals, counts, NUISANCE_STEPS)

    strengths = np.asarray(candidate.strengths, float)
    coarse, first = np.unique(strengths, return_index=True)
    k = int(np.argmin(sse(candidate.signatures_w[first])[0]))
    low, high = coarse[max(k - 1, 0)], coarse[min(k + 1, len(coarse) - 1)]
    fine = np.linspace(low, high, GRID)
    rows, _ = strength_rows(candidate.model, candidate.params, name, fine)
    fine_sig = window_power(candidate.model, profiles, rows, windows, basis, energy_j) \
        - base_power
    cost = sse(fine_sig)
    best = float(np.clip(_vertex(fine, cost), low, high)[0])
    interval = (best, best)
    grid, order = np.unique(np.concatenate([coarse, fine]), return_index=True)
    signatures = np.vstack([candidate.signatures_w[first], fine_sig])[order]
    if draws is not None and len(draws):
        spread = _vertex(grid, sse(signatures, draws))
        interval = tuple(np.quantile(spread, [0.05, 0.95]).tolist())
        interval = (min(interval[0], best), max(interval[1], best))
    lo, hi = candidate.model.bounds[candidate.model.param_index(name)]
    return fitted_strength(name, best, interval, energy_curve(grid, signatures, windows),
                           _beyond_bound(fine, cost[0], lo, hi))


def energy_curve(strengths, signatures_w: np.ndarray, windows) -> tuple[np.ndarray, np.ndarray]:
    """(strengths, kWh): the energy an effect adds over the log at each strength of its grid,
    each signature's extra power (one per strength) times the windows' hours (every window,
    usable or not)."""
    grid, first = np.unique(np.asarray(strengths, float), return_index=True)
    return grid, signatures_w[first] @ windows.duration_h / 1e3


def fitted_strength(name: str, best: float, interval: tuple[float, float], curve,
                    at_bound: bool = False) -> Strength:
    """The strength ``best`` of parameter ``name`` with its interval, and the energy the
    effect adds over the log there and over the interval, linear between the points of
    ``curve`` (:func:`energy_curve`)."""
    grid, energy_kwh = curve
    inside = energy_kwh[(grid > interval[0]) & (grid < interval[1])]
    ends = np.interp(interval, grid, energy_kwh)
    return Strength({name: best}, {name: interval}, at_bound,
                    float(np.interp(best, grid, energy_kwh)),
                    (float(min(ends.min(), inside.min(initial=np.inf))),
                     float(max(ends.max(), inside.max(initial=-np.inf)))),
                    energy_curve=curve)


def _beyond_bound(x: np.ndarray, cost: np.ndarray, low: float, high: float) -> bool:
    """Whether the best fit wants a strength beyond the parameter's bounds: the minimum over
    the grid ``x`` lies at a bound and the parabola through the three points nearest to it
    has its vertex more than ``AT_BOUND`` of the range beyond (or no minimum at all). A true
    strength at the bound itself puts the vertex there, not beyond."""
    j, margin = int(np.argmin(cost)), AT_BOUND * (high - low)
    if j == 0 and x[0] <= low + margin:
        ends, beyond = slice(0, 3), lambda v: v < low - margin
    elif j == len(x) - 1 and x[-1] >= high - margin:
        ends, beyond = slice(-3, None), lambda v: v > high + margin
    else:
        return False
    a, b, c = np.polyfit(x[ends], cost[ends], 2)
    return bool(a <= 0 or beyond(-b / (2 * a)))
