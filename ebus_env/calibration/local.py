"""Local refinement: Levenberg-Marquardt on the SoC residuals, from several starts at once."""

from __future__ import annotations

import numpy as np

from ebus_env.calibration.problem import CalibrationProblem


def distinct_starts(x: np.ndarray, cost: np.ndarray, k: int = 4, min_distance: float = 0.25,
                    within: float = 3.0) -> np.ndarray:
    """Up to ``k`` good points at least ``min_distance`` apart (normalised, max-norm), best
    first, among those costing at most ``within`` times the best: starts for polishing."""
    order = np.argsort(cost, kind="stable")
    chosen: list[int] = []
    for i in order:
        if not np.isfinite(cost[i]) or cost[i] > within * cost[order[0]]:
            break
        if all(np.max(np.abs(x[i] - x[j])) >= min_distance for j in chosen):
            chosen.append(i)
            if len(chosen) == k:
                break
    return x[chosen]


def polish(problem: CalibrationProblem, starts: np.ndarray, iterations: int = 12,
           step: float = 0.01) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Levenberg-Marquardt on the SoC residuals from several starts at once.

    All starts advance in lock-step: per iteration one batched run gives every start's
    forward-difference Jacobian, and a second tries three damping values per start. Steps are
    projected onto the unit box. Returns (points, their NRMSE, their Jacobians)."""
    u = np.clip(np.atleast_2d(starts).astype(float), 0.0, 1.0)
    k, d = u.shape
    r = problem.residuals(u)
    f = np.sqrt(np.sum(r * r, axis=1))
    damping = np.full(k, 1e-3)
    jac = np.zeros((k, r.shape[1], d))
    factors = np.array([0.1, 1.0, 10.0])

    def jacobians(u: np.ndarray, r: np.ndarray) -> np.ndarray:
        signs = np.where(u + step <= 1.0, 1.0, -1.0)  # (k, d)
        shifted = (u[:, None, :] + np.eye(d)[None] * (signs * step)[:, :, None]).reshape(-1, d)
        rs = problem.residuals(shifted).reshape(k, d, -1)
        return np.transpose((rs - r[:, None, :]) / (signs * step)[:, :, None], (0, 2, 1))

    for _ in range(iterations):
        jac = jacobians(u, r)
        trials = np.zeros((k, len(factors), d))
        for i in range(k):
            jtj = jac[i].T @ jac[i]
            g = jac[i].T @ r[i]
            scale = np.diag(jtj) + 1e-12
            for j, factor in enumerate(factors):
                lam = damping[i] * factor
                delta = np.linalg.solve(jtj + lam * np.diag(scale), -g)
                trials[i, j] = np.clip(u[i] + delta, 0.0, 1.0)
        rt = problem.residuals(trials.reshape(-1, d)).reshape(k, len(factors), -1)
        ft = np.sqrt(np.sum(rt * rt, axis=2))
        best = np.argmin(ft, axis=1)
        improved = ft[np.arange(k), best] < f * (1 - 1e-6)
        moved = 0.0
        for i in np.flatnonzero(improved).tolist():
            moved = max(moved, float(np.max(np.abs(trials[i, best[i]] - u[i]))))
            u[i], r[i], f[i] = trials[i, best[i]], rt[i, best[i]], ft[i, best[i]]
            damping[i] *= factors[best[i]] / 3.0
        damping[~improved] *= 10.0
        if not improved.any() or moved < 1e-5:
            break
    return u, f, jacobians(u, r)
