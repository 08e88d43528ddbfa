"""Small bounded least-squares fits, exact and fast: many re-fits that share one matrix (the
calibrated parameters' re-fit in every bootstrap draw and at every strength of a candidate,
:func:`~ebus_env.diagnostics.candidates.estimate_strength`), and one fit at a time warm-started
from the bounds that held in the fit before (:func:`bounded_lstsq`: the reweighting steps of a
robust fit, :mod:`~ebus_env.diagnostics.attribution`).

Each fit is the convex problem::

    SSE[d, g] = min_{|x_j| <= b}  sum_i c_di (r_gi - (A x)_i)^2

with A the (windows, columns) matrix, r_g one residual, c_d one draw's window counts. On its
normal equations, G_d = A' C_d A and h_dg = A' C_d r_g, it is a box-constrained quadratic
program, and a point is its minimum exactly when it satisfies the Karush-Kuhn-Tucker conditions
(Nocedal & Wright, *Numerical Optimization*, 2nd ed., ch. 12 and 16). The bounds bind alike in
nearly every draw: each residual's active set, taken from its unit-weight fit, starts
primal-dual active-set iterations over all draws at once (batched linear solves), and a draw's
solution is kept only where the conditions hold; the rest go to bounded-variable least squares
(scipy's BVLS, Stark & Parker 1995, Comput. Stat. 10, 129-141), on the problem's R factor
(:func:`bvls`).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import lsq_linear

KKT_TOL = 1e-9  # of the gradient's scale: a condition this close holds


def bvls(a: np.ndarray, b: np.ndarray, low, high) -> np.ndarray:
    """min ||a x - b|| with low <= x <= high by BVLS. A tall ``a`` (windows or seconds by a few
    columns) is first reduced to its R factor: with [a b] = Q [R z], ||a x - b||^2 = ||R x -
    z||^2 for every x (Q is orthonormal), so the bounded minimum is the same while each of
    BVLS's inner least-squares solves is (columns + 1) rows long, not (windows) rows."""
    if a.shape[0] > 2 * (a.shape[1] + 1):
        rz = np.linalg.qr(np.column_stack([a, b]), mode="r")
        a, b = rz[:, :-1], rz[:, -1]
    return lsq_linear(a, b, bounds=(low, high), method="bvls").x


def _bvls(a: np.ndarray, r: np.ndarray, c: np.ndarray, bound: float) -> float:
    """The weighted SSE of one fit by BVLS (the exact reference)."""
    root = np.sqrt(c)
    x = bvls(a * root[:, None], r * root, -bound, bound)
    rr = r - a @ x
    return float(c @ (rr * rr))


def refit_sse(a: np.ndarray, residuals: np.ndarray, counts: np.ndarray,
              bound: float) -> np.ndarray:
    """(draws, residuals) weighted SSE after the best re-fit of the columns of ``a`` within
    +-``bound`` (see the module docstring): ``residuals`` (G, windows), ``counts`` (D,
    windows)."""
    residuals = np.atleast_2d(residuals)
    counts = np.atleast_2d(counts)
    n = a.shape[1]
    if n == 0:
        return counts @ (residuals * residuals).T
    out = np.empty((len(counts), len(residuals)))
    gram = np.einsum("dm,mi,mj->dij", counts, a, a)  # (D, n, n)
    cross = np.einsum("dm,mi,gm->dgi", counts, a, residuals)  # (D, G, n)
    diag = np.maximum(np.einsum("dii->di", gram), 1e-300)
    scale = KKT_TOL * (np.abs(cross).max(axis=(1, 2)) + np.abs(gram).max(axis=(1, 2)) * bound)
    for g, r in enumerate(residuals):
        x0 = bvls(a, r, -bound, bound)
        side = np.where(np.abs(x0) >= bound * (1 - 1e-9), np.sign(x0), 0.0)
        x, grad = _active_set(gram, cross[:, g, :], diag, np.broadcast_to(
            side, (len(counts), n)).copy(), -bound, bound)
        ok = _kkt(x, grad, -bound, bound, scale[:, None])
        rr = r - x[ok] @ a.T
        out[ok, g] = np.einsum("dm,dm->d", counts[ok], rr * rr)
        for d in np.flatnonzero(~ok):
            out[d, g] = _bvls(a, r, counts[d], bound)
    return out


