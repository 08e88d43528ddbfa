"""The FASTSim 3 truth source: the scaled bus's physics, the hidden effects and reproducibility."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("fastsim", reason="the FASTSim truth source needs fastsim (the 'bench' "
                    "extra: pip install -e '.[bench]')")

from benchmarks.truth import fastsim_source as fs  # noqa: E402
from benchmarks.truth.days import route_day  # noqa: E402

HOURS = 1.5


def nominal_base(aux_base_w: float = 4000.0) -> dict:
    return {**fs.NOMINAL, "aux_base_w": aux_base_w}


@pytest.fixture(scope="module")
def flat_plan():
    return route_day(np.random.default_rng(7), HOURS, 7.0, "rt44", climate="mild")


def day_energy_kwh(clean) -> float:
    return float(clean["energy_out_j"].sum() / 3.6e6)


def test_flat_day_consumption_is_a_12m_bus(flat_plan):
    clean = fs.simulate(flat_plan, nominal_base(), None, {})
    assert 0.8 <= fs.consumption_kwh_per_km(clean) <= 1.6
    # FASTSim followed the plan: the distance driven is the plan's
    assert clean["distance_m"].iloc[-1] == pytest.approx(flat_plan["distance_m"].iloc[-1],
                                                         rel=0.01)


def test_constant_speed_road_load_is_the_scaled_bus():
    n, v = 300, 10.0
    speed = np.concatenate((np.linspace(0.0, v, 20), np.full(n, v)))
    base = nominal_base()
    veh = fs.bus_vehicle(base, 14000.0, 4000.0)
    run = fs.run_fastsim(veh, speed, np.zeros(len(speed)), np.full(len(speed), 15.0),
                         np.zeros(len(speed)), 0.0)
    cruise = slice(-100, None)
    # rolling resistance C_rr m g v and drag rho c_d A v^3 / 2 with the bus's values
    assert run["rolling_w"][cruise] == pytest.approx(base["rolling_coef"] * 14000.0 * 9.81 * v,
                                                     rel=0.01)
    # (FASTSim 3.1.0's drag is 2.3 % below this at the 1.2 kg/m^3 it reports as air density)
    rho = run["air_density_kg_per_m3"][cruise]
    assert run["drag_w"][cruise] == pytest.approx(
        0.5 * rho * base["drag_coef"] * base["frontal_area_m2"] * v**3, rel=0.03)
    # the pack gives the road load and the auxiliaries through the drivetrain's losses
    out_w = run["energy_out_j"][cruise]
    road_w = run["rolling_w"][cruise] + run["drag_w"][cruise]
    efficiency = road_w / (out_w - 4000.0 / 0.985)
    assert np.all((efficiency > 0.75) & (efficiency < base["drivetrain_efficiency"]))


def test_standing_drains_the_aux_energy():
    n = 600
    veh = fs.bus_vehicle(nominal_base(), fs.NOMINAL["curb_mass_kg"], 5000.0)
    run = fs.run_fastsim(veh, np.zeros(n), np.zeros(n), np.full(n, 15.0), np.zeros(n), 0.0)
    # 5 kW for 599 s through FASTSim's constant pack efficiency (0.985 in the Zoe file)
    assert run["energy_out_j"].sum() == pytest.approx(5000.0 * (n - 1) / 0.985, rel=0.002)


def test_grade_day_uses_more_energy_than_its_control():
    plan = route_day(np.random.default_rng(11), HOURS, 7.0, "rt7", climate="mild")
    assert np.ptp(plan["altitude_m"]) > 20.0  # the route climbs
    base = nominal_base()
    control = fs.simulate(plan, base, None, {})
    graded = fs.simulate(plan, base, "road_grade", {})
    assert day_energy_kwh(graded) > day_energy_kwh(control) * 1.01


@pytest.mark.parametrize("hidden, climate, start_h, min_kwh", [
    ("cabin_heating", "cold", 7.0, 3.0),  # a winter morning: ~10 kW of heat
    ("cabin_cooling", "hot", 13.0, 0.5),  # a summer afternoon: ~6 kW of cooling at COP ~4
])
def test_hvac_day_uses_more_energy_than_its_control(hidden, climate, start_h, min_kwh):
    plan = route_day(np.random.default_rng(5), HOURS, start_h, "rt44", climate=climate)
    base = nominal_base()
    effect = fs.draw_hvac(np.random.default_rng(3), hidden)
    control = fs.simulate(plan, base, None, {})
    hvac = fs.simulate(plan, base, hidden, effect)
    extra_kwh = day_energy_kwh(hvac) - day_energy_kwh(control)
    assert extra_kwh == pytest.approx(hvac["hvac_elec_w"].sum() / 3.6e6, rel=0.05)
    assert extra_kwh > min_kwh
    # the cabin is held near its setpoint
    assert abs(hvac["cabin_temp_degc"].iloc[600:].mean() - effect["setpoint_degc"]) < 1.5
    heat_w = hvac["hvac_thermal_w"].mean()
    assert heat_w > 0 if hidden == "cabin_heating" else heat_w < 0


def test_passenger_mass_day_uses_more_energy(flat_plan):
    base = nominal_base()
    assert flat_plan["passengers"].max() > 10
    control = fs.simulate(flat_plan, base, None, {})
    loaded = fs.simulate(flat_plan, base, "passenger_mass", {"passenger_mass_kg": 75.0})
    assert (loaded["mass_kg"] - base["curb_mass_kg"]).max() == pytest.approx(
        75.0 * flat_plan["passengers"].max())
    assert day_energy_kwh(loaded) > day_energy_kwh(control)
    # chained runs join without a gap: time and distance keep going
    assert np.all(np.diff(loaded["distance_m"]) >= 0.0)
    assert loaded["distance_m"].iloc[-1] == pytest.approx(control["distance_m"].iloc[-1], rel=1e-3)


def test_time_of_day_load_switches_at_a_standstill():
    clock = np.linspace(5.0, 8.0, 10801)
    speed = np.where((clock > 6.49) & (clock < 6.6), 8.0, 0.0)  # driving across 06:30
    aux = fs.aux_schedule_w(clock, speed, 6.5, 17.0, 1500.0)
    off = np.flatnonzero(aux == 0.0)[0]
    assert speed[off] == 0.0 and clock[off] >= 6.6  # held until the bus stood again
    assert aux[0] == 1500.0 and aux[-1] == 0.0


def test_the_bus_pack_counts_charge_charges_to_the_stop_soc_and_caps_its_voltage():
    """The pack around FASTSim's terminal power: its SoC falls by the counted charge, the
    terminal power is FASTSim's draw less the charger's, the charger gives its rating times
    its efficiency below the taper, then tapers and ends at the stop SoC."""
    n = 3600
    base = nominal_base()
    charger_w = np.full(n, 300e3)
    charger_w[:5] = 0.0  # plugged in at 5 s
    drawn_w = np.full(n, 5e3)
    pack = fs.rebuild_pack(drawn_w, charger_w, base, 0.5, 0.9)
    soc, current, volts = pack["soc_frac"], pack["battery_current_a"], pack["battery_voltage_v"]
    q_as = 3600.0 * fs.pack_capacity_ah(base["capacity_kwh"])
    assert np.allclose(np.diff(soc), -current[1:] / q_as)
    assert np.allclose(volts * current, drawn_w - pack["charger_in_w"], rtol=1e-9, atol=1e-6)
    assert not pack["charging"][:5].any() and pack["charging"][5]
    assert pack["charger_in_w"][10] == pytest.approx(fs.CHARGE_EFFICIENCY * 300e3)
    assert current[10] < 0.0 < current[2]  # charging; drawing before the plug
    # a resistance: the voltage rises under charge and falls under load, about the OCV
    ocv = fs.PACK_CELLS * fs.ocv_cell_v("LFP", soc[9])
    assert volts[10] == pytest.approx(ocv - base["pack_r_ohm"] * current[10], rel=1e-4)
    assert soc.max() <= 0.9
    end = int(np.flatnonzero(pack["charging"])[-1]) + 1
    assert end < n - 1 and not pack["charging"][end:].any()
    assert soc[end - 1] > 0.9 - fs.TAPER_FRAC * fs.END_OF_CHARGE_FRAC
    assert np.all(np.diff(soc[end:]) < 0.0)


def test_the_bus_packs_charge_current_stops_at_the_cells_charge_voltage():
    """A 450 kW charger on a pack with a high resistance near its stop SoC: the BMS caps the
    current where the cells reach 3.65 V; a drawn power the pack cannot give is an error."""
    n = 200
    base = {**nominal_base(), "pack_r_ohm": 0.25}
    pack = fs.rebuild_pack(np.zeros(n), np.full(n, 450e3), base, 0.80, 0.95)
    v_max = fs.PACK_CELLS * fs.PACKS["LFP"]["cell_v_max"]
    on = pack["charging"] == 1
    assert on[1:].all() and pack["battery_voltage_v"][on].max() == pytest.approx(v_max)
    assert (pack["charger_in_w"][on] < fs.CHARGE_EFFICIENCY * 450e3).all()
    with pytest.raises(RuntimeError, match="more than the pack can give"):
        fs.rebuild_pack(np.full(n, 5e6), np.zeros(n), base, 0.5, 0.9)


def test_under_inflated_tyres_roll_harder_from_their_day_and_log_a_force():
    """The FASTSim bus's tyre fault: its rolling-resistance power rises by the drawn share,
    and the truth's force power is that extra, in the driving modes."""
    plan = route_day(np.random.default_rng(5), 0.5, 8.0, "rt44", climate="mild")
    base = nominal_base()
    normal = fs.simulate(plan, base, None, {})
    soft = fs.simulate(plan, base, "underinflated_tyres", {"rolling_rise_frac": 0.2})
    moving = normal["rolling_w"] > 0.0
    assert soft["rolling_w"][moving].sum() / normal["rolling_w"][moving].sum() == \
        pytest.approx(1.2, rel=0.02)
    assert soft["p_force_w"].sum() == pytest.approx(soft["rolling_w"].sum() / 6.0, rel=1e-9)
    assert day_energy_kwh(soft) > day_energy_kwh(normal)


