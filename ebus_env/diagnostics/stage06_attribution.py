"""Stage 6, attribution: which candidate's signature explains the missing power on held-out
windows, the verdict (:func:`~ebus_env.diagnostics.attribution.attribute`), its strength with
a bootstrap interval, and where the power is missing: by operating mode and by bins, the
windows the model misses most, and what the missing power moves with
(:mod:`ebus_env.diagnostics.clues`). A verdict whose strength is implausible is withdrawn
here; stages 7-10 may settle it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ebus_env.diagnostics import attribution, clues, residual
from ebus_env.diagnostics.candidates import Strength, estimate_strength
from ebus_env.diagnostics.ladder import Rung, windows_in
from ebus_env.diagnostics.stage04_residual import Residual

if TYPE_CHECKING:
    from ebus_env.diagnostics.diagnosis_run import DiagnosisRun

WORST = 5  # the windows listed where the model misses most
CLUE_SIGMA = 3.0  # standard errors a mode's missing power must stand out by (mode_clue)


def _class_table(names, missing, noise, share, usable, hours) -> list[dict]:
    p, se = residual.decompose(missing[usable], noise[usable], share[usable])
    rows = []
    for i, name in enumerate(names):
        if hours[i] <= 0:
            continue
        rows.append({"class": name, "hours": round(float(hours[i]), 3),
                     "missing_kw": float(p[i]) / 1e3, "stderr_kw": float(se[i]) / 1e3,
                     "missing_kwh": float(p[i]) / 1e3 * float(hours[i])})
    return rows


def breakdowns(anchored, windows, missing, noise, usable) -> tuple[list[dict], dict]:
    """Missing power by operating mode and by bins of the binned signals."""
    every = anchored[0].record_every
    hours_per_row = every * anchored[0].profile.dt_s / 3600.0
    labels = [residual.operating_modes(r) for r in anchored]
    share = residual.fractions(labels, windows, every, len(residual.MODES))
    hours = np.bincount(np.concatenate(labels), minlength=len(residual.MODES)) * hours_per_row
    modes = [{"mode": r.pop("class"), **r} for r in
             _class_table(residual.MODES, missing, noise, share, usable, hours)]
    bins = {}
    signals = [residual.binned_signals(r) for r in anchored]
    for name, (edges, names) in residual.BINS.items():
        labels = [np.clip(np.digitize(s[name], edges) - 1, 0, len(names) - 1) for s in signals]
        share = residual.fractions(labels, windows, every, len(names))
        hours = np.bincount(np.concatenate(labels), minlength=len(names)) * hours_per_row
        bins[name] = _class_table(names, missing, noise, share, usable, hours)
    return modes, bins


def _worst(anchored, windows, missing, noise, usable) -> list[dict]:
    """The windows where the model misses most, relative to their noise, with context."""
    score = np.where(usable, np.abs(missing) / np.maximum(noise, 1.0), -np.inf)
    out = []
    for w in np.argsort(-score)[:WORST]:
        if not np.isfinite(score[w]):
            break
        r = anchored[windows.profile_index[w]]
        rows = windows.rows(w, r.record_every)
        mode = np.bincount(residual.operating_modes(r)[rows], minlength=len(residual.MODES))
        out.append({
            "start_h": float(windows.start_h[w]),
            "end_h": float(windows.start_h[w] + windows.duration_h[w]),
            "time_of_day_h": float(residual.channel(r, "time_of_day_h")[rows][0]),
            "missing_kw": float(missing[w]) / 1e3, "stderr_kw": float(noise[w]) / 1e3,
            "mean_speed_kmh": float(3.6 * np.mean(r.trace("speed_mps")[rows])),
            "ambient_degc": float(np.mean(residual.channel(r, "ambient_degc")[rows])),
            "soc_pct": float(100 * np.mean(r.trace("soc_frac")[rows])),
            "main_mode": residual.MODES[int(np.argmax(mode))],
        })
    return out





@dataclass
class Attributed:
    """The ranking, the verdict, its strength and the breakdowns."""

    ranked: list
    selected: list[str]
    verdict: str | None
    why: str
    significance: float
    strength: Strength  # of the verdict: value, interval, energy
    verdict_w: np.ndarray | None
    ranking: list[dict]
    parameters: list[dict]
    clues: list[dict]
    modes: list[dict]
    bins: dict
    worst: list[dict]
    status: str  # see attribution.Decision, or "implausible"
    clue: str | None  # the operating mode where the power is missing
    at_bound: str | None = None  # the effect whose strength the fit put at a bound
    refit: Rung | None = None  # the bus re-calibrated with the verdict's effect, where done

    @property
    def estimate(self) -> dict:
        return self.strength.value


def mode_clue(modes: list[dict]) -> str | None:
    """The operating mode where the most energy is missing, among those whose missing power
    stands out of its standard error by ``CLUE_SIGMA``: where an effect the library lacks
    draws its energy."""
    shown = [m for m in modes if np.isfinite(m["missing_kw"]) and np.isfinite(m["stderr_kw"])
             and m["missing_kw"] > CLUE_SIGMA * m["stderr_kw"]]
    if not shown:
        return None
    return max(shown, key=lambda m: m["missing_kwh"])["mode"]


def attributed_strength(best, res: Residual, by_name: dict, nuisance: tuple[str, ...],
                        blocks, profiles) -> tuple[Strength, Strength]:
    """A candidate's strength with its bootstrap interval, the calibrated parameters moving
    back along their linear signatures: fitted on the calibration blocks' windows and widened
    to take in the same fit on the held-out blocks' (the first), and on the calibration
    blocks' alone (the second: what the energy floor is judged on)."""
    w = res.windows
    weight = attribution.weights(res.noise_w)
    moving = [by_name[n].signature_w for n in nuisance if n in by_name]
    nuisance_w = np.column_stack(moving) if moving else None

    def strength_on(windows):
        return estimate_strength(best, profiles, w, res.basis, res.energy_j, res.base_power_w,
                                 res.missing_w, weight, windows, nuisance_w,
                                 attribution.block_draws(int(windows.sum())))

    in_cal = windows_in(blocks[0], w)
    strength = own = strength_on(res.usable & in_cal)
    held = res.usable & ~in_cal
    if held.sum() >= attribution.MIN_WINDOWS:  # enough to check the estimate on
        strength = strength.taking_in(strength_on(held))
    return strength, own


