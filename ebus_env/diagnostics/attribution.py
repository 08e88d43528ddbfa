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

* the missing power stands out of the noise: chi-square of the windows' missing power in
  noise units lies ``MIN_SIGNIFICANCE`` standard deviations above its value for noise alone;
* the effect explains at least ``MIN_EXPLAINED`` of it, ``MIN_MARGIN`` more than the
  runner-up;
* it still adds ``MIN_GAIN`` when a parameter of the model explains as much on its own (else
  a mis-set parameter, not a missing effect, is the simpler explanation).

Otherwise no missing effect is supported by the data.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

MIN_EXPLAINED = 0.3
MIN_MARGIN = 0.05
MIN_SIGNIFICANCE = 3.0
MIN_GAIN = 0.05
TIE = 0.01  # held-out shares this close are equal
HUBER_C = 3.0  # noise units: a window this far off is an outlier (a driver's action, a glitch)


@dataclass
class Attribution:
    name: str
    kind: str
    explained: float  # held-out share of the missing power
    scale: float  # beta: the candidate's strength relative to its signature
    estimate: dict = field(default_factory=dict)  # parameter -> value, for the verdict


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


def _least_squares(a: np.ndarray, b: np.ndarray, nonneg: np.ndarray) -> np.ndarray:
    """min |a beta - b| with beta >= 0 where asked: a column whose coefficient comes out
    negative is held at 0 (the most negative first) and the rest re-solved. Exact for one
    constrained column, the case of every attribution fit but stepwise ones."""
    free = np.ones(a.shape[1], bool)
    while True:
        beta = np.zeros(a.shape[1])
        beta[free] = np.linalg.lstsq(a[:, free], b, rcond=None)[0]
        bad = np.where(nonneg & free & (beta < 0), beta, 0.0)
        if not bad.any():
            return beta
        free[np.argmin(bad)] = False


def _fit(x: np.ndarray, y: np.ndarray, w: np.ndarray, nonneg: np.ndarray,
         iterations: int = 50) -> np.ndarray:
    """Weighted robust (Huber) least squares, coefficients >= 0 where asked: iteratively
    re-weighted least squares (Huber's weights min(1, c/|r|)), which converges to the
    minimum of the convex Huber loss."""
    sw = np.sqrt(w)
    a, b = x * sw[:, None], y * sw
    beta = _least_squares(a, b, nonneg)
    for _ in range(iterations):
        r = np.abs(a @ beta - b)
        u = np.sqrt(np.minimum(1.0, HUBER_C / np.maximum(r, 1e-300)))
        new = _least_squares(a * u[:, None], b * u, nonneg)
        if np.max(np.abs(new - beta)) <= 1e-7 * (np.max(np.abs(beta)) + 1e-12):
            return new
        beta = new
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


def _loss(x: np.ndarray, y: np.ndarray, w: np.ndarray, nonneg: np.ndarray) -> tuple[
        float, np.ndarray]:
    """Huber loss of the best fit of y by the columns of x, and the coefficients."""
    beta = _fit(x, y, w, nonneg)
    return float(np.sum(huber(np.sqrt(w) * (y - x @ beta)))), beta


def held_out_best(variants: np.ndarray, y: np.ndarray, w: np.ndarray, nonneg: bool,
                  folds: int, nuisance: np.ndarray | None = None) -> tuple[float, int, float]:
    """Held-out share of y explained by one of several signatures (rows of ``variants``: an
    effect at several strengths) together with the ``nuisance`` columns (parameters free to
    re-adjust), the variant that fits the training folds best chosen in each fold. Returns
    the share, the variant that fits all windows best and its coefficient."""
    extra = np.zeros((len(y), 0)) if nuisance is None else nuisance
    signs = np.array([nonneg] + [False] * extra.shape[1])
    sw = np.sqrt(w)

    def fits(rows):
        return [_loss(np.column_stack([v[rows], extra[rows]]), y[rows], w[rows], signs)
                for v in variants]

    lost = total = 0.0
    for test in folds_of(len(y), folds):
        train = np.setdiff1d(np.arange(len(y)), test)
        if len(train) < len(signs) + 1:
            continue
        trained = fits(train)
        k = int(np.argmin([f[0] for f in trained]))
        pred = np.column_stack([variants[k][test], extra[test]]) @ trained[k][1]
        lost += float(np.sum(huber(sw[test] * (y[test] - pred))))
        total += float(np.sum(huber(sw[test] * y[test])))
    everything = fits(np.arange(len(y)))
    chosen = int(np.argmin([f[0] for f in everything]))
    return (1.0 - lost / total if total > 0 else 0.0), chosen, float(everything[chosen][1][0])