def test_cases_are_the_truthsim_days_fastsim_can_express():
    listed = fs.cases(n_per_effect=2, n_control=3, seed=4)
    hidden = [c.hidden for c in listed]
    assert all(hidden.count(h) == 2 for h in fs.HIDDEN) and hidden.count(None) == 3
    assert len({c.case_id for c in listed}) == len(listed)
    truthsim_days = {c.seed: c for c in fs.truthsim.cases(2, 3, seed=4)}
    for case in listed:  # the same route day as the independent simulator's case
        twin = truthsim_days[case.seed]
        assert (twin.route, twin.hours, twin.start_clock_h, twin.climate) == \
            (case.route, case.hours, case.start_clock_h, case.climate)


def test_generate_is_byte_reproducible():
    heating = next(c for c in fs.cases(1, 0, seed=9) if c.hidden == "cabin_heating")
    case = dataclasses.replace(heating, hours=1.0)
    log_a, truth_a = fs.generate(case)
    log_b, truth_b = fs.generate(case)
    assert fs.truthsim.log_bytes(log_a) == fs.truthsim.log_bytes(log_b)
    assert json.dumps(truth_a, sort_keys=True) == json.dumps(truth_b, sort_keys=True)
    assert truth_a["source"] == "fastsim" and truth_a["expected_verdict"] == "cabin_hvac"
    assert set(log_a.columns) >= {"timestamp", "speed_kmh", "soc_pct", "ambient_degc"}
    assert "passengers" not in log_a.columns and "altitude_m" not in log_a.columns
    assert "battery_current_a" not in log_a.columns  # a SoC-only log unless asked
    bms, truth_bms = fs.generate(case, current_voltage=True)
    pd.testing.assert_frame_equal(bms[log_a.columns], log_a)
    assert {"battery_current_a", "battery_voltage_v"} <= set(bms.columns)
    assert truth_bms["chemistry"] == "LFP" and str(log_a["timestamp"].iloc[0]).endswith("-08:00")
    assert 100.0 <= truth_a["strength"]["cabin_hvac.ua_w_per_k"] <= 1500.0
    assert truth_a["summary"]["hidden_kwh"] > 0.0
    assert truth_a["summary"]["soc_footprint_pct"] > 0.0  # the heater draws on the pack


def test_an_oracle_log_adds_the_hidden_effects_own_power():
    """``--oracle`` on FASTSim's days: ``logged_load_kw`` adds up to the effect's energy."""
    heating = next(c for c in fs.cases(1, 0, seed=9) if c.hidden == "cabin_heating")
    case = dataclasses.replace(heating, hours=1.0)
    log, truth = fs.generate(case)
    oracle, _ = fs.generate(case, oracle=True)
    pd.testing.assert_frame_equal(oracle[log.columns], log)
    load_kwh = oracle["logged_load_kw"].sum() / 3600.0
    assert load_kwh == pytest.approx(truth["summary"]["effect_kwh"], rel=0.01, abs=0.002)
