"""Held-out tests: does a candidate effect, beside the bus-to-bus parameters, predict blocks of
the log it was not fitted on better than those parameters alone?

The data are the missing power of ``n`` units (bins of a BMS log, windows of a SoC log), ``y``
[W], with weights ``w`` (1 / variance), the bus-to-bus parameters' linear signatures ``X``
(``n`` x ``p``: the change of the model's power per unit change of each), whose coefficients
stay within ``[low, high]`` (the parameters' search box about their fitted values), and each
candidate's signatures at ``K`` strengths, ``S`` (``K`` x ``n``). The units' blocks are dealt
into :data:`FOLDS` folds; each fold is predicted from a fit on the others::

    null:       y ~ X a                       a in [low, high]
    candidate:  y ~ X a + b S_k               b >= 0, k chosen on the training folds

and each block's held-out loss is ``sum w (y - y_hat)^2`` over its units. A candidate's gain
on block ``j`` is the null's loss there less its own, and its test statistic is the mean gain
over the blocks in units of its standard error (a paired test over blocks, which are far
apart enough to be nearly independent)::

    z = mean(g) / (sd(g) / sqrt(n_blocks))

Strengths are chosen inside the training folds, so the held-out loss pays for the choice.
Every parameter the data can move (the bus-to-bus ones within their whole search box) moves
with the candidate: an effect is credited only with what they cannot take up.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ebus_env.diagnostics.boxlsq import bounded_lstsq
from ebus_env.diagnostics.residual import correlation_time

FOLDS = 5


@dataclass
class Nuisance:
    """The bus-to-bus parameters' columns and the box their coefficients stay in."""

    names: list[str]
    x: np.ndarray  # (n, p)
    low: np.ndarray  # (p,)
    high: np.ndarray  # (p,)

    def with_column(self, name: str, column: np.ndarray, low: float = 0.0,
                    high: float = np.inf) -> Nuisance:
        return Nuisance([*self.names, name], np.column_stack([self.x, column]),
                        np.append(self.low, low), np.append(self.high, high))


@dataclass
class Test:
    """A candidate's held-out test and its fit on all the data."""

    name: str
    z: float  # mean held-out gain over blocks, in standard errors
    gain: float  # share of the null's held-out loss it removes
    block_gain: np.ndarray  # per block: the null's held-out loss less the candidate's
    choice: int  # strength chosen on all the data
    beta: float  # its coefficient there
    coef: np.ndarray  # the bus-to-bus coefficients fitted with it
    fitted: np.ndarray  # y_hat of the fit on all the data (n,)
    loss: float  # weighted loss of that fit
    folds_loss: np.ndarray = field(default_factory=lambda: np.zeros(0))  # per block, held out
    unit: float = 1.0  # the noise unit of its held-out residuals (:func:`noise_unit`)

    @property
    def held_out_loss(self) -> float:
        return float(self.folds_loss.sum())

    @property
    def chi2(self) -> float:
        """The held-out loss it removes, in noise units: ``sum(gain) / unit``."""
        return float(self.block_gain.sum() / self.unit)


def folds_of(block: np.ndarray, folds: int = FOLDS) -> np.ndarray:
    """The fold of each unit: blocks dealt round robin (neighbouring blocks in different
    folds, so every fold spans the day)."""
    _, index = np.unique(block, return_inverse=True)
    return index % folds


def _solve(x: np.ndarray, y: np.ndarray, sw: np.ndarray, low: np.ndarray, high: np.ndarray
           ) -> np.ndarray:
    """Weighted bounded least squares, columns scaled to one for conditioning."""
    a = x * sw[:, None]
    scale = np.sqrt(np.sum(a * a, axis=0))
    scale[scale <= 0.0] = 1.0
    coef, _ = bounded_lstsq(a / scale, y * sw, low * scale, high * scale)
    return coef / scale


def block_losses(residual: np.ndarray, w: np.ndarray, block: np.ndarray) -> np.ndarray:
    _, index = np.unique(block, return_inverse=True)
    return np.bincount(index, w * residual * residual)


