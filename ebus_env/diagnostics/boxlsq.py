"""Many small bounded least-squares re-fits that share one matrix: the calibrated parameters'
re-fit in every bootstrap draw and at every strength of a candidate
(:func:`~ebus_env.diagnostics.candidates.estimate_strength`).

Each fit is the convex problem::

    SSE[d, g] = min_{|x_j| <= b}  sum_i c_di (r_gi - (A x)_i)^2

with A the (windows, columns) matrix, r_g one residual, c_d one draw's window counts. On its
normal equations, G_d = A' C_d A and h_dg = A' C_d r_g, it is a box-constrained quadratic
program, and a point is its minimum exactly when it satisfies the Karush-Kuhn-Tucker conditions
(Nocedal & Wright, *Numerical Optimization*, 2nd ed., ch. 12 and 16). The bounds bind alike in
nearly every draw: each residual's active set, taken from its unit-weight fit, starts
primal-dual active-set iterations over all draws at once (batched linear solves), and a draw's
solution is kept only where the conditions hold; the rest go to bounded-variable least squares
(scipy's BVLS, Stark & Parker 1995, Comput. Stat. 10, 129-141).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import lsq_linear

KKT_TOL = 1e-9  # of the gradient's scale: a condition this close holds


def _bvls(a: np.ndarray, r: np.ndarray, c: np.ndarray, bound: float) -> float:
    """The weighted SSE of one fit by BVLS (the exact reference)."""
    root = np.sqrt(c)
    x = lsq_linear(a * root[:, None], r * root, bounds=(-bound, bound), method="bvls").x
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
        x0 = lsq_linear(a, r, bounds=(-bound, bound), method="bvls").x
        side = np.where(np.abs(x0) >= bound * (1 - 1e-9), np.sign(x0), 0.0)
        x, grad = _active_set(gram, cross[:, g, :], diag, np.broadcast_to(
            side, (len(counts), n)).copy(), bound)
        # the KKT conditions, from x alone: zero gradient where free, pointing out at a bound
        upper, lower, tol = x >= bound * (1 - 1e-12), x <= -bound * (1 - 1e-12), scale[:, None]
        ok = np.all(np.abs(x) <= bound * (1 + 1e-12), axis=1) & np.all(np.where(
            upper, grad <= tol, np.where(lower, grad >= -tol, np.abs(grad) <= tol)), axis=1)
        rr = r - x[ok] @ a.T
        out[ok, g] = np.einsum("dm,dm->d", counts[ok], rr * rr)
        for d in np.flatnonzero(~ok):
            out[d, g] = _bvls(a, r, counts[d], bound)
    return out


def _active_set(gram, h, diag, side, bound, iterations: int = 8):
    """Primal-dual active-set iterations (Hintermueller, Ito & Kunisch 2002, SIAM J. Optim. 13,
    865-888) for min x'Gx/2 - h'x within +-bound, every draw at once from the guess ``side``
    (+1 at the upper bound, -1 at the lower, 0 free): solve with the bound variables held,
    then move each variable to the side its multiplier asks for, until no set changes. Returns
    x and G x - h; the caller checks the KKT conditions."""
    eye = np.eye(gram.shape[1])
    ridge = 1e-14 * np.abs(gram).max(axis=(1, 2))[:, None, None] * eye  # collinear columns
    for _ in range(iterations):
        free = side == 0
        both = free[:, :, None] & free[:, None, :]
        held = side * bound
        system = np.where(both, gram + ridge, eye)
        rhs = np.where(free, h - np.einsum("dij,dj->di", gram, held), held)
        try:
            x = np.linalg.solve(system, rhs[..., None])[..., 0]
        except np.linalg.LinAlgError:  # a draw without information: every draw to BVLS
            return np.full_like(h, np.nan), np.full_like(h, np.nan)
        grad = np.einsum("dij,dj->di", gram, x) - h
        multiplier = np.where(free, 0.0, -grad)  # > 0 pushes up, < 0 down
        trial = x + multiplier / diag
        new = np.where(trial > bound, 1.0, np.where(trial < -bound, -1.0, 0.0))
        if np.array_equal(new, side):
            break
        side = new
    return x, grad
