"""Depot charging plans: every plan keeps the plugs, the grid limit and each bus's time at the
depot; the optimised plan is never dearer than charging on arrival or a flat spread."""

from __future__ import annotations

import numpy as np
import pytest

from ebus_env.study.depot_plan import METHODS, STEP_S, plan

PRICES = np.array([0.10] * 6 + [0.20] * 11 + [0.40] * 4 + [0.20] * 3)  # dear 17-21 h
DEMAND = 0.6  # per kW and day
ETA = 0.95


def fleet(n=30, seed=1):
    rng = np.random.default_rng(seed)
    arrive = rng.uniform(17.0, 23.0, n) * 3600
    depart = rng.uniform(29.0, 30.5, n) * 3600  # 05:00-06:30 the next morning
    need = rng.uniform(50.0, 200.0, n)
    return arrive, depart, need


def cost(p):
    load = p.folded_kw()
    return float((load * STEP_S / 3600 * PRICES[np.arange(96) * 900 // 3600]).sum()
                 + DEMAND * load.max())


@pytest.mark.parametrize("method", METHODS)
def test_every_plan_keeps_plugs_limit_and_windows(method):
    arrive, depart, need = fleet()
    chargers, kw, limit = 12, 100.0, 900.0
    p = plan(method, arrive, depart, need, chargers, kw, ETA, limit, PRICES, DEMAND)
    steps = (p.k0 + np.arange(p.power_kw.shape[1])) * STEP_S
    inside = (steps[None, :] >= arrive[:, None] - 1e-6) & \
        (steps[None, :] + STEP_S <= depart[:, None] + 1e-6)
    assert (p.power_kw[~inside] == 0.0).all()  # only while at the depot
    assert (p.power_kw <= kw / ETA + 1e-6).all()  # at most a charger's rating (grid side)
    assert (p.power_kw.sum(axis=0) <= limit + 1e-6).all()
    assert (p.power_kw.sum(axis=0) <= chargers * kw / ETA + 1e-6).all()  # the plugs' capacity
    if method != "optimal":  # whole plugs: never more buses charging than plugs
        assert ((p.power_kw > 1e-9).sum(axis=0) <= chargers).all()
    # energy into the packs: what each got, and never more than it needed
    assert p.delivered_kwh == pytest.approx(p.power_kw.sum(axis=1) * STEP_S / 3600 * ETA)
    assert (p.delivered_kwh <= need + 1e-6).all()


def test_the_optimal_plan_is_never_dearer_and_charges_when_power_is_cheap():
    arrive, depart, need = fleet()
    plans = {m: plan(m, arrive, depart, need, 30, 100.0, ETA, 2000.0, PRICES, DEMAND)
             for m in METHODS}
    assert not any(p.short.any() for p in plans.values())  # enough plugs and time for all
    assert cost(plans["optimal"]) <= min(cost(plans["on_arrival"]), cost(plans["flat"])) + 1e-6
    # no charging in the dear evening hours when the night is long enough
    evening = plans["optimal"].folded_kw()[17 * 4:21 * 4]
    assert evening.sum() < 0.05 * plans["optimal"].folded_kw().sum()
    assert plans["on_arrival"].folded_kw()[17 * 4:21 * 4].sum() > 0.0
    assert "LP" in plans["optimal"].status


def test_a_bus_that_cannot_get_its_energy_is_reported_short():
    arrive = np.array([20 * 3600.0, 20 * 3600.0])
    depart = np.array([21 * 3600.0, 30 * 3600.0])  # one hour, or ten
    need = np.array([300.0, 300.0])  # 300 kWh: 3 h at 100 kW
    for method in METHODS:
        p = plan(method, arrive, depart, need, 2, 100.0, ETA, 1000.0, PRICES, DEMAND)
        assert p.short.tolist() == [True, False], method
        assert p.delivered_kwh[0] == pytest.approx(100.0, rel=1e-6)  # one hour at 100 kW


def test_the_optimal_plan_steers_around_the_sites_other_load():
    """Told of the terminals' load after midnight, the plan keeps the billed peak lower than
    the same plan made without knowing it."""
    arrive, depart, need = fleet(10)
    base = np.zeros(96)
    base[0:8] = 500.0  # the terminals' charging, 00:00-02:00
    blind = plan("optimal", arrive, depart, need, 10, 100.0, ETA, 2000.0, PRICES, DEMAND)
    told = plan("optimal", arrive, depart, need, 10, 100.0, ETA, 2000.0, PRICES, DEMAND, base)
    assert (base + told.folded_kw()).max() < (base + blind.folded_kw()).max()
    assert told.delivered_kwh == pytest.approx(need, rel=1e-6)
