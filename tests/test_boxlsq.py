"""The bounded least-squares fits equal scipy's bounded-variable least squares (BVLS): the
batched re-fit draw by draw, and one fit at a time from any warm start."""

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


def _bvls_x(a, b, low, high):
    return lsq_linear(a, b, bounds=(low, high), method="bvls").x


def test_one_fit_equals_bvls_from_any_warm_start():
    """Mixed bounds (>= 0, a box, none) on nearly collinear columns: the same minimum as BVLS,
    cold, warm-started from the fit's own bounds, and from a wrong guess; the bounds it
    reports are the ones the solution sits at."""
    rng = np.random.default_rng(6)
    for trial in range(80):
        n, k = int(rng.integers(12, 120)), int(rng.integers(1, 8))
        a = rng.normal(size=(n, k)) * rng.uniform(0.1, 1e3, k)
        if k > 1:
            a[:, 1] = a[:, 0] * 0.95 + 0.05 * a[:, 1]
        b = a @ rng.normal(0, 3, k) + rng.normal(0, 1, n) * a.std()
        low = np.where(rng.random(k) < 0.4, 0.0, np.where(rng.random(k) < 0.5, -1.0, -np.inf))
        high = np.where(np.isfinite(low) & (low < 0), 1.0, np.inf)
        ref = _bvls_x(a, b, low, high)
        cost = np.sum((a @ ref - b) ** 2)
        x, side = boxlsq.bounded_lstsq(a, b, low, high)
        for guess in (side, -side, rng.integers(-1, 2, k).astype(float)):
            y, again = boxlsq.bounded_lstsq(a, b, low, high, guess * np.isfinite(
                np.where(guess > 0, high, low)))
            assert np.sum((a @ y - b) ** 2) <= cost * (1 + 1e-9) + 1e-12, trial
            np.testing.assert_array_equal(again, side)
        np.testing.assert_allclose(x, ref, rtol=1e-6, atol=1e-9 * np.abs(ref).max())
        assert np.all(x >= low) and np.all(x <= high)
        np.testing.assert_array_equal(side, np.where(x >= high, 1, np.where(x <= low, -1, 0)))


def test_a_fit_the_active_set_cannot_finish_goes_to_bvls(monkeypatch):
    rng = np.random.default_rng(7)
    a, b = rng.normal(size=(30, 4)), rng.normal(size=30) * 5
    low, high = np.array([0.0, -0.1, -np.inf, 0.0]), np.array([np.inf, 0.1, np.inf, np.inf])
    monkeypatch.setattr(boxlsq, "_active_set", lambda gram, h, *_: (np.zeros_like(h), -h))
    x, _ = boxlsq.bounded_lstsq(a, b, low, high)
    np.testing.assert_allclose(x, _bvls_x(a, b, low, high), rtol=1e-12)


def test_bvls_on_the_r_factor_finds_the_full_problems_minimum():
    """A day's seconds by a few columns, two of them nearly collinear, bounds that bind: BVLS
    on the R factor reaches the minimum of BVLS on the whole tall matrix."""
    rng = np.random.default_rng(8)
    for trial in range(20):
        n, k = int(rng.integers(200, 5000)), int(rng.integers(2, 12))
        a = rng.normal(size=(n, k)) * rng.uniform(0.1, 1e3, k)
        a[:, 1] = a[:, 0] * 0.99 + 0.01 * a[:, 1]
        b = a @ rng.normal(0, 3, k) + rng.normal(0, 1, n) * a.std()
        low = np.where(rng.random(k) < 0.5, 0.0, -np.inf)
        high = np.where(rng.random(k) < 0.3, 0.5, np.inf)
        ref = _bvls_x(a, b, low, high)
        x = boxlsq.bvls(a, b, low, high)
        assert np.all(x >= low) and np.all(x <= high)
        cost, best = np.sum((a @ x - b) ** 2), np.sum((a @ ref - b) ** 2)
        assert cost == pytest.approx(best, rel=1e-9), trial
        np.testing.assert_allclose(x, ref, rtol=1e-5, atol=1e-7 * np.abs(ref).max())
