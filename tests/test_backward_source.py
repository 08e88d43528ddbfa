"""The backward-facing (ADVISOR/VECTO-style) truth source: its physics by hand, its balances,
signs and limits, and its cases."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd
import pytest

from benchmarks.truth import backward_source as bw
from benchmarks.truth import cases as truth_cases
from benchmarks.truth.days import route_day


def nominal(chemistry: str = "LFP") -> dict:
    return {**bw.NOMINAL, **bw.PACKS[chemistry], "chemistry": chemistry,
            "motor_loss_scale": 1.0}


def flat_plan(seconds: int, speed_mps: float = 0.0, *, ramp_s: float = 0.0,
              charging: bool = False, charger_kw: float = 0.0,
              ambient_degc: float = 15.0) -> pd.DataFrame:
    t = np.arange(seconds, dtype=float)
    speed = speed_mps * np.clip(t / ramp_s, 0.0, 1.0) if ramp_s else np.full(seconds, speed_mps)
    plan = pd.DataFrame({
        "time_s": t, "clock_h": 10.0 + t / 3600.0, "speed_target_mps": speed,
        "grade_frac": 0.0, "altitude_m": 50.0, "door_open": 0, "charging": int(charging),
        "charger_kw": charger_kw if charging else 0.0, "ambient_degc": ambient_degc,
        "passengers": 0, "solar_w_per_m2": 0.0, "distance_m": np.cumsum(speed), "leg": 0})
    plan.attrs.update(date="2025-05-01", climate="mild")
    return plan


def test_the_electrode_potentials_give_each_chemistrys_cell_window():
    """OCV = U_+ - U_-: the LG M50 (NMC811/graphite-SiOx) window of Chen et al. 2020 spans
    2.5-4.19 V; both curves rise with SoC; LFP keeps its flat 3.2-3.35 V plateau."""
    assert bw.cell_ocv_v("NMC", 0.0) == pytest.approx(2.50, abs=0.01)
    assert bw.cell_ocv_v("NMC", 1.0) == pytest.approx(4.19, abs=0.01)
    for chemistry in ("LFP", "NMC"):
        soc, volts = bw.ocv_table(chemistry)
        assert np.all(np.diff(volts) > -1e-9)
    plateau = [bw.cell_ocv_v("LFP", z) for z in np.linspace(0.3, 0.9, 13)]
    assert 3.2 < min(plateau) and max(plateau) < 3.35
    assert bw.cell_ocv_v("LFP", 1.0) < bw.PACKS["LFP"]["cell_v_max"]


def test_resistance_follows_arrhenius_and_rises_at_low_soc():
    expected = math.exp(28e3 / 8.314 * (1.0 / 273.15 - 1.0 / 298.15))
    assert bw.resistance_factor(0.0, 0.5) == pytest.approx(expected, rel=1e-3)  # x2.8
    assert bw.resistance_factor(25.0, 0.5) == pytest.approx(1.0, abs=1e-3)
    assert bw.resistance_factor(25.0, 0.0) == pytest.approx(1.5)


def test_the_motor_loss_model_by_hand_and_the_drive_power_chain():
    """At 1000 N m and 200 rad/s: copper 6900 W, iron 0.5 x 200^1.5, windage 1.25e-4 x
    200^3, 300 W; the axle's loss torque against the flow; the inverter's on top."""
    bus = nominal()
    loss = bw.motor_loss_w(bus, 1000.0, 200.0)
    assert loss == pytest.approx(0.0069 * 1e6 + 0.5 * 200.0 ** 1.5 + 1.25e-4 * 8e6 + 300.0)
    v = 10.0
    force = 5000.0
    p_dc, p_axle, p_motor_inv = bw.dc_power_w(bus, force, v)
    w = v / bus["wheel_radius_m"] * bus["axle_ratio"]
    t_out = force * bus["wheel_radius_m"] / bus["axle_ratio"]
    t_loss = bus["axle_drag_nm"] + bus["axle_loss_frac"] * t_out
    p_ac = (t_out + t_loss) * w + bw.motor_loss_w(bus, t_out + t_loss, w)
    assert p_axle == pytest.approx(t_loss * w)
    assert p_dc == pytest.approx(p_ac + bus["inverter_switch_w"] + bus["inverter_loss_frac"] * p_ac)
    assert p_dc == pytest.approx(force * v + p_axle + p_motor_inv)
    # generating: losses are taken from what the wheel gives back
    back, axle_back, rest_back = bw.dc_power_w(bus, -force, v)
    assert back < 0.0 and -back < force * v
    assert back == pytest.approx(-force * v + axle_back + rest_back)
    assert bw.dc_power_w(bus, 0.0, v) == (0.0, 0.0, 0.0)


def test_constant_speed_draws_the_road_load_through_the_drive():
    bus = nominal()
    speed = 12.0
    trace = bw.simulate(flat_plan(400, speed, ramp_s=60.0), bus)
    steady = trace[trace["time_s"] > 200.0]
    assert np.allclose(steady["speed_mps"], speed)
    road_n = bus["rrc_n_per_kn"] / 1000.0 * bus["curb_mass_kg"] * 9.81 \
        + 0.5 * 1.2 * bus["cda_m2"] * speed ** 2
    assert steady["p_wheel_w"].to_numpy() == pytest.approx(road_n * speed, rel=1e-9)
    p_dc = bw.dc_power_w(bus, road_n, speed)[0]
    assert steady["p_battery_w"].to_numpy() == pytest.approx(p_dc + bus["aux_base_w"], rel=1e-9)
    # a backward model follows the trace exactly where it can
    assert trace["trace_miss_mps"].abs().max() < 1e-9


@pytest.fixture(scope="module")
def hilly_day():
    plan = route_day(np.random.default_rng(5), 1.5, 7.0, "rt45", charger_kw=300.0,
                     charger_terminals=(0, 1))
    bus = nominal("NMC")
    return plan, bus, bw.simulate(plan, bus, "road_grade")


def test_the_energy_balances_close(hilly_day):
    """Wheel: the force the wheel needs, over the day, is road load + grade + kinetic energy;
    the motor's work less what the friction brakes took is that; DC: drive + loads - charger
    is the battery's; battery: OCV energy less its losses."""
    _, bus, tr = hilly_day
    end = tr.iloc[-1]
    assert end["e_wheel_j"] == pytest.approx(end["e_road_j"] + end["e_grade_j"]
                                             + end["e_kinetic_j"] + end["e_force_j"],
                                             rel=1e-9, abs=1.0)
    motor_wheel = end["e_drive_dc_j"] - end["e_axle_loss_j"] - end["e_motor_loss_j"]
    assert motor_wheel - end["e_friction_j"] == pytest.approx(end["e_wheel_j"], rel=1e-9, abs=1.0)
    dc = end["e_drive_dc_j"] + end["e_aux_j"] + end["e_hidden_j"] - end["e_charger_j"]
    assert end["e_battery_j"] == pytest.approx(dc, rel=1e-9)
    assert end["e_battery_j"] == pytest.approx(end["e_ocv_j"] - end["e_battery_loss_j"],
                                               rel=1e-9)
    climb = tr["altitude_m"].iloc[-1] - tr["altitude_m"].iloc[0]
    assert end["e_grade_j"] == pytest.approx(bus["curb_mass_kg"] * 9.81 * climb, rel=1e-6,
                                             abs=1e3)
    assert end["e_friction_j"] > 0.0 and end["e_axle_loss_j"] > 0.0