def _cross_validated(y, w, nuisance: Nuisance, signatures: np.ndarray | None, block,
                     fold) -> np.ndarray:
    """Held-out prediction of every unit: each fold from a fit on the others (the strength,
    when ``signatures`` are given, chosen on the training units)."""
    sw = np.sqrt(w)
    pred = np.zeros_like(y)
    for f in np.unique(fold):
        train, test = fold != f, fold == f
        if signatures is None:
            coef = _solve(nuisance.x[train], y[train], sw[train], nuisance.low, nuisance.high)
            pred[test] = nuisance.x[test] @ coef
            continue
        best, best_loss = None, np.inf
        for s in signatures:
            x = np.column_stack([nuisance.x, s])
            coef = _solve(x[train], y[train], sw[train], np.append(nuisance.low, 0.0),
                          np.append(nuisance.high, np.inf))
            r = y[train] - x[train] @ coef
            loss = float(np.sum(w[train] * r * r))
            if loss < best_loss:
                best, best_loss = (x, coef), loss
        x, coef = best
        pred[test] = x[test] @ coef
    return pred


def fit_all(y, w, nuisance: Nuisance, signatures: np.ndarray | None = None
            ) -> tuple[int, float, np.ndarray, np.ndarray, float]:
    """The fit on all the data: (strength chosen, its coefficient, the bus-to-bus
    coefficients, y_hat, weighted loss)."""
    sw = np.sqrt(w)
    if signatures is None:
        coef = _solve(nuisance.x, y, sw, nuisance.low, nuisance.high)
        fitted = nuisance.x @ coef
        return -1, 0.0, coef, fitted, float(np.sum(w * (y - fitted) ** 2))
    best = None
    for k, s in enumerate(signatures):
        x = np.column_stack([nuisance.x, s])
        coef = _solve(x, y, sw, np.append(nuisance.low, 0.0), np.append(nuisance.high, np.inf))
        fitted = x @ coef
        loss = float(np.sum(w * (y - fitted) ** 2))
        if best is None or loss < best[4]:
            best = (k, float(coef[-1]), coef[:-1], fitted, loss)
    return best


class HeldOut:
    """The null (bus-to-bus parameters alone) cross-validated once; candidates tested against
    it (:meth:`test`)."""

    def __init__(self, y: np.ndarray, w: np.ndarray, nuisance: Nuisance, block: np.ndarray,
                 folds: int = FOLDS):
        self.y, self.w, self.nuisance, self.block = y, w, nuisance, block
        self.fold = folds_of(block, folds)
        self.null_pred = _cross_validated(y, w, nuisance, None, block, self.fold)
        self.null_blocks = block_losses(y - self.null_pred, w, block)
        _, _, self.null_coef, self.null_fitted, self.null_loss = fit_all(y, w, nuisance)


    @property
    def n_blocks(self) -> int:
        return len(self.null_blocks)

    def test(self, name: str, signatures: np.ndarray) -> Test:
        """Held-out test of a candidate with ``signatures`` (K, n)."""
        pred = _cross_validated(self.y, self.w, self.nuisance, signatures, self.block,
                                self.fold)
        own = block_losses(self.y - pred, self.w, self.block)
        gain = self.null_blocks - own
        k, beta, coef, fitted, loss = fit_all(self.y, self.w, self.nuisance, signatures)
        return Test(name, paired_z(gain), float(gain.sum() / max(self.null_blocks.sum(), 1e-300)),
                    gain, k, beta, coef, fitted, loss, own, noise_unit(self.y - pred, self.w))


def noise_unit(residual: np.ndarray, w: np.ndarray) -> float:
    """What one unit of the held-out loss is worth: the weighted residuals' mean square (the
    weights may be off by a common factor) times their correlation time (neighbouring units
    are not independent draws). Taken from the residuals of the model with the candidate, so
    that a large effect does not inflate the noise it is measured against."""
    r = residual * np.sqrt(w)
    return float(np.mean(r * r)) * correlation_time(r, max_lag=200)


def paired_z(gain: np.ndarray) -> float:
    """Mean over blocks in units of its standard error (0 when there is no spread)."""
    if len(gain) < 2:
        return 0.0
    se = float(np.std(gain, ddof=1)) / np.sqrt(len(gain))
    return float(np.mean(gain) / se) if se > 0 else 0.0


def margin(first: Test, second: Test) -> float:
    """How much better ``first`` predicts the held-out blocks than ``second``, in ``first``'s
    noise units (negative: worse)."""
    return (second.held_out_loss - first.held_out_loss) / first.unit
