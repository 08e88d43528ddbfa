"""The diagnosis of BMS logs, in the power domain (see :mod:`ebus_env.diagnostics.power`).

1. The pack from the log (its capacity from the counted charge), the bus-to-bus parameters
   fitted to the logged power (:mod:`~ebus_env.diagnostics.power_fit`), twice: the second
   time with each bin weighted by the scatter of its operating mode.
2. Candidates: the library's effects the bus lacks, forms outside the library, and on several
   days each of them from a day on (:mod:`~ebus_env.diagnostics.power_candidates`).
3. Each tested against the bus-to-bus parameters alone on held-out blocks
   (:mod:`~ebus_env.diagnostics.heldout`); the decision (:func:`decide`).
4. The named effect's strength and the energy it adds, with block-bootstrap intervals; the
   missing power by operating mode; the held-out fall of the power residual.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import norm

from ebus_env.diagnostics.candidates import effect_candidates
from ebus_env.diagnostics.heldout import HeldOut, Nuisance, Test, fit_all, noise_unit, versus
from ebus_env.diagnostics.power import (
    BIN_S,
    MODES,
    TRACE,
    anchored_runs,
    log_power,
    log_voltage,
    make_bins,
)
from ebus_env.diagnostics.power_candidates import (
    Form,
    bin_signatures,
    from_day,
    outside_forms,
)
from ebus_env.diagnostics.power_fit import fit_bus, pack_values

ALPHA = 0.001
"""The chance, on a day with nothing missing, that a candidate passes the held-out test, over
all the candidates tried together (Bonferroni: each is tested at ALPHA / K)."""
Z_APART = 2.0
"""How far (paired z over held-out blocks) the first candidate must predict better than the
runner-up to be named alone; else the data cannot tell them apart."""
BOOT = 200
SEED = 0


def z_needed(tried: int) -> float:
    """The held-out z a candidate needs when ``tried`` were tested (Bonferroni)."""
    return float(norm.isf(ALPHA / max(tried, 1)))


@dataclass
class Finding:
    """What the power path concludes."""

    status: str  # named, tie, outside library, noise
    verdict: str | None
    why: str
    since_day: int
    tests: list[Test]
    forms: dict[str, Form]
    needed_z: float
    strength: dict = field(default_factory=dict)
    modes: list[dict] = field(default_factory=list)
    fall: float = float("nan")


def class_weights(residual: np.ndarray, bins, use: np.ndarray) -> np.ndarray:
    """1 / variance of each bin from the robust scatter (MAD) of the residual in its dominant
    operating mode."""
    mode = np.argmax(bins.mode_share, axis=1)
    w = np.ones(len(residual))
    floor = 50.0  # W: a bin is never trusted beyond the log's resolution
    for m in np.unique(mode):
        inside = use & (mode == m)
        if inside.sum() < 10:
            continue
        r = residual[inside]
        sigma = max(1.4826 * float(np.median(np.abs(r - np.median(r)))), floor)
        w[mode == m] = 1.0 / sigma**2
    return w


def candidate_forms(bus, profiles, bins, fit, days: int, add=(), values=None, runs=()):
    """Every form to test: the library's effects, the forms outside it, and on several days
    each from a day on. Returns (forms, set aside)."""
    signatures_of = bin_signatures(profiles, bins, fit.runs)
    user = tuple(e for e in add if not e.builtin)
    effects, aside = effect_candidates(bus, profiles[0].dt_s, values or fit.values,
                                       signatures_of, user, runs=runs)
    forms = [Form(c.name, c.kind, c.signatures_w, strengths=c.strengths,
                  strength_param=c.strength_param, effect=c.effect) for c in effects]
    forms += outside_forms(profiles, bins, fit.runs)
    if days > 1:
        forms += [from_day(f, bins, d) for f in list(forms) for d in range(1, days)]
    return forms, aside


def label(form: Form) -> str:
    return form.name if form.since_day == 0 else f"{form.name} from day {form.since_day}"


def decide(tests: dict[str, Test], forms: dict[str, Form], needed: float
           ) -> tuple[str, str | None, str]:
    """(status, the named form's label or None, why)."""
    passing = sorted((t for t in tests.values() if t.z >= needed), key=lambda t: -t.z)
    library = [t for t in passing if forms[t.name].kind != "outside"]
    outside = [t for t in passing if forms[t.name].kind == "outside"]
    if library:
        top = library[0]
        # a change from a day on is the finding only where it beats the effect on every day
        always = tests.get(forms[top.name].name)
        if forms[top.name].since_day and always is not None and versus(top, always) < Z_APART:
            top = always if always.z >= needed else top
        rivals = [t for t in library if forms[t.name].name != forms[top.name].name]
        if rivals and versus(top, rivals[0]) < Z_APART:
            return "tie", None, (
                f"{label(forms[top.name])} and {label(forms[rivals[0].name])} both explain the "
                f"missing power on held-out blocks (z {top.z:.1f} and {rivals[0].z:.1f}, "
                f"{needed:.1f} needed) and neither predicts them clearly better: the data "
                "cannot tell them apart")
        return "named", top.name, ""
    if outside:
        top = outside[0]
        return "outside library", None, (
            f"no library effect explains the missing power on held-out blocks (the best, "
            f"{_best_library(tests, forms)}); {forms[top.name].meaning.replace('a kW', 'some')} "
            f"does (z {top.z:.1f}, {needed:.1f} needed)"
            + (f", from day {forms[top.name].since_day} on" if forms[top.name].since_day else ""))
    return "noise", None, (f"no candidate predicts held-out blocks better than the bus's own "
                           f"parameters (the best, {_best(tests, forms)}; {needed:.1f} needed): "
                           "the model explains these data")


def _best(tests, forms) -> str:
    t = max(tests.values(), key=lambda t: t.z)
    return f"{label(forms[t.name])}, z {t.z:.1f}"


def _best_library(tests, forms) -> str:
    lib = [t for t in tests.values() if forms[t.name].kind != "outside"]
    return _best(dict((t.name, t) for t in lib), forms) if lib else "none tested"


def energy_kwh(test: Test, form: Form) -> float:
    """The energy a tested form adds over the logs at its fitted strength [kWh]."""
    return float(test.beta * form.signatures_w[test.choice].sum() * BIN_S / 3.6e6)


def strength_of(test: Test, form: Form, signatures: np.ndarray, y, w, nuisance, block,
                seconds: float, unit: float) -> dict:
    """The form's strength (its parameter's value at the chosen signature) and the energy it
    adds over the logs [kWh], with 90 % intervals: the strengths whose fit is within the 90 %
    level of the best (their loss within 2.71 noise units: what the shape of the data allows),
    and refits on blocks resampled with replacement (what its noise allows), together.
    ``signatures`` are the form's on the fitted units; its own cover every unit (the energy)."""
    total = form.signatures_w.sum(axis=1) * seconds / 3.6e6  # kWh per unit coefficient
    sub = signatures
    energies, values = [], []
    for k in range(len(sub)):
        _, beta, _, _, loss = fit_all(y, w, nuisance, sub[k:k + 1])
        if (loss - test.loss) / unit <= 2.71:
            energies.append(beta * total[k])
            if form.strengths is not None:
                values.append(form.strengths[k])
    rng = np.random.default_rng(SEED)
    blocks = np.unique(block)
    for _ in range(BOOT):
        pick = rng.choice(blocks, len(blocks))
        rows = np.concatenate([np.flatnonzero(block == b) for b in pick])
        part = Nuisance(nuisance.names, nuisance.x[rows], nuisance.low, nuisance.high)
        k, beta, *_ = fit_all(y[rows], w[rows], part, sub[:, rows])
        energies.append(beta * total[k])
        if form.strengths is not None:
            values.append(form.strengths[k])
    out = {"energy_kwh": float(test.beta * total[test.choice]),
           "energy_interval_kwh": [float(x) for x in np.quantile(energies, [0.05, 0.95])],
           "coefficient": test.beta}
    if form.strengths is not None and form.strength_param:
        out["parameters"] = {form.strength_param: float(form.strengths[test.choice])}
        out["interval"] = {form.strength_param:
                           [float(x) for x in np.quantile(values, [0.05, 0.95])]}
    return out


def mode_table(residual, w, bins, use) -> list[dict]:
    """The missing power in each operating mode [kW]: the weighted least-squares fit of each
    bin's missing power to its shares of time in the modes, with block-bootstrap standard
    errors."""
    share = bins.mode_share[use]
    y, ww, block = residual[use], w[use], bins.block[use]

    def fit(rows):
        a = share[rows] * np.sqrt(ww[rows])[:, None]
        seen = share[rows].sum(axis=0) > 1e-6
        coef = np.full(share.shape[1], np.nan)
        coef[seen] = np.linalg.lstsq(a[:, seen], y[rows] * np.sqrt(ww[rows]), rcond=None)[0]
        return coef

    coef = fit(np.arange(len(y)))
    rng = np.random.default_rng(SEED)
    blocks = np.unique(block)
    boot = [fit(np.concatenate([np.flatnonzero(block == b)
                                for b in rng.choice(blocks, len(blocks))])) for _ in range(BOOT)]
    se = np.nanstd(np.array(boot), axis=0)
    hours = bins.mode_share[use].sum(axis=0) * bins.seconds / 3600.0
    return [{"mode": m, "missing_kw": float(c) / 1e3, "stderr_kw": float(s) / 1e3,
             "hours": float(h), "missing_kwh": float(c) / 1e3 * float(h)}
            for m, c, s, h in zip(MODES, coef, se, hours, strict=True)]


@dataclass
class PowerRun:
    """Everything the power path built, for the report and the later stages."""

    model: object
    profiles: list
    bins: object
    fit: object
    logged_w: np.ndarray
    missing_w: np.ndarray
    weights: np.ndarray
    finding: Finding
    aside: list[dict]
    pack: dict


def diagnose_power(bus, profiles, day_of: list[int], add=(), fixed=None, say=None) -> PowerRun:
    """The power path on BMS ``profiles`` (``day_of``: each profile's day, 0 first)."""
    say = say or (lambda text: None)
    fixed = dict(fixed or {})
    model = bus.build(profiles[0].dt_s)
    pack = {k: v for k, v in pack_values(model, profiles).items() if k not in fixed}
    start = {**pack, **fixed}
    first = anchored_runs(model, profiles, model.param_vector(model.carry_over(start)), TRACE)
    bins = make_bins(profiles, [r[0] for r in first], day_of)
    logged = bins.means(log_power(profiles))
    voltage = bins.means(log_voltage(profiles))
    use = bins.fit
    say("fitting the bus to the logged power")
    fit = fit_bus(model, profiles, bins, logged, voltage, np.ones(len(bins)), start,
                  tuple(fixed))
    missing = fit.missing(logged, use)
    weights = class_weights(missing, bins, use)
    fit = fit_bus(model, profiles, bins, logged, voltage, weights, fit.values, tuple(fixed), 2)
    missing = fit.missing(logged, use, weights)
    weights = class_weights(missing, bins, use)
    say("signatures of the candidates")
    recorded = [model.simulate(p, fit.params, soc_start=None, record_every=max(
        1, int(round(1.0 / p.dt_s)))) for p in profiles]
    days = max(day_of) + 1
    forms, aside = candidate_forms(bus, profiles, bins, fit, days, add, fit.values, recorded)
    by_label = {label(f): f for f in forms}
    say(f"held-out tests of {len(forms)} candidates")
    nuisance = fit.nuisance.__class__(fit.nuisance.names, fit.nuisance.x[use],
                                      fit.nuisance.low, fit.nuisance.high)
    held = HeldOut(missing[use], weights[use], nuisance, bins.block[use])
    tests = {name: held.test(name, f.signatures_w[:, use]) for name, f in by_label.items()}
    needed = z_needed(len(tests))
    status, verdict, why = decide(tests, by_label, needed)
    finding = Finding(status, verdict, why, by_label[verdict].since_day if verdict else 0,
                      sorted(tests.values(), key=lambda t: -t.chi2), by_label, needed)
    if verdict:
        form = by_label[verdict]
        t = tests[verdict]
        finding.strength = strength_of(t, form, form.signatures_w[:, use], missing[use],
                                       weights[use], nuisance, bins.block[use], BIN_S,
                                       noise_unit(missing[use] - t.fitted, weights[use]))
        finding.fall = tests[verdict].gain
    finding.modes = mode_table(missing, weights, bins, use)
    return PowerRun(model, list(profiles), bins, fit, logged, missing, weights, finding, aside,
                    pack)


def summary(run: PowerRun) -> dict:
    """The finding in plain numbers (for quick looks and the bench)."""
    f = run.finding
    return {"status": f.status, "verdict": f.verdict, "since_day": f.since_day,
            "needed_z": f.needed_z, "why": f.why,
            "top": [(t.name, round(t.z, 2), round(t.gain, 3), round(t.chi2, 1),
                     round(energy_kwh(t, f.forms[t.name]), 2)) for t in f.tests[:5]],
            "strength": f.strength, "fall": f.fall,
            "modes": [(m["mode"], round(m["missing_kw"], 2), round(m["stderr_kw"], 2))
                      for m in f.modes if math.isfinite(m["missing_kw"])],
            "pack": run.pack}