def test_signs_driving_drains_braking_returns_charging_fills(hilly_day):
    _, bus, tr = hilly_day
    pulling = tr["p_wheel_w"] > 5e3
    assert (tr["p_drive_dc_w"][pulling] > tr["p_wheel_w"][pulling]).all()  # losses on top
    assert (tr["battery_current_a"][pulling] > 0.0).all()
    regen = (tr["p_wheel_w"] < -20e3) & (tr["speed_mps"] > 6.0)
    assert regen.any() and (tr["p_drive_dc_w"][regen] < 0.0).all()
    charging = tr["charging"] == 1
    assert charging.any() and (tr["battery_current_a"][charging] < 0.0).all()
    assert (np.diff(tr["soc_frac"][charging].to_numpy()) >= 0.0).all()
    standing = (tr["speed_mps"] == 0.0) & (tr["p_wheel_w"] == 0.0) & ~charging
    assert tr["p_battery_w"][standing].to_numpy() == pytest.approx(bus["aux_base_w"])


def test_the_voltage_floor_cuts_traction_and_the_speed_falls_behind_the_trace():
    bus = nominal("NMC")
    for key in ("r0_ohm", "r1_ohm", "r2_ohm"):
        bus[key] *= 1.6
    plan = flat_plan(120, 16.0, ramp_s=16.0)
    cold = {"pack_temp0_degc": -15.0, "start_offset_k": 0.0,
            "pack_heat_capacity_j_per_k": 1.8e6, "pack_ha_w_per_k": 100.0}
    tr = bw.simulate(plan, bus, "cold_battery", cold, soc0_frac=0.12)
    floor_v = bus["cells_series"] * bus["cell_v_min"]
    assert tr["derated"].sum() > 3
    assert tr["battery_voltage_v"].min() >= floor_v - 0.5
    assert tr["trace_miss_mps"].max() > 0.5
    warm = bw.simulate(plan, bus, soc0_frac=0.12)
    assert warm["derated"].sum() == 0 and tr["distance_m"].iloc[-1] < warm["distance_m"].iloc[-1]


