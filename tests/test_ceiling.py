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


def _synthetic_bus(monkeypatch, condition, start_day):
    """``ceiling_bus`` on six synthetic days: a bus-to-bus parameter with one coefficient on
    every day, two nuisances per day, a fault (``dragging_brake``) acting from
    ``start_day`` on and a rival (``regen_soc_limit``) that never acts."""
    from types import SimpleNamespace

    rng = np.random.default_rng(7)
    n, days = 200, 6
    t = np.linspace(0.0, 1.0, n)
    signals = []
    for d in range(days):
        moved = rng.normal(size=n).cumsum() / 10.0  # the parameter's day-to-day sensitivity
        nuisance = [rng.normal(size=n), np.ones(n)]
        brake = np.sin(2 * np.pi * (3 + d) * t) + 1.0
        regen = np.cos(2 * np.pi * (5 + d) * t)
        y = 0.5 * moved + 0.3 * nuisance[0] + 0.1 * d + rng.normal(0.0, 0.05, n)
        if condition and d >= start_day:
            y = y + 0.2 * brake
        reading = {"y": y, "moved": {"curb_mass_kg": moved}, "nuisance": nuisance,
                   "signatures": {"dragging_brake": brake, "regen_soc_limit": regen}}
        signals.append(dict.fromkeys(ceiling.WINDOW_S, reading))
    module = SimpleNamespace(
        bus_days=lambda bus: [SimpleNamespace(hours=9.0, day=d) for d in range(days)],
        MULTI_DAY={"dragging_brake": ("outside_library", "from_day")})
    monkeypatch.setattr(ceiling, "Source", lambda name: SimpleNamespace(
        name=name, module=module, bus_effects=("dragging_brake", "regen_soc_limit")))
    monkeypatch.setattr(ceiling, "day_signals", lambda source, case, *args: signals[case.day])
    bus = SimpleNamespace(bus_id="bus_x", condition=condition, start_day=start_day, seed=1)
    return ceiling.ceiling_bus(("truthsim", bus, None))


def test_a_bus_fault_is_read_over_its_days_and_dated_from_its_first_day(monkeypatch):
    """A fault from day 3 stands far above the noise with the bus's parameter shared by its
    days; every start more than a day from the true one fits clearly worse (dated), the best
    start is the true one; a control bus of the same days has no candidate at 3 at any
    start."""
    row = _synthetic_bus(monkeypatch, "dragging_brake", 3)
    reading = row["bms"]
    assert row["days"] == 6 and row["condition_kind"] == "from_day"
    assert reading["separable"] and reading["snr"] > 10.0
    assert reading["best_start"] == 3 and reading["dated"]
    assert reading["start_margin"] > ceiling.SEPARATION
    # what the bus's parameters leave: the fault's swing (0.2^2 / 2 on 3 days of 6) and the
    # noise (0.05^2); the fault removes all but the noise: 1 - 0.0025 / 0.0125
    assert reading["fall"] == pytest.approx(0.8, abs=0.03)
    quiet = _synthetic_bus(monkeypatch, None, None)["soc"]
    assert "snr" not in quiet and quiet["max_other_snr"] < 3.0


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


@pytest.mark.slow
def test_a_regen_limit_bus_is_separable_and_dated_over_its_days():
    """The truth simulator's first regen-limit bus (its fault from day 2), the last 3 h of
    each of its six days: in the pack's power and voltage the limit stands far above 3, beats
    every candidate of another library effect at any start, and only a start within a day of
    day 2 fits as well."""
    source = ceiling.Source("truthsim")
    bus = next(b for b in source.module.buses(1, 0) if b.condition == "regen_soc_limit")
    assert bus.start_day == 2
    row = ceiling.ceiling_bus(("truthsim", bus, None, False, True))
    assert row["days"] == 6 and row["hours"] == pytest.approx(18.0)
    for kind in ("bms", "volt"):
        assert row[kind]["separable"] and row[kind]["snr"] > 30.0, row[kind]
        assert row[kind]["dated"] and abs(row[kind]["best_start"] - 2) <= 1
