"""The ceiling (``benchmarks/ceiling.py``): its windows, its fit and its standard errors by
hand, and a day of the truth simulator read through it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

ceiling = pytest.importorskip("benchmarks.ceiling", reason="benchmarks/ not in this checkout")


def test_windows_are_means_or_changes_over_whole_windows():
    values = np.arange(10.0)
    assert np.array_equal(ceiling.windows(values, 4, False), [1.5, 5.5])  # the rest dropped
    assert np.array_equal(ceiling.windows(values, 4, True), [3.0, 3.0])


def test_newey_west_is_the_ols_covariance_for_white_residuals_without_lags():
    """With no lags Newey-West is White's covariance; with residuals of one size it is the
    OLS covariance times n / (n - k) apart (here the same sum of squares)."""
    rng = np.random.default_rng(0)
    x = np.column_stack((np.ones(50), rng.normal(size=50)))
    resid = np.where(rng.random(50) < 0.5, -1.0, 1.0)
    white = ceiling.newey_west(x, resid, lags=0)
    assert white == pytest.approx(np.linalg.inv(x.T @ x))
    # lags add the residuals' autocovariance: positively correlated residuals widen it
    runs = np.repeat([1.0, -1.0], 25)
    assert ceiling.newey_west(x, runs, 4)[1, 1] > ceiling.newey_west(x, runs, 0)[1, 1]


def test_the_fit_finds_a_signature_the_basis_cannot_make_and_not_one_it_can():
    rng = np.random.default_rng(1)
    n = 400
    basis = np.column_stack((np.ones(n), np.linspace(0.0, 1.0, n)))
    effect = np.sin(np.linspace(0.0, 12.0, n))
    noise = rng.normal(0.0, 0.1, n)
    y = basis @ [0.3, -0.2] + 0.05 * effect + noise
    found = ceiling.fit(y, basis, effect)
    # SNR ~ 0.05 / (0.1 / sqrt(n / 2)) ~ 7
    assert 4.0 < found["snr"] < 11.0
    absent = ceiling.fit(basis @ [0.3, -0.2] + noise, basis, effect)
    assert abs(absent["snr"]) < 3.0
    assert found["rss"] == pytest.approx(absent["rss"], rel=0.05)
    # a constant load beside a constant base: not identifiable, SNR 0
    assert ceiling.fit(y, basis, 2.0 * np.ones(n))["snr"] == 0.0


def test_a_bms_log_holds_what_its_power_or_its_voltage_holds():
    """A day separable in the voltage only is separable on the BMS log, at the voltage's SNR;
    a control day's largest SNR is the larger of the two signals'."""
    power = {"windows": 60, "max_other_snr": 1.2}  # the pack effect leaves the power alone
    volt = {"windows": 60, "max_other_snr": 0.4, "snr": 36.0, "margin": 50.0, "fall": 0.9,
            "separable": True}
    row = ceiling.with_either({"source": "truthsim", "bms": power, "volt": volt})
    either = row[ceiling.EITHER]
    assert either["separable"] and either["snr"] == 36.0 and either["max_other_snr"] == 1.2
    weak = dict(volt, snr=2.0, separable=False)
    assert not ceiling.with_either({"bms": power, "volt": weak})[ceiling.EITHER]["separable"]
    assert ceiling.EITHER not in ceiling.with_either({"soc": power})  # a SoC log: nothing


@pytest.mark.slow
def test_a_cold_pack_the_power_does_not_show_is_separable_in_the_voltage():
    """The truth simulator's drive asks for a power, so its cold pack moves the pack's
    current and voltage but hardly their product: on the first 3 h of its cold-battery day 02
    the power has no signature of it, while the logged voltage holds it far above 3 and
    better than every candidate of another library effect."""
    source = ceiling.Source("truthsim")
    cold = [c for c in ceiling.cases_of(source, False, 3, 0, ("cold_battery",))
            if c.hidden == "cold_battery"][2]
    row = ceiling.ceiling_day(("truthsim", dataclasses.replace(cold, hours=3.0), None))
    assert "snr" not in row["bms"]
    assert row["volt"]["separable"] and row["volt"]["snr"] > 10.0
    assert row["volt"]["margin"] > ceiling.SEPARATION


@pytest.mark.slow
def test_a_grade_day_is_separable_on_its_bms_log_and_a_control_day_has_no_effect():
    """The truth simulator's first grade day, its last hour: the grade's SNR on the BMS log
    is far above 3, it beats every other candidate and removes most of the missing power
    the bus's parameters leave; the SoC log's 12 windows are too few for every parameter
    free, so nothing is claimed. Its first control day, its last 3 h (the smoke days'): no
    candidate reaches 3 in the power, the voltage or the SoC."""
    source = ceiling.Source("truthsim")
    listed = ceiling.cases_of(source, False, 1, 1)
    grade = next(c for c in listed if c.hidden == "road_grade")
    control = next(c for c in listed if c.hidden is None)
    graded = ceiling.ceiling_day(("truthsim", dataclasses.replace(
        grade, start_clock_h=grade.start_clock_h + grade.hours - 1.0, hours=1.0), None))
    assert graded["bms"]["separable"] and graded["bms"]["snr"] > 30.0
    assert 0.5 < graded["bms"]["fall"] <= 1.0
    assert graded["soc"]["windows"] == 12 and "snr" not in graded["soc"]
    quiet = ceiling.ceiling_day(("truthsim", dataclasses.replace(
        control, start_clock_h=control.start_clock_h + control.hours - ceiling.SMOKE_HOURS,
        hours=ceiling.SMOKE_HOURS), None))
    for kind in ("bms", "volt", "soc"):
        assert "snr" not in quiet[kind] and quiet[kind]["max_other_snr"] < 3.0, quiet