def test_charging_is_constant_current_then_held_at_the_charge_voltage():
    bus = nominal("NMC")
    bus["r0_ohm"] *= 2.0
    tr = bw.simulate(flat_plan(1800, charging=True, charger_kw=300.0), bus, soc0_frac=0.60,
                     charge_stop_frac=0.97)
    v_max = bus["cells_series"] * bus["cell_v_max"]
    assert tr["battery_voltage_v"].max() <= v_max + 1e-6
    assert tr["cv_phase"].iloc[-100:].all() and not tr["cv_phase"].iloc[:5].any()
    assert tr["p_charger_w"].iloc[2] == pytest.approx(300e3)  # the charger's rating first
    assert tr["p_charger_w"].iloc[-1] < tr["p_charger_w"].iloc[2]


def test_the_steady_state_cabin_by_hand():
    """VECTO-style: the heat to hold the setpoint is the conductance x dT less the sun and
    the passengers; the heat pump gives what it can at its COP, the heater the rest."""
    ph = {"ua_w_per_k": 400.0, "fresh_air_kg_per_s": 0.4, "door_air_m3_per_s": 0.6,
          "solar_area_m2": 4.0, "setpoint_degc": 20.0, "heat_pump_w": 10e3,
          "cooling_max_w": 24e3, "fans_w": 500.0}
    power, heat = bw.hvac_power_w(ph, True, 0.0, 100.0, 1, 20)
    conductance = 400.0 + 0.4 * 1005.0 + 1.2 * 1005.0 * 0.6
    need = conductance * 20.0 - 4.0 * 100.0 - 75.0 * 20
    assert heat == pytest.approx(need)
    pump = 10e3 * 0.75  # the pump's capacity at 0 degC
    assert power == pytest.approx(500.0 + pump / 2.2 + (need - pump))
    power, heat = bw.hvac_power_w(ph, True, -20.0, 0.0, 0, 0)  # below the pump's range
    assert power == pytest.approx(500.0 + heat)
    cooling = {**ph, "setpoint_degc": 24.0}
    power, heat = bw.hvac_power_w(cooling, False, 30.0, 500.0, 0, 30)
    assert heat < 0.0 and power == pytest.approx(500.0 - heat / 3.0)
    assert bw.hvac_power_w(ph, True, 25.0, 0.0, 0, 0) == (500.0, 0.0)  # no heat needed


@pytest.mark.parametrize("hidden", sorted(bw.HIDDEN))
def test_each_hidden_effect_costs_energy_and_is_recorded(hidden):
    case = next(c for c in bw.cases(1, 0) if c.hidden == hidden) if hidden in \
        truth_cases.EFFECTS else None
    if case is None:  # a multi-day condition: its first bus's day with the fault acting
        bus = next(b for b in bw.buses(1, 0) if b.condition == hidden)
        case = bw.bus_days(bus)[-1]
    start = 16.0 if hidden == "aux_schedule" else case.start_clock_h
    hours = 6.0 if hidden == "battery_chiller" else 2.0  # the pack warms over the layovers
    case = dataclasses.replace(case, hours=hours, start_clock_h=start)
    log, truth = bw.generate(case)
    assert truth["source"] == "backward"
    assert truth["expected_verdict"] == truth_cases.VERDICTS[hidden]
    if hidden != "capacity_step":  # a weak cell group changes the losses only
        assert truth["summary"]["effect_kwh"] > 0.2
    assert truth["summary"]["soc_footprint_pct"] > 0.01
    if truth["expected_verdict"] == "outside_library":
        assert truth["outside_modes"] and set(truth["outside_modes"]) <= set(truth_cases.MODES)
    assert ("altitude_m" in log) == (hidden == "road_grade")
    assert "battery_current_a" not in log


def test_a_case_is_byte_reproducible_and_its_bms_log_adds_two_columns():
    case = dataclasses.replace(bw.cases(1, 0)[1], hours=0.5)
    log_a, truth_a = bw.generate(case)
    log_b, truth_b = bw.generate(case)
    assert truth_cases.log_bytes(log_a) == truth_cases.log_bytes(log_b) and truth_a == truth_b
    bms, _ = bw.generate(case, current_voltage=True)
    pd.testing.assert_frame_equal(bms[log_a.columns], log_a)
    assert list(bms.columns[-2:]) == ["battery_current_a", "battery_voltage_v"]


def test_the_cases_and_buses_are_the_benchs():
    listed = bw.cases()
    assert len(listed) == 10 * len(truth_cases.EFFECTS) + 30
    assert all(c.case_id.startswith("backward_") for c in listed)
    buses = bw.buses()
    counts = pd.Series([b.condition or "control" for b in buses]).value_counts()
    assert (counts.drop("control") == 5).all() and counts["control"] == 4
    assert set(counts.index) - {"control"} == set(bw.MULTI_DAY)
