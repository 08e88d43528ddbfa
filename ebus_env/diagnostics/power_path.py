"""The diagnosis in the power domain: BMS logs second by second (see
:mod:`ebus_env.diagnostics.power`), SoC-only logs by the charge their SoC counts in each window
(:mod:`ebus_env.diagnostics.soc_power`).

1. The pack from the log (its capacity from the counted charge), the bus-to-bus parameters
   and the sensor's terms fitted to the logged power (:mod:`~ebus_env.diagnostics.power_fit`),
   twice: the second time with each bin weighted by the scatter of its operating mode.
2. Candidates: the library's effects the bus lacks, forms outside the library, and on several
   days each of them from a day on (:mod:`~ebus_env.diagnostics.power_candidates`).
3. Each tested against the bus-to-bus parameters alone on held-out blocks
   (:mod:`~ebus_env.diagnostics.heldout`): the held-out loss it removes, in noise units
   (``chi2``), and the decision (:func:`decide`). A load or force outside the library is
   reported from :data:`MIN_OUTSIDE_KW` on, and from a day on only where the days split
   there (:func:`separated`).
4. The named effect's strength and the energy it adds, with intervals (a strength the data
   put beyond an end of its parameter's range withdraws the name: :func:`bound_reached`,
   :data:`BEYOND_SURE`); from which day it acts
   on several days; the missing power by operating mode; what the logged voltage says of the
   pack's resistance (a cold pack shows there, not in the power).

The decision's constants are set on the control days of one truth source and checked on the
others (docs/validation.md says which, and how to measure them again).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2 as chi2_dist

from ebus_env.calibration.problem import CHARGER_SHARE
from ebus_env.diagnostics.candidates import effect_candidates, strength_rows
from ebus_env.diagnostics.heldout import HeldOut, Nuisance, Test, fit_all, margin, noise_unit
from ebus_env.diagnostics.power import (
    BIN_S,
    MODES,
    TRACE,
    anchored_runs,
    log_power,
    log_voltage,
    logger_lag,
    logs_power,
    make_bins,
)
from ebus_env.diagnostics.power_candidates import (
    Form,
    bin_signatures,
    from_day,
    outside_forms,
)
from ebus_env.diagnostics.power_fit import (
    fit_bus,
    pack_resistance,
    pack_values,
    resistance_check_at,
)
from ebus_env.diagnostics.soc_power import WINDOW_S, as_power_logs
from ebus_env.diagnostics.voltage import (
    AGEING,
    MIN_CHANGE,
    ages,
    day_step,
    explain_change,
    predicted_ln_ratios,
    step_strength,
)

ALPHA = 0.01
"""The chance, on a day with nothing missing, that some candidate passes, over all the
candidates tried together (Bonferroni: each is tested at ALPHA / K)."""
NULL_SCALE = 8.0
"""The held-out chi-square of a candidate on a day with nothing missing is this many times a
chi-square of one degree of freedom: two models of a bus never agree to the watt, and the
structure they differ by is not noise (set on the tuning source's control days)."""
FORM_SPREAD = 0.35
"""The spread (one standard deviation of ln) of an effect's energy as a library form gives it
against the bus's own: a library form is not the bus's (set on the tuning source's days
named right); the energy's 90 % interval takes it in beside the noise's."""
BOOT = 200
SEED = 0
OUTSIDE_MODE = {"load while standing": "idle", "load while accelerating": "accelerating",
                "load while cruising": "cruising", "load while braking": "braking/regen",
                "load while charging": "CC charging",
                "load while braking at high SoC": "braking/regen",
                "load after the doors close": "idle",
                "load switching on and off while standing": "idle",
                "resisting force": "cruising"}
"""The operating mode (as the report names them) where each form outside the library puts
the power it misses."""


NULL_SCALE_SOC = 1.0
""":data:`NULL_SCALE` for a SoC-only log read by window (:mod:`.soc_power`): there the SoC's
steps, not the two models' structure, are most of a window's missing power (set on the
tuning source's control days as :data:`NULL_SCALE` was)."""


def needed(tried: int, scale: float = NULL_SCALE) -> float:
    """The held-out chi-square a candidate needs when ``tried`` were tested (``scale``: the
    log's null scale)."""
    return float(scale * chi2_dist.isf(ALPHA / max(tried, 1), 1))


def apart(scale: float = NULL_SCALE) -> float:
    """How much better (in noise units, held out) one candidate must predict than another to
    be preferred to it: a 5 % test at the log's null scale."""
    return float(scale * chi2_dist.isf(0.05, 1))



@dataclass
class Finding:
    """What the power path concludes."""

    status: str  # named, voltage, tie, implausible, outside library, noise
    verdict: str | None  # the named effect
    why: str
    since_day: int  # the day the named effect (or the outside form) acts from; 0: every day
    since_interval: tuple[int, int]  # the days it may start on, within the 90 % level
    clue: str | None  # the operating mode where a load outside the library shows
    tests: list[Test]  # best first
    forms: dict[str, Form]
    needed: float
    strength: dict = field(default_factory=dict)
    modes: list[dict] = field(default_factory=list)
    fall: float = float("nan")


def class_weights(residual: np.ndarray, bins, use: np.ndarray) -> np.ndarray:
    """1 / variance of each bin from the robust scatter (MAD) of the residual in its dominant
    operating mode; a mode with too few bins to say takes the scatter of all bins."""
    # a SoC-only log's window mixes the modes, and its noise is the SoC's steps in any mode
    mode = np.zeros(len(bins)) if bins.by_window else np.argmax(bins.mode_share, axis=1)
    floor = 50.0  # W: a bin is never trusted beyond the log's resolution

    def sigma(r):
        return max(1.4826 * float(np.median(np.abs(r - np.median(r)))), floor)

    w = np.full(len(residual), 1.0 / sigma(residual[use]) ** 2 if use.any() else 1.0)
    for m in np.unique(mode):
        inside = use & (mode == m)
        if inside.sum() >= 10:
            w[mode == m] = 1.0 / sigma(residual[inside]) ** 2
    return w


def candidate_forms(bus, profiles, bins, fit, days: int, add=(), runs=()):
    """Every form to test: the library's effects, the forms outside it, and on several days
    each from a day on. Returns (forms, the library's candidates, set aside)."""
    signatures_of = bin_signatures(profiles, bins, fit.runs)
    user = tuple(e for e in add if not e.builtin)
    effects, aside = effect_candidates(bus, profiles[0].dt_s, fit.values, signatures_of, user,
                                       runs=runs)
    forms = [Form(c.name, c.kind, c.signatures_w, strengths=c.strengths,
                  strength_param=c.strength_param, effect=c.effect) for c in effects]
    forms += outside_forms(profiles, bins, fit.runs)
    if days > 1:
        forms += [from_day(f, bins, d) for f in list(forms) for d in range(1, days)]
    return forms, effects, aside


def label(form: Form) -> str:
    return form.name if form.since_day == 0 else f"{form.name} from day {form.since_day}"


def since(tests: dict[str, Test], forms: dict[str, Form], name: str,
          scale: float = NULL_SCALE) -> tuple[int, tuple]:
    """The day a form acts from (0: every day) and the days within :func:`apart` of the best,
    among the forms of ``name`` on every day and from each day on."""
    mine = {forms[k].since_day: t for k, t in tests.items() if forms[k].name == name}
    best = min(mine.values(), key=lambda t: t.held_out_loss)
    day = next(d for d, t in mine.items() if t is best)
    close = [d for d, t in mine.items() if margin(best, t) <= apart(scale)]
    return day, (min(close), max(close))


MIN_OUTSIDE_KW = 0.3
"""The least power a load or force outside the library must tell apart (:func:`outside_kw`)
for the diagnosis to report it: less is a few lamps, no matter for a workshop, and within what
the model's own 1 Hz drivetrain and charger leave between like buses (a few hundred watts)."""


def outside_kw(test: Test, signature_w: np.ndarray, null_fitted: np.ndarray) -> float:
    """The power [kW] a form outside the library tells apart: what its fit adds to the
    prediction (against the fit without it, ``null_fitted``) on the bins where it acts
    (``signature_w``, at its chosen strength, above a twentieth of its largest) less what it
    adds on the others, the bus's parameters and the sensor's terms refitted beside it.
    A compressor after each door closing that the auxiliary load took in part counts whole;
    a load while charging fitted at 3 kW that frees the current sensor's gain to take the
    3 kW back on the charger (and fit a difference while driving) counts nothing."""
    acting = signature_w > 0.05 * signature_w.max()
    if not acting.any():
        return 0.0
    change = test.fitted - null_fitted
    elsewhere = float(np.mean(change[~acting])) if (~acting).any() else 0.0
    return (float(np.mean(change[acting])) - elsewhere) / 1e3


def separated(signature_w: np.ndarray, since_day: int, missing_w: np.ndarray,
              weights: np.ndarray, bins, use: np.ndarray) -> bool:
    """Whether the days split at ``since_day``: a form's size (``signature_w``: its signature
    on every day) fitted on each day alone (``sum w s y / sum w s^2`` over the day's bins) is
    larger on every day from then than on any day before. A change that starts on a day and
    stays splits them; the days' own spread (a bus meets another driver most days) does not,
    and a form from a day that only picks the days a spread happened to favour is no change
    from that day. With three days on each side, days that differ only by chance split so
    one time in 20."""
    if since_day == 0:
        return True
    s = signature_w
    size = {}
    for d in range(int(bins.day.max()) + 1):
        on = use & (bins.day == d) & (s != 0)
        if on.any():
            size[d] = float(np.sum(weights[on] * s[on] * missing_w[on])
                            / np.sum(weights[on] * s[on] ** 2))
    before = [v for d, v in size.items() if d < since_day]
    after = [v for d, v in size.items() if d >= since_day]
    return not before or not after or min(after) > max(before)


def reportable(name: str, forms: dict[str, Form], sizes_kw: dict[str, float]) -> bool:
    """Whether test ``name`` is of a form outside the library large enough to report
    (:data:`MIN_OUTSIDE_KW`)."""
    return forms[name].kind == "outside" and sizes_kw[name] >= MIN_OUTSIDE_KW


def decide(tests: dict[str, Test], forms: dict[str, Form], sizes_kw: dict[str, float],
           tried: int | None = None, scale: float = NULL_SCALE
           ) -> tuple[str, str | None, str, str | None]:
    """(status, the named effect or None, why, the operating-mode clue or None).

    A library effect is named when its held-out chi-square passes :func:`needed` for the
    number of candidates tried, no other library effect that passes comes within
    :func:`apart` of it, and no form outside the library predicts clearly better (then the
    library's effect explains only part). Where no library effect passes and a form outside
    it does, no library effect explains the missing power, and the form says where it goes
    missing. A form outside the library counts from :data:`MIN_OUTSIDE_KW` of its size
    (``sizes_kw``: :func:`outside_kw` by test name). ``tried``: the candidates tested
    (default: those in ``tests``); ``scale``: the log's null scale."""
    threshold, far = needed(tried or len(tests), scale), apart(scale)
    ranked = sorted(tests.values(), key=lambda t: -t.chi2)
    library = [t for t in ranked if forms[t.name].kind != "outside"]
    outside = [t for t in ranked if reportable(t.name, forms, sizes_kw)]
    best_out = outside[0] if outside and outside[0].chi2 >= threshold else None

    def best_of(effect):
        return min((t for t in library if forms[t.name].name == effect),
                   key=lambda t: t.held_out_loss)

    effects = list(dict.fromkeys(forms[t.name].name for t in library if t.chi2 >= threshold))
    if effects:
        best = [best_of(e) for e in effects]
        best.sort(key=lambda t: t.held_out_loss)
        top = best[0]
        name = forms[top.name].name
        if len(best) > 1 and margin(top, best[1]) < far:
            other = forms[best[1].name].name
            return "tie", None, (
                f"{name} and {other} both explain the missing power on held-out blocks "
                f"(chi-square {top.chi2:.0f} and {best[1].chi2:.0f}, {threshold:.0f} needed) and "
                "neither predicts them clearly better: the data cannot tell them apart"), None
        if best_out is not None and margin(best_out, top) >= far:
            form = forms[best_out.name]
            return "outside library", None, (
                f"{name} explains part of the missing power (chi-square {top.chi2:.0f}), but "
                f"{form.meaning.replace('a kW', 'some')} predicts the held-out blocks clearly "
                f"better (chi-square {best_out.chi2:.0f}): a load or force the library lacks"
            ), OUTSIDE_MODE.get(form.name)
        return "named", name, "", None
    best_lib = library[0] if library else None
    lib_note = (f"the best library effect, {label(forms[best_lib.name])}, removes "
                f"chi-square {best_lib.chi2:.0f} of the held-out loss" if best_lib
                else "no library effect could be tested")
    if best_out is not None:
        form = forms[best_out.name]
        when = f", from day {form.since_day} on" if form.since_day else ""
        return "outside library", None, (
            f"no library effect explains the missing power on held-out blocks ({lib_note}; "
            f"{threshold:.0f} needed); {form.meaning.replace('a kW', 'some')} does "
            f"(chi-square {best_out.chi2:.0f}){when}"), OUTSIDE_MODE.get(form.name)
    return "noise", None, (f"no candidate predicts held-out blocks better than the bus's own "
                           f"parameters ({lib_note}; {threshold:.0f} needed): the model "
                           "explains these data"), None


def energy_kwh(test: Test, form: Form, seconds: float) -> float:
    """The energy a tested form adds over the logs at its fitted strength [kWh] (``seconds``:
    a bin's length)."""
    return float(test.beta * form.signatures_w[test.choice].sum() * seconds / 3.6e6)


def fixed_size(form: Form) -> bool:
    """Whether a form is a library effect with no strength parameter (the road grade,
    ``m g sin(alpha)`` from the log's altitude). Its fitted coefficient is not a strength, and
    its input's noise shrinks it (regression dilution): a GPS altitude's few metres of error,
    correlated over a minute, fit the truth simulator's grade days at 0.46-0.57 of the
    grade's own size, their energy 29-69 % of the truth's. The energy's interval then reaches
    the form's own size (with the form's spread); the estimate stays the fitted one, since at
    its own size the input's noise costs energy of its own (up to 2.4 times the truth's on
    FASTSim's flatter days)."""
    return form.kind != "outside" and form.strengths is None


def strength_of(test: Test, form: Form, signatures: np.ndarray, y, w, nuisance, block,
                seconds: float) -> dict:
    """The form's strength (:func:`strength_read`: the chosen signature's, or the fitted
    size's) and the energy it adds over the logs [kWh] (of a :func:`fixed_size` form the
    interval reaching its own size), with 90 % intervals: the strengths whose fit lies within
    2.71 noise units of the best (what the shape of the data allows), refits on blocks
    resampled with replacement (what its noise allows) and, for the energy,
    :data:`FORM_SPREAD`; and the share of those refits at or beyond each end of the range
    (``beyond_share``). ``signatures`` are the form's on the fitted units; its own cover
    every unit."""
    total = form.signatures_w.sum(axis=1) * seconds / 3.6e6  # kWh per unit coefficient
    unit = noise_unit(y - test.fitted, w)
    energies, values, sides = [], [], []

    def value(k: int, beta: float) -> float:
        return strength_read(form, k, beta)[0]

    for k in range(len(signatures)):
        _, beta, _, _, loss = fit_all(y, w, nuisance, signatures[k:k + 1])
        if (loss - test.loss) / unit <= 2.71:
            energies.append(beta * total[k])
            if form.strengths is not None:
                values.append(value(k, beta))
    rng = np.random.default_rng(SEED)
    blocks = np.unique(block)
    for _ in range(BOOT):
        rows = np.concatenate([np.flatnonzero(block == b)
                               for b in rng.choice(blocks, len(blocks))])
        part = Nuisance(nuisance.names, nuisance.x[rows], nuisance.low, nuisance.high)
        k, beta, *_ = fit_all(y[rows], w[rows], part, signatures[:, rows])
        energies.append(beta * total[k])
        sides.append(bound_reached(form, k, beta))
        if form.strengths is not None:
            values.append(value(k, beta))
    energy = float(test.beta * total[test.choice])
    low, high = np.quantile(energies, [0.05, 0.95])
    spread = math.exp(1.645 * FORM_SPREAD)
    if fixed_size(form):  # the fit may be shrunk by its input's noise: up to its own size
        high = max(high, float(total[test.choice]) * spread)
    out = {"energy_kwh": energy,
           "energy_interval_kwh": [float(min(low, energy / spread)),
                                   float(max(high, energy * spread))],
           "coefficient": test.beta,
           "beyond_share": {side: sides.count(side) / len(sides) for side in ("lower", "upper")}}
    if form.strengths is not None and form.strength_param:
        out["parameters"] = {form.strength_param: float(value(test.choice, test.beta))}
        low, high = np.quantile(values, [0.05, 0.95])
        grid = np.sort(np.asarray(form.strengths, float))
        # no finer than the grid of strengths tried: out to halfway to the next ones
        below, above = grid[grid < low], grid[grid > high]
        low = min(low, 0.5 * (low + below[-1])) if len(below) else low
        high = max(high, 0.5 * (high + above[0])) if len(above) else high
        out["interval"] = {form.strength_param: [float(low), float(high)]}
    return out


PARALLEL = 0.98
"""The cosine between signatures above which a form's strengths differ mostly in size (a
load's scale): its fitted size then reads its strength too (:func:`scaled`). A cabin's
signatures across its conductance stand at 0.985-1 (the fans' and the sun's share stays while
the conductance scales the rest), a regen limit's across its SoC fall to 0.5 and below."""
SAME_SHAPE = 0.999
"""The cosine above which signatures differ only in size: the one chosen among them is
chance, and the size alone reads the strength."""


def scaled(form: Form, choice: int, beta: float) -> tuple[float, str | None] | None:
    """For a form whose signatures differ mostly in size across its strengths, the strength
    whose signature is the fitted power ``beta`` times the chosen one, interpolated in the
    signatures' sizes, and the end of the range the fit lies beyond ("lower", "upper"; None
    inside). None for a form whose shape changes with its strength (a regen limit's SoC),
    where the chosen signature says the strength.

    The held-out test fits a coefficient beside the chosen signature, so a load's signature
    at scale 5 times 0.3 is a scale of 1.5: reading the strength off the chosen signature
    alone would overstate it, and call it a bound where it is not."""
    if form.strengths is None or len(form.strengths) < 3:
        return None
    sig = np.asarray(form.signatures_w, float)
    ref = sig[choice]
    norm = float(np.linalg.norm(ref))
    if norm <= 0.0 or least_cosine(form, choice) < PARALLEL:
        return None
    size = sig @ ref / norm**2  # each signature's size, the chosen one's 1
    values = np.asarray(form.strengths, float)
    order = np.argsort(size)
    size, values = size[order], values[order]
    if np.any(np.diff(values) < 0) and np.any(np.diff(values) > 0):
        return None  # the size does not follow the strength one way
    rising = values[-1] >= values[0]
    if beta > size[-1]:
        return float(values[-1]), "upper" if rising else "lower"
    if beta < size[0]:
        return float(values[0]), "lower" if rising else "upper"
    return float(np.interp(beta, size, values)), None


def least_cosine(form: Form, choice: int) -> float:
    """The least cosine between the chosen signature and the form's others (1 for one of a
    single shape)."""
    sig = np.asarray(form.signatures_w, float)
    ref = sig[choice]
    norm = float(np.linalg.norm(ref))
    lengths = np.linalg.norm(sig, axis=1)
    on = lengths > 1e-9 * norm
    if norm <= 0.0 or not on.any():
        return 1.0
    return float(np.min(np.abs(sig[on] @ ref) / (lengths[on] * norm)))


def strength_read(form: Form, choice: int, beta: float = 1.0) -> tuple[float, str | None]:
    """The strength a form was fitted at (``choice``, with coefficient ``beta``) and the end
    of its parameter's declared range it lies at or beyond (None inside; the signatures span
    the range, ends included). Two readings: the chosen signature's own strength (its shape)
    and, for signatures that differ mostly in size, the fitted size (:func:`scaled`). Where
    the shapes bend (a cabin: the shape follows the conductance, the size the energy), the
    form is at an end only where both readings are, and the strength is the size's reading
    where that is inside, else the shape's: on the truth simulator's cooling days the best
    shape was the top conductance at half to two thirds of its size, and on FASTSim's (whose air
    conditioner draws half the library's power for the same heat) a shape inside the range
    at a size below the least conductance's."""
    values = np.asarray(form.strengths, float)
    shape_value = float(values[choice])
    shape_side = ("lower" if shape_value <= values.min() else
                  "upper" if shape_value >= values.max() else None)
    by_size = scaled(form, choice, beta)
    if by_size is None:
        return shape_value, shape_side
    if by_size[1] is None or least_cosine(form, choice) >= SAME_SHAPE:
        return by_size
    return (by_size if by_size[1] == shape_side else (shape_value, None))


def bound_reached(form: Form, choice: int, beta: float = 1.0) -> str | None:
    """``"lower"`` or ``"upper"`` where the strength a form was fitted at is an end of its
    parameter's declared range (:func:`strength_read`), else None."""
    if form.strengths is None or len(form.strengths) < 3:
        return None
    return strength_read(form, choice, beta)[1]


BEYOND_SURE = 0.95
"""The share of block resamples whose fit lies at or beyond the same end of a form's range
that withdraws a verdict whose strength is at that end (:func:`bound_reached`): the data
must ask for more than the effect can physically be, not merely reach the end (the one-sided
level of the 90 % intervals the strength and energy are given with)."""


def at_end_note(strength: dict) -> str:
    """What the report adds to a verdict whose strength is at an end of its range, where
    fewer than :data:`BEYOND_SURE` of the block resamples lie there ('' otherwise)."""
    side = strength.get("at_end")
    if not side:
        return ""
    return (f"; its strength is at the {side} end of its range, where the data ask beyond it "
            f"in {100 * strength['beyond_share'][side]:.0f} % of the block resamples "
            f"({100 * BEYOND_SURE:.0f} % would withdraw it)")


def implausible_why(form: Form, test: Test, side: str) -> str:
    """Why a library effect that passed is not named: its strength ends at a bound. Every
    bus-to-bus parameter was free beside it, so the data ask for more than the effect can
    physically be, and what it took up is another shape (the SoC windows' rule, in
    :mod:`~ebus_env.diagnostics.stage06_attribution`, without a re-calibration to settle
    it: here the bus's parameters are already free)."""
    values = np.asarray(form.strengths, float)
    value = strength_read(form, test.choice, test.beta)[0]
    return (f"the shape of {label(form)} fits (chi-square {test.chi2:.0f}), the strength is "
            f"implausible: {form.strength_param} ends at its {side} bound, "
            f"{value:.4g} (range {values.min():.4g} to {values.max():.4g}), "
            "with every bus-to-bus parameter free beside it (its form differs from what the "
            "log shows)")


def steady_pack_why(finding: Finding, moved: float, check) -> str:
    """Why an effect the power named is withdrawn: at its fitted strength it would move the
    pack's resistance by ``moved`` (ln span between periods) where the logged voltage shows
    it steady (:data:`~ebus_env.diagnostics.voltage.MIN_CHANGE`). Set on the truth
    simulator's control day 04: a pack held at 25 degC, whose missing power a pack 24 K warm
    at the start took up in part."""
    value = ", ".join(f"{k} = {v:.4g}" for k, v in finding.strength.get("parameters", {}).items())
    return (f"{finding.verdict} removes {100 * finding.fall:.0f} % of the missing power on "
            f"held-out blocks, but at {value} it would move the pack's resistance by "
            f"{100 * moved:.0f} % over the log, where the logged voltage shows it steady (within "
            f"{100 * check.span:.0f} %): the power's shape is another's")


MIN_REPRODUCED = 0.5
"""The least share of the voltage's change of the pack's resistance that an effect the power
named, and that moves the resistance, must reproduce at its best strength to stand
(:func:`unreproduced_pack_why`): less, and more of the change is left than it explains."""


def unreproduced_pack_why(finding: Finding, check) -> str:
    """Why an effect the power named is withdrawn where the logged voltage shows the pack's
    resistance changing ('' where it stands): the effect moves the resistance, yet at its best
    strength for the voltage it reproduces less than :data:`MIN_REPRODUCED` of the change. A
    pack effect reaches the power only through its losses (I^2 R, a few per cent of the
    energy), which any rise of the resistance raises alike; the voltage reads the resistance
    itself. Prompted by two buses of the truth bench's held-out sources: FASTSim's weak cell
    group (the resistance 27 % higher from the day it failed, flat within each day), which
    the power named a pack 11 K off its ambient, an effect that reproduced none of the
    voltage's change, and the backward model's pack chiller, also named ``ambient_battery``."""
    fit = next((f for f in check.explained_by if f.effect == finding.verdict), None)
    if fit is None or fit.explained >= MIN_REPRODUCED:
        return ""
    return (f"{finding.verdict} removes {100 * finding.fall:.0f} % of the missing power on "
            f"held-out blocks, but the logged voltage shows the pack's resistance changing by "
            f"{100 * check.span:.0f} % over the log in a way it does not reproduce (at its best "
            f"strength, {100 * max(fit.explained, 0.0):.0f} % of the change; "
            f"{100 * MIN_REPRODUCED:.0f} % needed): the power's shape is another's")


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
    boot = np.array([fit(np.concatenate([np.flatnonzero(block == b)
                                         for b in rng.choice(blocks, len(blocks))]))
                     for _ in range(BOOT)])
    seen = np.isfinite(boot).any(axis=0)
    se = np.full(boot.shape[1], np.nan)
    se[seen] = np.nanstd(boot[:, seen], axis=0)
    hours = bins.mode_share[use].sum(axis=0) * bins.seconds / 3600.0
    return [{"mode": m, "missing_kw": float(c) / 1e3, "stderr_kw": float(s) / 1e3,
             "hours": float(h), "missing_kwh": float(c) / 1e3 * float(h)}
            for m, c, s, h in zip(MODES, coef, se, hours, strict=True)]


def voltage_evidence(model, profiles, params, candidates, day_of: list[int],
                     named: tuple[str, dict] | None = None):
    """What the logged voltage says of the pack's resistance over the model's, which library
    effect reproduces a change of it over the log (:mod:`~ebus_env.diagnostics.voltage`),
    and on several days whether it rose from a day on (``check.step``); None without a
    change to show. ``named``: the effect the power named and its fitted strength; returned
    beside the check is how far that effect would move the pack's resistance over the log
    (the span of its ln ratio between periods; 0 for one that does not move it)."""
    check, windows, anchored = resistance_check_at(model, profiles, params)
    usable = np.ones(len(windows), bool)
    if check is not None and check.changes:
        check.explained_by = explain_change(check, profiles, anchored, windows, usable,
                                            candidates, shapes=True)
    if check is not None:
        check.step = day_step(check, windows, profiles, day_of)
    effect, values = named or (None, {})
    c = next((c for c in candidates if c.name == effect), None)
    if check is None or c is None or c.strength_param not in values:
        return check, 0.0
    row, _ = strength_rows(c.model, c.params, c.strength_param, [values[c.strength_param]])
    ln = predicted_ln_ratios(check, c.model, row[0], profiles, anchored, windows, usable)
    return check, float(np.nanmax(ln) - np.nanmin(ln)) if np.isfinite(ln).any() else 0.0


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
    resistance: object = None  # voltage.ResistanceCheck, or None

    @property
    def bus_table(self) -> list[dict]:
        """The bus as its logs give it: the fitted parameters and sensor terms
        (:meth:`~ebus_env.diagnostics.power_fit.BusFit.table`)."""
        return self.fit.table(self.logged_w, self.bins.fit, self.weights)

    @property
    def logger_lag_s(self) -> float | None:
        """Where a logged second starts against its time stamp [s] (:func:`logger_lag`); None
        on SoC-only logs, read by window."""
        if self.bins.by_window:
            return None
        return self.bins.lag * self.profiles[0].dt_s


def diagnose_power(bus, profiles, day_of: list[int], add=(), fixed=None, say=None) -> PowerRun:
    """The power path on ``profiles`` (``day_of``: each profile's day, 0 first): BMS logs
    in bins of :data:`BIN_S`; where a log has no pack current, the SoC's count in windows of
    :data:`~ebus_env.diagnostics.soc_power.WINDOW_S` (:mod:`~ebus_env.diagnostics.soc_power`),
    without the logged voltage's evidence."""
    say = say or (lambda text: None)
    fixed = dict(fixed or {})
    model = bus.build(profiles[0].dt_s)
    bms = all(logs_power(p) for p in profiles)
    pack: dict[str, float] = {}
    if bms:  # the capacity from the counted charge, the resistance from the logged voltage
        pack = {k: v for k, v in pack_values(model, profiles).items() if k not in fixed}
        resistance = pack_resistance(model, profiles,
                                     model.param_vector(model.carry_over({**pack, **fixed})))
        pack.update({k: v for k, v in resistance.items() if k not in fixed})
    start = {**pack, **fixed}
    params = model.param_vector(model.carry_over(start))
    if not bms:  # the SoC's count in each window, as a power log (:mod:`.soc_power`)
        profiles = as_power_logs(model, profiles, params)
    lag = logger_lag(model, profiles, params) if bms else 0
    first = anchored_runs(model, profiles, params, TRACE, lag)
    delivered = model.equivalent(CHARGER_SHARE)
    bins = make_bins(profiles, [r[0] for r in first], day_of, lag,
                     params[model.param_index(delivered)] if delivered else 1.0,
                     BIN_S if bms else WINDOW_S)
    logged = bins.means(log_power(profiles))
    voltage = bins.means(log_voltage(profiles))
    use = bins.fit
    say("fitting the bus to the logged power")
    fit = fit_bus(model, profiles, bins, logged, voltage, np.ones(len(bins)), start,
                  tuple(fixed))
    weights = class_weights(fit.missing(logged, use), bins, use)
    fit = fit_bus(model, profiles, bins, logged, voltage, weights, fit.values, tuple(fixed), 2)
    missing = fit.missing(logged, use, weights)
    weights = class_weights(missing, bins, use)
    say("signatures of the candidates")
    every = max(1, int(round(1.0 / profiles[0].dt_s)))
    recorded = [model.simulate(p, fit.params, record_every=every) for p in profiles]
    days = max(day_of) + 1
    forms, effects, aside = candidate_forms(bus, profiles, bins, fit, days, add, recorded)
    by_label = {label(f): f for f in forms}
    say(f"held-out tests of {len(forms)} candidates")
    nuisance = fit.tested_nuisance(use)
    held = HeldOut(missing[use], weights[use], nuisance, bins.block[use])
    tests = {name: held.test(name, f.signatures_w[:, use]) for name, f in by_label.items()}
    # a form outside the library from a day on must split the days there (the days' own
    # spread is no change from a day)
    credible = {k: t for k, t in tests.items() if by_label[k].kind != "outside"
                or separated(by_label[by_label[k].name].signatures_w[0],
                             by_label[k].since_day, missing, weights, bins, use)}
    sizes = {k: outside_kw(t, by_label[k].signatures_w[t.choice][use], held.null_fitted)
             for k, t in tests.items() if by_label[k].kind == "outside"}
    scale = NULL_SCALE if bms else NULL_SCALE_SOC
    status, verdict, why, clue = decide(credible, by_label, sizes, len(tests), scale)
    finding = Finding(status, verdict, why, 0, (0, 0), clue,
                      sorted(tests.values(), key=lambda t: -t.chi2), by_label,
                      needed(len(tests), scale))
    if verdict is not None:
        finding.since_day, finding.since_interval = since(tests, by_label, verdict, scale)
        best = next(t for k, t in tests.items() if by_label[k].name == verdict
                    and by_label[k].since_day == finding.since_day)
        form = by_label[best.name]
        finding.fall = best.gain
        finding.strength = strength_of(best, form, form.signatures_w[:, use], missing[use],
                                       weights[use], nuisance, bins.block[use], bins.seconds)
        side = bound_reached(form, best.choice, best.beta)
        if side and finding.strength["beyond_share"][side] >= BEYOND_SURE:
            finding.why = implausible_why(form, best, side)  # withdrawn: no strength to give
            finding.status, finding.verdict, finding.strength = "implausible", None, {}
            finding.since_day, finding.since_interval = 0, (0, 0)
        elif side:
            finding.strength["at_end"] = side
    elif status == "outside library" and tests:
        top = max((t for k, t in credible.items() if reportable(k, by_label, sizes)),
                  key=lambda t: t.chi2)
        finding.since_day, finding.since_interval = since(credible, by_label,
                                                          by_label[top.name].name, scale)
    finding.modes = mode_table(missing, weights, bins, use)
    say("the pack's resistance from the logged voltage")
    named = (finding.verdict, finding.strength.get("parameters", {})) \
        if finding.status == "named" else None
    check, moved = voltage_evidence(model, profiles, fit.params, effects, day_of, named) \
        if bms else (None, 0.0)
    if check is not None and moved >= MIN_CHANGE and finding.status == "named":
        # the two signals are independent, and the voltage is the pack's own measure
        why = steady_pack_why(finding, moved, check) if not check.changes \
            else unreproduced_pack_why(finding, check)
        if why:
            finding.why = why
            finding.status, finding.verdict, finding.strength = "implausible", None, {}
            finding.since_day, finding.since_interval = 0, (0, 0)
    if check is not None and check.step is not None and finding.status != "named" \
            and ages(bus):
        # the pack's own measure, beside which the power's shapes are second-hand: a weak
        # cell group moves the power only where the charger's CV phase and regen near full
        # bind, which a missing-power test takes for a regen limit or a load there
        step = check.step
        finding.status, finding.verdict, finding.clue = "voltage", AGEING, None
        finding.since_day, finding.since_interval = step.since_day, step.since_days
        finding.why = step.why("this day")
        finding.strength = step_strength(step, check, model, profiles, day_of, FORM_SPREAD)
    elif check is not None and check.best is not None and finding.status in (
            "noise", "outside library", "implausible"):
        finding.status, finding.verdict = "voltage", check.best.effect
        finding.why = (f"the logged voltage shows the pack's resistance changing over the log, "
                       f"and {check.best.effect} reproduces {100 * check.best.explained:.0f} % "
                       "of the change; the power the pack delivered shows no missing effect")
    return PowerRun(model, list(profiles), bins, fit, logged, missing, weights, finding, aside,
                    pack, check)


def summary(run: PowerRun) -> dict:
    """The finding in plain numbers (for quick looks and the bench)."""
    f = run.finding
    return {"status": f.status, "verdict": f.verdict, "since_day": f.since_day,
            "since_interval": f.since_interval, "clue": f.clue, "needed": f.needed,
            "why": f.why,
            "top": [(t.name, round(t.chi2, 1), round(t.gain, 3),
                     round(energy_kwh(t, f.forms[t.name], run.bins.seconds), 2))
                    for t in f.tests[:5]],
            "strength": f.strength, "fall": f.fall,
            "modes": [(m["mode"], round(m["missing_kw"], 2), round(m["stderr_kw"], 2))
                      for m in f.modes if math.isfinite(m["missing_kw"])],
            "pack": run.pack, "logger_lag_s": run.logger_lag_s,
            "resistance": run.resistance.finding() if run.resistance else None}
