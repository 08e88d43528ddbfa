"""Which candidate explains the missing power: sparse, cross-validated, robust regression.

Each window's missing power y_w is fitted by a candidate's signature s_w scaled by beta (an
effect's beta >= 0: an effect cannot be "negatively present"; of an effect's signatures at
several strengths, the one that fits the training windows best), weighted by the window's
uncertainty, with Huber's loss so that a window the model cannot know about (the driver
switches the heater on a minute in) does not decide the fit. The windows are dealt into
``folds`` folds; each is predicted from a fit on the others, and a candidate's score is the
share of the missing power it explains on held-out windows::

    explained = 1 - sum huber(sqrt(w) (y - beta s)) / sum huber(sqrt(w) y)   (held-out)

Forward stepwise selection then adds candidates while each adds at least ``MIN_GAIN`` to the
held-out share. The verdict is the best missing effect only when

* there are ``MIN_WINDOWS`` usable windows at least: fewer cannot be dealt into folds and
  bootstrap blocks that test anything (a 17-min log holds three 5-min windows);
* the missing power stands out of the noise: chi-square of the windows' missing power in
  noise units lies ``MIN_SIGNIFICANCE`` standard deviations above its value for noise alone;
* the effect explains at least ``MIN_EXPLAINED`` of it, and ``MIN_GAIN`` more than
  re-adjusting the calibrated (nuisance) parameters alone;
* it beats the nuisance parameters alone in ``CONFIDENCE`` of the draws of a moving-block
  bootstrap over the windows' held-out losses (Kuensch 1989, Ann. Statist. 17(3) 1217-1241);
* it beats the runner-up by ``MIN_MARGIN`` of the share, or in ``CONFIDENCE`` of the
  bootstrap draws (a clear winner by a few points): else the data cannot tell the two apart,
  and both are reported, neither named;
* it still adds ``MIN_GAIN`` when a parameter of the model explains as much on its own (else
  a mis-set parameter, not a missing effect, is the simpler explanation).

Otherwise no missing effect is supported by the data.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ebus_env.diagnostics.boxlsq import bounded_lstsq

MIN_EXPLAINED = 0.3
MIN_SIGNIFICANCE = 3.0
MIN_MARGIN = 0.05
MIN_GAIN = 0.05
TIE = 0.01  # held-out shares this close are equal
BOOT_BLOCK = 6  # windows per bootstrap block (30 min of 5-min windows)
BOOT_DRAWS = 400
MIN_WINDOWS = 2 * BOOT_BLOCK  # usable windows an attribution needs
CONFIDENCE = 0.95  # a winner beats the runner-up in this share of the bootstrap draws
NUISANCE_STEPS = 1.0
"""How far a calibrated (nuisance) parameter may move back when an effect is added, in its
signature's steps (10 % of its range): unbounded, a dozen collinear signatures over-fit the
training windows and predict the held-out ones worse than nothing."""
HUBER_C = 3.0  # noise units: a window this far off is an outlier (a driver's action, a glitch)
FIT_STEPS = 200  # reweighting steps of a robust fit, at most
FIT_TOL = 1e-9  # converged: no coefficient's column moves the fit by more (of the data's norm)


@dataclass
class Attribution:
    name: str
    kind: str
    explained: float  # held-out share of the missing power
    scale: float  # beta: the candidate's strength relative to its signature
    fit_w: np.ndarray | None = field(default=None, repr=False)  # per window: beta s + nuisance
    estimate: dict = field(default_factory=dict)  # parameter -> value, for the verdict
    lost: np.ndarray = field(default=None, repr=False)  # held-out loss per window
    total: np.ndarray = field(default=None, repr=False)  # loss of predicting nothing
    band: tuple[float, float] = (float("nan"), float("nan"))  # bootstrap 5-95 % of explained


def weights(noise: np.ndarray) -> np.ndarray:
    floor = np.median(noise) if np.isfinite(np.median(noise)) else 1.0
    return 1.0 / (noise**2 + floor**2 + 1e-12)


def folds_of(n: int, folds: int) -> list[np.ndarray]:
    """Interleaved folds: window i is held out in fold i mod ``folds``, so every fold sees
    every part of the day (a feature that occurs once, a warm-up, is in some training folds)."""
    return [np.arange(k, n, folds) for k in range(min(folds, n))]


def huber(r: np.ndarray) -> np.ndarray:
    """Huber's loss of residuals in noise units: quadratic within ``HUBER_C``, linear beyond."""
    a = np.abs(r)
    return np.where(a <= HUBER_C, 0.5 * r * r, HUBER_C * (a - 0.5 * HUBER_C))


