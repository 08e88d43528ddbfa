"""The batched bounded re-fit equals one bounded-variable least-squares fit per draw."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from ebus_env.diagnostics import boxlsq


def _reference(a, residuals, counts, bound):
    out = np.empty((len(counts), len(residuals)))
    for d, c in enumerate(counts):
        root = np.sqrt(c)
        for g, r in enumerate(residuals):
            x = lsq_linear(a * root[:, None], r * root, bounds=(-bound, bound), method="bvls").x
            out[d, g] = c @ (r - a @ x) ** 2
    return out


def _problem(seed, windows=60, columns=8, residuals=6, draws=50):
    """Bootstrap-like counts, two nearly collinear columns, residuals large enough that the
    bounds bind on some columns and not on others."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(windows, columns))
    a[:, 1] = a[:, 0] + 1e-4 * rng.normal(size=windows)
    residuals = a @ rng.uniform(-2.0, 2.0, columns) + rng.normal(size=(residuals, windows))
    return a, residuals, rng.poisson(1.0, size=(draws, windows)).astype(float)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_batched_refit_equals_bvls_draw_by_draw(seed):
    a, residuals, counts = _problem(seed)
    sse = boxlsq.refit_sse(a, residuals, counts, 1.0)
    assert sse == pytest.approx(_reference(a, residuals, counts, 1.0), rel=1e-9)
    free = boxlsq.refit_sse(a, residuals, counts, 1e6)  # no bound binds: plain least squares
    assert np.all(free <= sse + 1e-9)


def test_draws_where_the_active_set_fails_go_to_bvls(monkeypatch):
    """A solution that breaks the KKT conditions is never kept: with the active-set step made
    useless, every draw is solved by BVLS and the result is unchanged."""
    a, residuals, counts = _problem(3, draws=10)
    monkeypatch.setattr(boxlsq, "_active_set",
                        lambda gram, h, *_: (np.zeros_like(h), -h))
    assert boxlsq.refit_sse(a, residuals, counts, 1.0) == pytest.approx(
        _reference(a, residuals, counts, 1.0), rel=1e-9)


def test_without_columns_the_sse_is_the_weighted_sum_of_squares():
    rng = np.random.default_rng(4)
    residuals, counts = rng.normal(size=(3, 20)), rng.poisson(1.0, size=(5, 20)).astype(float)
    assert boxlsq.refit_sse(np.zeros((20, 0)), residuals, counts, 1.0) == pytest.approx(
        counts @ (residuals**2).T)


def test_columns_without_information_go_to_bvls():
    """All columns zero: the normal equations are singular in every draw; BVLS answers."""
    rng = np.random.default_rng(5)
    residuals, counts = rng.normal(size=(2, 15)), rng.poisson(1.0, size=(4, 15)).astype(float)
    a = np.zeros((15, 3))
    assert boxlsq.refit_sse(a, residuals, counts, 1.0) == pytest.approx(
        counts @ (residuals**2).T)