def _score(by_name, names: list[str], y, w, usable, folds) -> float:
    """Held-out share of y that the candidates ``names`` explain together."""
    x = np.column_stack([by_name[n].signature_w[usable] for n in names])
    nonneg = np.array([by_name[n].kind != "parameter" for n in names])
    return held_out_explained(x, y, w, nonneg, folds)


def _gain(by_name, base: list[str], extra: str, y, w, usable, folds) -> float:
    """Held-out share that ``extra`` adds to the candidates ``base``."""
    return _score(by_name, base + [extra], y, w, usable, folds) - _score(by_name, base, y, w,
                                                                         usable, folds)


def attribute(missing_w: np.ndarray, noise_w: np.ndarray, candidates, usable: np.ndarray,
              folds: int = 5, nuisance: tuple[str, ...] = ()):
    """Score every candidate alone, select a sparse set, and decide the verdict.

    ``nuisance`` names parameter candidates fitted along with every effect: after a
    calibration, the calibrated parameters have absorbed part of a missing effect, and adding
    the effect lets them move back.

    Returns (ranking of single candidates best first, selected names, verdict name or None,
    why, significance of the missing power in standard deviations)."""
    y = missing_w[usable]
    w = weights(noise_w[usable])
    significance = _significance(y, noise_w[usable])
    by_name = {c.name: c for c in candidates}
    nuisance = tuple(n for n in nuisance if n in by_name)
    extra = np.column_stack([by_name[n].signature_w[usable] for n in nuisance]) \
        if nuisance else None
    ranking = []
    for c in candidates:
        effect = c.kind != "parameter"
        explained, c.chosen, scale = held_out_best(c.signatures_w[:, usable], y, w, effect,
                                                   folds, extra if effect else None)
        ranking.append(Attribution(c.name, c.kind, explained, scale))
    ranking.sort(key=lambda a: -a.explained)
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
    verdict, why = None, ""
    if significance < MIN_SIGNIFICANCE:
        why = (f"the missing power is at the noise level ({significance:.1f} standard deviations "
               "above it): the model explains these data")
    elif not effects or effects[0].explained < MIN_EXPLAINED:
        top = f" (best: {effects[0].name}, {100 * effects[0].explained:.0f} %)" if effects else ""
        why = ("no registered effect explains the missing power on held-out windows" + top
               + "; see the clues for what kind of effect to write")
    elif len(effects) > 1 and effects[0].explained - effects[1].explained < MIN_MARGIN:
        why = (f"{effects[0].name} and {effects[1].name} explain the missing power about "
               f"equally ({100 * effects[0].explained:.0f} and "
               f"{100 * effects[1].explained:.0f} %): the data cannot tell them apart")
    elif nuisance and effects[0].explained - _score(by_name, list(nuisance), y, w, usable,
                                                    folds) < MIN_GAIN:
        why = (f"{effects[0].name} explains hardly more than re-adjusting the calibrated "
               "parameters does")
    elif params and params[0].explained >= effects[0].explained - TIE and _gain(
            by_name, [params[0].name], effects[0].name, y, w, usable, folds) < MIN_GAIN:
        why = (f"the parameter {params[0].name} explains the missing power as well "
               f"({100 * params[0].explained:.0f} %, {effects[0].name} "
               f"{100 * effects[0].explained:.0f} %): a mis-set parameter is the simpler "
               "explanation; calibrate it (--calibrate) before adding an effect")
    else:
        verdict = effects[0].name
    return ranking, selected, verdict, why, significance


def _significance(y: np.ndarray, noise: np.ndarray) -> float:
    """How far chi2 = sum (y / noise)^2 lies above its expectation n for noise alone, in its
    standard deviations sqrt(2 n)."""
    n = len(y)
    if n == 0:
        return 0.0
    chi2 = float(np.sum((y / np.maximum(noise, 1e-9)) ** 2))
    return (chi2 - n) / np.sqrt(2.0 * n)