def attribution_stage(res: Residual, candidates, nuisance: tuple[str, ...], blocks,
                      profiles) -> Attributed:
    """Which candidate explains the missing power, the verdict and its strength with a
    bootstrap interval (fitted on the calibration blocks' windows, widened to take in the same
    fit on the held-out blocks'), and where the power is missing. A verdict whose strength sits
    at a bound of its parameter is withdrawn: the shape fits, the strength is implausible."""
    w = res.windows
    at_bound = None
    decision = attribution.attribute(res.missing_w, res.noise_w, candidates, res.usable,
                                     nuisance=nuisance, measurement_w=res.measurement_w)
    ranked, verdict, why, status = (decision.ranking, decision.verdict, decision.why,
                                    decision.status)
    by_name = {c.name: c for c in candidates}
    weight = attribution.weights(res.noise_w)
    strength, verdict_w = Strength({}, {}), None
    # where the power is missing: beyond a normal day's gap, with a reference (the attribution
    # stays on the missing power itself: taking the gap off there named fewer effects right)
    modes, bins = breakdowns(res.anchored, w, *res.beyond_normal(), res.usable)
    if verdict is not None:
        best = by_name[verdict]
        strength, own = attributed_strength(best, res, by_name, nuisance, blocks, profiles)
        if strength.at_bound:
            (name, value), = strength.value.items()
            low, high = best.model.bounds[best.model.param_index(name)]
            # the effect's size at the bound tells a user how far its form (its other
            # parameters) is from the bus's: a cabin whose fans alone outdraw the data
            side = "lower" if value - low < high - value else "upper"
            why = (f"the shape of {verdict} fits, the strength is implausible: {name} ends at "
                   f"its {side} bound, {value:.4g} (range {low:.4g} to {high:.4g}), where it adds "
                   f"{strength.energy_kwh:.3g} kWh over the log (its other parameters, or its "
                   "form, differ from this bus's)")
            status, verdict, at_bound = "implausible", None, verdict
        elif own.least_energy_kwh() < (floor_kwh := res.resolution_kwh()):
            # the fit's strength, or one inside its interval on the windows it was fitted on,
            # adds less energy than the log can show at all: the shape matched noise, not an
            # effect (a regen limit above the SoC the day reaches). The held-out blocks' fit
            # widens the doubt on the size, not on whether there is an effect: fewer windows
            # resolve less, and a load that comes and goes may not be in them.
            low, high = own.energy_interval_kwh
            within = (f"at the strength that fits it adds {own.energy_kwh:.2g} kWh"
                      if abs(own.energy_kwh) < floor_kwh else
                      f"within its 90 % interval it adds as little as "
                      f"{np.sign(own.energy_kwh) * own.least_energy_kwh():.2g} kWh "
                      f"({low:.2g} to {high:.2g} kWh)")
            why = (f"the shape of {verdict} fits, the strength is implausible: {within} over "
                   f"the log, less than the log resolves ({floor_kwh:.2g} kWh, the standard "
                   "error of the energy it measures)")
            status, verdict = "implausible", None
        else:
            # like with like: the missing power the fit predicts, the calibrated parameters
            # moving back included (they absorbed part of the effect)
            verdict_w = next(a.fit_w for a in ranked if a.name == verdict)
    clue = mode_clue(modes)
    if status == "outside library" and clue:
        why += f"; the power is missing mostly while {clue}" + (
            " (beyond what the reference day misses)" if res.normal_w is not None else "")
    ranking = [{"effect": a.name, "kind": a.kind, "explained_fraction": a.explained,
                "explained_band": list(a.band),
                "parameters": strength.value if a.name == verdict else {},
                "interval": strength.interval if a.name == verdict else {},
                **({"energy_kwh": strength.energy_kwh,
                    "energy_interval_kwh": list(strength.energy_interval_kwh)}
                   if a.name == verdict and strength.value else {})}
               for a in ranked if a.kind != "parameter"]
    parameters = []
    for a in [a for a in ranked if a.kind == "parameter"][:10]:
        i = res.model.param_index(a.name)
        value = res.params[i] + a.scale * by_name[a.name].step
        low, high = res.model.bounds[i]
        parameters.append({"parameter": a.name, "explained_fraction": a.explained,
                           "change_for_fit": a.scale * by_name[a.name].step,
                           "value_for_fit": value, "within_bounds": bool(low <= value <= high)})
    found = clues.correlations(clues.window_features(res.anchored, w), res.missing_w, weight,
                               res.usable)
    worst = _worst(res.anchored, w, res.missing_w, res.noise_w, res.usable)
    return Attributed(ranked, decision.selected, verdict, why, decision.significance,
                      strength, verdict_w, ranking, parameters, found, modes, bins, worst,
                      status, clue, at_bound)



def ranked_with(ranking: list[dict], verdict: str, strength: Strength) -> list[dict]:
    """The ranking with the verdict's row carrying ``strength``: its value, interval and
    energy."""
    return [{**r, "parameters": strength.value, "interval": strength.interval,
             "energy_kwh": strength.energy_kwh,
             "energy_interval_kwh": list(strength.energy_interval_kwh)}
            if r["effect"] == verdict else r for r in ranking]



def run(ctx: DiagnosisRun) -> None:
    """Fill ``ctx.found``: the attribution of ``ctx.res`` among ``ctx.candidates``."""
    ctx.found = attribution_stage(ctx.res, ctx.candidates, ctx.nuisance, ctx.blocks,
                                  ctx.profiles)