def _bounds(nonneg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.where(nonneg, 0.0, -np.inf), np.full(len(nonneg), np.inf)


def _fit(x: np.ndarray, y: np.ndarray, w: np.ndarray, nonneg: np.ndarray,
         bounds: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Weighted robust least squares, coefficients >= 0 where asked (or within ``bounds``)::

        min_beta  sum_w huber(sqrt(w) (y - x beta))

    by iteratively reweighted least squares (Holland & Welsch 1977, Commun. Statist. A6(9)
    813-827): each step solves the bounded linear least-squares problem
    (:func:`~ebus_env.diagnostics.boxlsq.bounded_lstsq`, from the bounds that held in the
    step before) with the windows beyond ``HUBER_C`` weighted down by ``HUBER_C / |r|``. That
    quadratic lies above Huber's loss and touches it at the current residuals, so every step
    lowers the loss, to the convex problem's minimum."""
    sw = np.sqrt(w)
    a, b = x * sw[:, None], y * sw
    low, high = (np.asarray(v, float) for v in (bounds or _bounds(nonneg)))
    scale = np.maximum(np.linalg.norm(a, axis=0), 1e-300)
    beta, side = bounded_lstsq(a, b, low, high)
    r = np.abs(a @ beta - b)
    if not np.any(r > HUBER_C):
        return beta  # no window in the linear part of the loss: least squares is the answer
    for _ in range(FIT_STEPS):
        v = np.sqrt(np.minimum(1.0, HUBER_C / np.maximum(r, 1e-300)))
        new, side = bounded_lstsq(a * v[:, None], b * v, low, high, side)
        moved = float(np.max(np.abs(new - beta) * scale))
        beta = new
        if moved <= FIT_TOL * (1.0 + float(np.linalg.norm(b))):
            break
        r = np.abs(a @ beta - b)
    return beta


def held_out_explained(x: np.ndarray, y: np.ndarray, w: np.ndarray, nonneg: np.ndarray,
                       folds: int) -> float:
    """Held-out share of y explained by the columns of x: 1 - sum huber(held-out residual) /
    sum huber(y) over the folds."""
    lost = total = 0.0
    sw = np.sqrt(w)
    for test in folds_of(len(y), folds):
        train = np.setdiff1d(np.arange(len(y)), test)
        if len(train) < x.shape[1] + 1:
            continue
        beta = _fit(x[train], y[train], w[train], nonneg)
        lost += float(np.sum(huber(sw[test] * (y[test] - x[test] @ beta))))
        total += float(np.sum(huber(sw[test] * y[test])))
    return 1.0 - lost / total if total > 0 else 0.0


def _loss(x: np.ndarray, y: np.ndarray, w: np.ndarray, bounds) -> tuple[float, np.ndarray]:
    """Huber loss of the best fit of y by the columns of x (coefficients within ``bounds``),
    and the coefficients."""
    beta = _fit(x, y, w, np.zeros(x.shape[1], bool), bounds)
    return float(np.sum(huber(np.sqrt(w) * (y - x @ beta)))), beta


def held_out_best(variants: np.ndarray, y: np.ndarray, w: np.ndarray, nonneg: bool,
                  folds: int, nuisance: np.ndarray | None = None) -> tuple[
        float, int, np.ndarray, np.ndarray, np.ndarray]:
    """Held-out share of y explained by one of several signatures (rows of ``variants``: an
    effect at several strengths) together with the ``nuisance`` columns (parameters free to
    re-adjust), the variant that fits the training folds best chosen in each fold. Returns
    the share, the variant that fits all windows best, its coefficients (the variant's first,
    then the nuisance columns'), and per window the held-out loss and the loss of predicting
    nothing (for the bootstrap)."""
    extra = np.zeros((len(y), 0)) if nuisance is None else nuisance
    signs = np.zeros(1 + extra.shape[1])
    bounds = (np.concatenate([[0.0 if nonneg else -np.inf], np.full(extra.shape[1],
                                                                   -NUISANCE_STEPS)]),
              np.concatenate([[np.inf], np.full(extra.shape[1], NUISANCE_STEPS)]))
    sw = np.sqrt(w)

    def fits(rows):
        return [_loss(np.column_stack([v[rows], extra[rows]]), y[rows], w[rows], bounds)
                for v in variants]

    lost = np.zeros(len(y))
    total = huber(sw * y)
    for test in folds_of(len(y), folds):
        train = np.setdiff1d(np.arange(len(y)), test)
        if len(train) < len(signs) + 1:
            lost[test] = total[test]
            continue
        trained = fits(train)
        k = int(np.argmin([f[0] for f in trained]))
        pred = np.column_stack([variants[k][test], extra[test]]) @ trained[k][1]
        lost[test] = huber(sw[test] * (y[test] - pred))
    everything = fits(np.arange(len(y)))
    chosen = int(np.argmin([f[0] for f in everything]))
    share = 1.0 - lost.sum() / total.sum() if total.sum() > 0 else 0.0
    return share, chosen, everything[chosen][1], lost, total


def block_draws(n: int, block: int = BOOT_BLOCK, draws: int = BOOT_DRAWS,
                seed: int = 0) -> np.ndarray:
    """Moving-block bootstrap over ``n`` consecutive windows: (draws, n) counts of how often
    each window is drawn, blocks of ``block`` windows starting anywhere (Kuensch 1989), so
    that the power missing in neighbouring windows, which is correlated, is drawn together."""
    rng = np.random.default_rng(seed)
    block = max(1, min(block, n))
    starts = rng.integers(0, n - block + 1, (draws, -(-n // block)))
    rows = (starts[:, :, None] + np.arange(block)).reshape(draws, -1)[:, :n]
    counts = np.zeros((draws, n))
    np.add.at(counts, (np.repeat(np.arange(draws), rows.shape[1]), rows.ravel()), 1.0)
    return counts


def shares(counts: np.ndarray, lost: np.ndarray, total: np.ndarray) -> np.ndarray:
    """Held-out explained share in each bootstrap draw."""
    return 1.0 - (counts @ lost) / np.maximum(counts @ total, 1e-300)


def _score(by_name, names: list[str], y, w, usable, folds) -> float:
    """Held-out share of y that the candidates ``names`` explain together."""
    x = np.column_stack([by_name[n].signature_w[usable] for n in names])
    nonneg = np.array([by_name[n].kind != "parameter" for n in names])
    return held_out_explained(x, y, w, nonneg, folds)


def _gain(by_name, base: list[str], extra: str, y, w, usable, folds) -> float:
    """Held-out share that ``extra`` adds to the candidates ``base``."""
    return _score(by_name, base + [extra], y, w, usable, folds) - _score(by_name, base, y, w,
                                                                         usable, folds)


class Decision(NamedTuple):
    """What :func:`attribute` concludes."""

    ranking: list[Attribution]  # single candidates, best first
    selected: list[str]  # the sparse set of forward selection
    verdict: str | None
    why: str  # why there is no verdict
    significance: float  # of the missing power above noise, in standard deviations
    status: str  # "named", "too few windows", "noise", "outside library", "tie", "parameter"


def attribute(missing_w: np.ndarray, noise_w: np.ndarray, candidates, usable: np.ndarray,
              folds: int = 5, nuisance: tuple[str, ...] = (),
              measurement_w: np.ndarray | None = None) -> Decision:
    """Score every candidate alone, select a sparse set, and decide the verdict.

    ``nuisance`` names parameter candidates fitted along with every effect: after a
    calibration, the calibrated parameters have absorbed part of a missing effect, and adding
    the effect lets them move back. The held-out losses per window are resampled by a
    moving-block bootstrap (:func:`block_draws`): the best effect is named only when it beats
    re-adjusting the nuisance parameters alone in ``CONFIDENCE`` of the draws, and the
    runner-up by ``MIN_MARGIN`` or in ``CONFIDENCE`` of the draws (see the module docstring);
    a band of 5-95 % of its explained share goes with each effect.

    ``noise_w`` weighs the windows; ``measurement_w`` (default ``noise_w``), the log's own
    standard error, is what the missing power must stand out of: the model's error on a
    window's power is mostly a scale error that calibration takes up, not scatter."""
    y = missing_w[usable]
    w = weights(noise_w[usable])
    significance = _significance(
        y, (noise_w if measurement_w is None else measurement_w)[usable])
    by_name = {c.name: c for c in candidates}
    nuisance = tuple(n for n in nuisance if n in by_name)
    extra = np.column_stack([by_name[n].signature_w[usable] for n in nuisance]) \
        if nuisance else None
    moving = np.column_stack([by_name[n].signature_w for n in nuisance]) if nuisance else None
    ranking = []
    for c in candidates:
        effect = c.kind != "parameter"
        explained, c.chosen, beta, lost, total = held_out_best(
            c.signatures_w[:, usable], y, w, effect, folds, extra if effect else None)
        # what the fit predicts: the effect, and the calibrated parameters moving back with it
        fit_w = beta[0] * c.signature_w + (moving @ beta[1:] if len(beta) > 1 else 0.0)
        ranking.append(Attribution(c.name, c.kind, explained, float(beta[0]), fit_w,
                                   lost=lost, total=total))
    ranking.sort(key=lambda a: -a.explained)
    counts = block_draws(len(y))
    for a in ranking:
        a.band = tuple(np.quantile(shares(counts, a.lost, a.total), [0.05, 0.95]).tolist())
    selected: list[str] = []
    current = 0.0
    pool = [a.name for a in ranking[:25]]  # the best 25 alone are the only ones worth trying
    while pool:
        best, gain = None, MIN_GAIN
        for name in pool:
            score = _score(by_name, selected + [name], y, w, usable, folds)
            if score - current > gain:
                best, gain = name, score - current
        if best is None:
            break
        selected.append(best)
        current += gain
        pool.remove(best)
    effects = [a for a in ranking if a.kind != "parameter"]
    params = [a for a in ranking if a.kind == "parameter"]
    if len(y) < MIN_WINDOWS:
        return Decision(ranking, selected, None, (
            f"only {len(y)} usable windows: too few to tell effects apart on held-out windows "
            f"(at least {MIN_WINDOWS} are needed); diagnose several logs of the bus together, "
            "or give a shorter --window-s where the log's SoC resolution allows it"),
            significance, "too few windows")
    if significance < MIN_SIGNIFICANCE:
        return Decision(ranking, selected, None, (
            f"the missing power is at the noise level ({standing(significance)} it): the model "
            "explains these data"), significance, "noise")
    # a day with nothing wrong can end here too: a calibrated model of another make of bus
    # misses power beyond the log's noise (docs/validation.md counts the control days)
    outside = ("no library effect explains the missing power on held-out windows{}: a load "
               "or loss the library lacks, or where this bus differs from the calibrated model "
               "(a day with nothing wrong ends the same way); the clues and the operating modes "
               "say where the power is missing, and a normal day of the bus (--reference) says "
               "what it misses all the same")
    if not effects:
        return Decision(ranking, selected, None, outside.format(""), significance,
                        "outside library")
    top = effects[0]
    top_b = shares(counts, top.lost, top.total)
    if extra is not None:
        base = held_out_best(np.zeros((1, len(y))), y, w, True, folds, extra)
        base_share, base_b = base[0], shares(counts, base[3], base[4])
    else:
        base_share, base_b = 0.0, np.zeros(len(counts))
    gain_low = float(np.quantile(top_b - base_b, 1.0 - CONFIDENCE))
    if top.explained < MIN_EXPLAINED or top.explained - base_share < MIN_GAIN or gain_low <= 0:
        best = (f" (best: {top.name}, {100 * top.explained:.0f} %"
                + (f", re-adjusting the calibrated parameters alone {100 * base_share:.0f} %"
                   if extra is not None else "") + ")")
        return Decision(ranking, selected, None, outside.format(best), significance,
                        "outside library")
    if len(effects) > 1:
        second = effects[1]
        wins = float(np.mean(top_b > shares(counts, second.lost, second.total)))
        if wins < CONFIDENCE and top.explained - second.explained < MIN_MARGIN:
            return Decision(ranking, selected, None, (
                f"{top.name} and {second.name} explain the missing power about equally "
                f"({100 * top.explained:.0f} and {100 * second.explained:.0f} %; the first "
                f"fits better in {100 * wins:.0f} % of bootstrap resamples of the held-out "
                "windows): the data cannot tell them apart"), significance, "tie")
    if params and params[0].explained >= top.explained - TIE and _gain(
            by_name, [params[0].name], top.name, y, w, usable, folds) < MIN_GAIN:
        # a calibrated parameter fits the calibration hours, not these windows: its value (or
        # its search range) is what to question; an uncalibrated one is simply to be fitted
        fix = ("its calibrated value fits the calibration hours, not these windows: check it, "
               "hold a value you know (--set) or widen its search range"
               if params[0].name in nuisance else "calibrate it (--calibrate)")
        return Decision(ranking, selected, None, (
            f"the parameter {params[0].name} explains the missing power as well "
            f"({100 * params[0].explained:.0f} %, {top.name} {100 * top.explained:.0f} %): a "
            f"mis-set parameter is the simpler explanation; {fix} before adding an effect"),
            significance, "parameter")
    return Decision(ranking, selected, top.name, "", significance, "named")


def standing(significance: float) -> str:
    """``4.5 standard deviations above`` (or ``below``: chi2 under its expectation, a log
    smoother than its stated noise)."""
    side = "above" if significance >= 0 else "below"
    return f"{abs(significance):.1f} standard deviations {side}"


def _significance(y: np.ndarray, noise: np.ndarray) -> float:
    """How far chi2 = sum (y / noise)^2 lies above its expectation n for noise alone, in its
    standard deviations sqrt(2 n)."""
    n = len(y)
    if n == 0:
        return 0.0
    chi2 = float(np.sum((y / np.maximum(noise, 1e-9)) ** 2))
    return (chi2 - n) / np.sqrt(2.0 * n)