def bounded_lstsq(a: np.ndarray, b: np.ndarray, low: np.ndarray, high: np.ndarray,
                  side: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """min ||a x - b|| with low <= x <= high (bounds may be infinite), and the bound each
    coefficient sits at (+1 upper, -1 lower, 0 free), to warm-start the next fit of a similar
    problem (``side``; default: none binds). Primal-dual active-set steps (as
    :func:`_active_set`, for one problem) from that guess; a solution that breaks the KKT
    conditions goes to BVLS, so the answer is always the convex problem's minimum."""
    gram, h = a.T @ a, a.T @ b
    n = len(h)
    if n == 1 and gram[0, 0] > 0:  # one coefficient: the unbounded one, clipped
        x = np.clip(h / gram[0], low, high)
        return x, np.where(x >= high, 1.0, np.where(x <= low, -1.0, 0.0))
    side = np.zeros(n) if side is None else side
    ridge = 1e-14 * np.abs(gram).max(initial=0.0) * np.eye(n)  # collinear columns
    x = grad = None
    for _ in range(8):
        free = side == 0
        x = np.where(side > 0, high, np.where(side < 0, low, 0.0))
        try:
            if free.all():
                x = np.linalg.solve(gram + ridge, h)
            elif free.any():
                x[free] = np.linalg.solve((gram + ridge)[np.ix_(free, free)],
                                          h[free] - gram[np.ix_(free, ~free)] @ x[~free])
        except np.linalg.LinAlgError:
            x = None
            break
        grad = gram @ x - h
        trial = np.where(free, x, x - grad / np.maximum(np.diag(gram), 1e-300))
        new = np.where(trial > high, 1.0, np.where(trial < low, -1.0, 0.0))
        if np.array_equal(new, side):
            break
        side = new
    if x is None or not _kkt(x[None], grad[None], low, high, KKT_TOL * (
            np.abs(h).max(initial=0.0) + np.abs(gram).max(initial=0.0)
            * np.abs(x).max(initial=1.0)))[0]:
        x = bvls(a, b, low, high)
    return x, np.where(x >= high, 1.0, np.where(x <= low, -1.0, 0.0))


def _kkt(x, grad, low, high, tol) -> np.ndarray:
    """Per draw: x within its bounds and the KKT conditions hold, from x and the gradient
    G x - h alone: zero where free, pointing out of the box at a bound."""
    with np.errstate(invalid="ignore"):  # inf - inf at an infinite bound: never at it
        upper = x >= high - 1e-12 * np.abs(high)
        lower = x <= low + 1e-12 * np.abs(low)
    inside = (x <= high + 1e-12 * np.abs(high)) & (x >= low - 1e-12 * np.abs(low))
    return np.all(inside & np.where(upper, grad <= tol, np.where(
        lower, grad >= -tol, np.abs(grad) <= tol)), axis=1)


def _active_set(gram, h, diag, side, low, high, iterations: int = 8):
    """Primal-dual active-set iterations (Hintermueller, Ito & Kunisch 2002, SIAM J. Optim. 13,
    865-888) for min x'Gx/2 - h'x within [low, high], every draw at once from the guess
    ``side`` (+1 at the upper bound, -1 at the lower, 0 free): solve with the bound variables
    held, then move each variable to the side its multiplier asks for, until no set changes.
    Returns x and G x - h; the caller checks the KKT conditions."""
    eye = np.eye(gram.shape[1])
    ridge = 1e-14 * np.abs(gram).max(axis=(1, 2))[:, None, None] * eye  # collinear columns
    for _ in range(iterations):
        free = side == 0
        both = free[:, :, None] & free[:, None, :]
        held = np.where(side > 0, high, np.where(side < 0, low, 0.0))
        system = np.where(both, gram + ridge, eye)
        rhs = np.where(free, h - np.einsum("dij,dj->di", gram, held), held)
        try:
            x = np.linalg.solve(system, rhs[..., None])[..., 0]
        except np.linalg.LinAlgError:  # a draw without information: every draw to BVLS
            return np.full_like(h, np.nan), np.full_like(h, np.nan)
        grad = np.einsum("dij,dj->di", gram, x) - h
        multiplier = np.where(free, 0.0, -grad)  # > 0 pushes up, < 0 down
        trial = x + multiplier / diag
        new = np.where(trial > high, 1.0, np.where(trial < low, -1.0, 0.0))
        if np.array_equal(new, side):
            break
        side = new
    return x, grad
