"""Each effect on its own: hand-computed values, signs and limits, plain and compiled."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ebus_env.effects import battery, drivetrain
from ebus_env.effects.base import get_effect
from ebus_env.effects.tables import lookup1, lookup2
from ebus_env.units import GRAVITY_MPS2


def both(name, site="main"):
    """The plain and the numba-compiled function of an effect's call site."""
    eff = get_effect(name)
    return eff.calls[site].function, eff.jitted(site)


@pytest.mark.parametrize("fn", both("aero_drag"))
def test_aero_drag_hand_value_and_cube_law(fn):
    def drag_n(speed_mps):
        return fn(speed_mps=speed_mps, drag_coef=0.7, frontal_area_m2=7.5,
                  air_density_kg_per_m3=1.2)

    # 1/2 * 1.2 * 0.7 * 7.5 * 10^2 = 315 N
    assert drag_n(10.0) == pytest.approx(315.0)
    assert drag_n(0.0) == 0.0
    # power F v: doubling v multiplies it by 8
    assert drag_n(20.0) * 20.0 == pytest.approx(8 * drag_n(10.0) * 10.0)


@pytest.mark.parametrize("fn", both("rolling_resistance"))
def test_rolling_resistance(fn):
    def force_n(speed_mps, grade_frac=0.0):
        return fn(speed_mps=speed_mps, mass_kg=15000.0, grade_frac=grade_frac, rolling_coef=0.008)

    assert force_n(5.0) == pytest.approx(15000 * GRAVITY_MPS2 * 0.008)
    assert force_n(0.0) == 0.0  # a standing bus
    # on a 10 % grade the normal force is m g cos(alpha)
    assert force_n(5.0, 0.1) == pytest.approx(15000 * GRAVITY_MPS2 * 0.008 * math.cos(math.atan(0.1)))


@pytest.mark.parametrize("fn", both("road_grade"))
def test_road_grade_signs(fn):
    up = fn(mass_kg=15000.0, grade_frac=0.05)
    assert up == pytest.approx(15000 * GRAVITY_MPS2 * math.sin(math.atan(0.05)))
    assert fn(mass_kg=15000.0, grade_frac=-0.05) == pytest.approx(-up)
    assert fn(mass_kg=15000.0, grade_frac=0.0) == 0.0


@pytest.mark.parametrize("fn", both("passenger_load"))
def test_passenger_load_measured_count_wins(fn):
    assert fn(passenger_count=math.nan, load_frac=0.5, max_passengers=80.0) == 40.0
    assert fn(passenger_count=12.0, load_frac=0.5, max_passengers=80.0) == 12.0


@pytest.mark.parametrize("fn", both("passenger_mass"))
def test_passenger_mass(fn):
    assert fn(passengers=40.0, passenger_mass_kg=68.0) == 2720.0


@pytest.mark.parametrize("fn", both("regen_cutoff"))
def test_regen_cutoff(fn):
    def share(speed_mps, max_share=1.0, demand_n=-10_000.0, max_decel_mps2=5.0):
        return fn(speed_mps=speed_mps, wheel_force_demand_n=demand_n, road_force_n=1_000.0,
                  effective_mass_kg=14_000.0, max_brake_decel_mps2=5.0, cutoff_speed_mps=1.5,
                  max_share=max_share, max_decel_mps2=max_decel_mps2)

    assert share(1.4) == 0.0
    assert share(1.5) == 0.0
    assert share(1.6, max_share=0.8) == 0.8
    # series blending: a 14 t bus braking with 28 kN (2 m/s^2) and a motor allowed 0.8 m/s^2
    # alone gets 11.2 kN from the motor, the share 0.4; gentle braking stays with the motor
    assert share(10.0, demand_n=-28_000.0, max_decel_mps2=0.8) == pytest.approx(0.4)
    assert share(10.0, demand_n=-7_000.0, max_decel_mps2=0.8) == 1.0
    assert share(10.0, max_share=0.7, demand_n=-14_000.0, max_decel_mps2=0.8) == \
        pytest.approx(0.7)  # 9.8 kN < 11.2 kN
    # at the brakes' own 5 m/s^2 nothing is limited, however hard the driver asks: the demand
    # is cut to 14 t x 5 m/s^2 less the road's 1 kN first, 69 kN < 70 kN
    assert share(10.0, demand_n=-500_000.0) == 1.0


@pytest.mark.parametrize("fn", both("cccv_taper"))
def test_cccv_taper_decays_with_negative_exponent(fn):
    def taper(soc_frac):
        return fn(soc_frac=soc_frac, capacity_ah=300.0, cv_soc_pct=87.5, decay_per_pct=0.23,
                  cc_c_rate=3.0)

    assert taper(0.80) == (900.0, 1.0)
    # docs/physics.md §5.4: exp(-0.23 (SoC - 87.5)) = 0.563 at 90 %, 0.178 at 95 %, 0.056 at 100 %
    assert taper(0.90)[1] == pytest.approx(0.563, abs=1e-3)
    assert taper(0.95)[1] == pytest.approx(0.178, abs=1e-3)
    assert taper(1.00)[1] == pytest.approx(0.056, abs=1e-3)
    tapers = [taper(s)[1] for s in np.linspace(0.85, 1.0, 31)]
    assert np.all(np.diff(tapers) <= 0)


@pytest.mark.parametrize("fn", both("static_rcd"))
def test_static_rcd(fn):
    assert fn(rcd_frac=0.2, resistance_growth=1.5) == pytest.approx((0.8, 1.3))
    assert fn(rcd_frac=0.0, resistance_growth=1.5) == (1.0, 1.0)


def test_auxiliaries_and_schedule():
    from ebus_env.effects.tables import TableData

    for fn in both("auxiliaries"):
        assert fn(base_power_w=4000.0) == 4000.0
    table = TableData((0, 7, 8, 9, 24), (0, 0, 2000, 0, 0)).encode("schedule_w")
    for fn in both("aux_schedule"):
        assert fn(time_of_day_h=3.0, scale=1.0, schedule_w=table) == 0.0
        assert fn(time_of_day_h=8.0, scale=1.0, schedule_w=table) == 2000.0
        assert fn(time_of_day_h=7.5, scale=2.0, schedule_w=table) == pytest.approx(2000.0)


def test_replayed_load_is_the_logged_load_times_its_scale():
    for fn in both("replayed_load"):
        assert fn(logged_load_w=3000.0, scale=1.0) == 3000.0
        assert fn(logged_load_w=3000.0, scale=0.5) == 1500.0
        assert fn(logged_load_w=-800.0, scale=2.0) == -1600.0  # a load returning power
        assert fn(logged_load_w=0.0, scale=3.0) == 0.0  # a log without it: nothing


CABIN = dict(setpoint_degc=20.0, deadband_k=1.0, ua_w_per_k=400.0, heat_capacity_j_per_k=1e6,
             fresh_air_kg_per_s=0.4, door_air_m3_per_s=0.7, passenger_heat_w=100.0,
             solar_area_m2=6.0, heating_max_w=25000.0, cooling_max_w=25000.0,
             heat_pump_max_w=16000.0, heat_pump_min_ambient_degc=-10.0, cop_heat_0c=2.45,
             cop_heat_slope_per_k=0.07, cop_cool_25c=3.0, cop_cool_slope_per_k=0.06,
             fan_power_w=800.0, control_gain_w_per_k=3000.0)


def cabin(fn, cabin_temp, ambient, passengers=0.0, door=0.0, solar=0.0, **over):
    p = {**CABIN, **over}
    return fn(cabin_temp_degc=cabin_temp, ambient_degc=ambient, passengers=passengers,
              door_open=door, solar_w_per_m2=solar, cabin_heat_w=0.0, dt_s=0.1, **p)


@pytest.mark.parametrize("fn", both("cabin_hvac"))
def test_cabin_hvac_heating_pulls_back_to_band_edge_with_heat_pump(fn):
    # 0.1 K below the band (19 degC) at 0 degC outside: cancel the losses, add K * 0.1 K
    conductance = 400.0 + 0.4 * 1005.0
    passive = -conductance * 18.9 + 100.0  # driver's heat
    electric, heat, next_temp = cabin(fn, 18.9, 0.0)
    assert heat == pytest.approx(3000.0 * 0.1 - passive)
    assert next_temp == pytest.approx(18.9 + 0.1 * 3000.0 * 0.1 / 1e6)
    assert electric == pytest.approx(800.0 + heat / 2.45)  # heat pump, COP at 0 degC


@pytest.mark.parametrize("fn", both("cabin_hvac"))
def test_cabin_hvac_idles_in_band_and_uses_ptc_when_cold(fn):
    electric, heat, _ = cabin(fn, 20.0, 19.0)
    assert heat == 0.0 and electric == 800.0
    # below the heat pump's minimum ambient the PTC heater (COP 1) does it all
    electric, heat, _ = cabin(fn, 18.5, -15.0)
    assert heat > 0 and electric == pytest.approx(800.0 + heat)
    # saturated: a cold cabin gets the maximum heating power
    _, heat, _ = cabin(fn, 0.0, -15.0)
    assert heat == 25000.0


@pytest.mark.parametrize("fn", both("cabin_hvac"))
def test_cabin_hvac_cooling_and_door_losses(fn):
    electric, heat, _ = cabin(fn, 21.5, 30.0, passengers=50.0, solar=600.0)
    assert heat < 0
    cop = 3.0 - 0.06 * 5.0
    assert electric == pytest.approx(800.0 - heat / cop)
    closed = cabin(fn, 18.0, 10.0)[1]
    opened = cabin(fn, 18.0, 10.0, door=1.0)[1]
    assert opened - closed == pytest.approx(1.2 * 1005.0 * 0.7 * 8.0)


MOTOR = dict(wheel_radius_m=0.48, gear_ratio=5.67, gearbox_efficiency=0.96,
             peak_power_kw=200.0, peak_torque_nm=2800.0, regen_power_kw=150.0)


@pytest.mark.parametrize("fn", both("efficiency_map", "limits"))
def test_motor_limits(fn):
    traction, regen = fn(speed_mps=0.0, **MOTOR)
    assert traction == pytest.approx(2800 * 5.67 * 0.96 / 0.48)  # torque-limited at rest
    traction, regen = fn(speed_mps=20.0, **MOTOR)
    assert traction == pytest.approx(200e3 * 0.96 / 20.0)  # power-limited
    assert regen == pytest.approx(150e3 / (0.96 * 20.0))


def test_map_power_quadrants_and_losses():
    loss_map = drivetrain.LOSS_MAP.resolve().encode("loss_map")
    for fn in both("efficiency_map", "power"):
        args = dict(speed_mid_mps=10.0, wheel_radius_m=0.48, gear_ratio=5.67,
                    gearbox_efficiency=0.96, peak_torque_nm=2800.0, max_motor_speed_rpm=3000.0,
                    loss_map=loss_map)
        assert fn(motor_force_n=0.0, **args) == 0.0  # no torque, no power
        motoring = fn(motor_force_n=5000.0, **args)
        generating = fn(motor_force_n=-5000.0, **args)
        wheel = 5000.0 * 10.0
        assert wheel / 0.96 < motoring < wheel / 0.80  # losses on top of the gearbox
        assert 0.70 * wheel * 0.96 < -generating < wheel * 0.96
        eff = wheel / motoring
        assert 0.85 < eff < 0.96


def test_constant_efficiency_power():
    for fn in both("constant_efficiency", "power"):
        assert fn(motor_force_n=1000.0, speed_mid_mps=10.0, wheel_radius_m=0.48, gear_ratio=5.67,
                  gearbox_efficiency=0.96, motor_efficiency=0.9) == pytest.approx(1e4 / 0.96 / 0.9)
        assert fn(motor_force_n=-1000.0, speed_mid_mps=10.0, wheel_radius_m=0.48, gear_ratio=5.67,
                  gearbox_efficiency=0.96, motor_efficiency=0.9) == pytest.approx(-1e4 * 0.96 * 0.9)


def test_efficiency_map_converts_to_losses():
    data = drivetrain.TableData((-1.0, 0.0, 1.0), (0.0, 0.5, 1.0),
                                ((0.9, 0.9, 0.9), (0.9, 0.9, 0.9), (0.9, 0.9, 0.9)))
    loss = np.array(drivetrain.efficiency_to_loss(data).z)
    # motoring at tau = 1, s = 1: |tau s| (1/0.9 - 1); generating: |tau s| (1 - 0.9)
    assert loss[2, 2] == pytest.approx(1 / 0.9 - 1)
    assert loss[0, 2] == pytest.approx(0.1)
    assert loss[1, 1] == 0.0


BATTERY = dict(cells_series=204.0, cells_parallel=3.0, cell_capacity_ah=100.0,
               cell_resistance_mohm=1.0, connection_factor=1.2,
               activation_energy_j_per_mol=25000.0, coulombic_efficiency=0.998,
               soc_min_frac=0.0, soc_max_frac=1.0, max_charge_c_rate=3.0,
               max_discharge_c_rate=5.0, cell_voltage_min_v=2.0, cell_voltage_max_v=3.6)


def battery_tables():
    return (battery.OCV_CELL.resolve().encode("ocv"),
            battery.RESISTANCE_SOC.resolve().encode("r"))


PACK = {k: BATTERY[k] for k in ("cells_series", "cells_parallel", "cell_capacity_ah",
                                 "cell_resistance_mohm", "connection_factor",
                                 "activation_energy_j_per_mol")}
LIMITS = {k: BATTERY[k] for k in ("cells_series", "connection_factor", "coulombic_efficiency",
                                   "soc_min_frac", "soc_max_frac", "max_charge_c_rate",
                                   "max_discharge_c_rate", "cell_voltage_min_v",
                                   "cell_voltage_max_v")}


@pytest.mark.parametrize("fn", both("rint_battery", "pack"))
def test_battery_pack_capacity_and_resistance(fn):
    q, r = fn(capacity_factor=1.0, resistance_factor=1.0, battery_temp_degc=25.0, **PACK)
    assert q == 300.0 and r == pytest.approx(1e-3 * 204 / 3 * 1.2)
    # ageing shrinks capacity and raises resistance; cold raises resistance (Arrhenius)
    q_aged, r_aged = fn(capacity_factor=0.8, resistance_factor=1.3, battery_temp_degc=25.0, **PACK)
    assert q_aged == 240.0 and r_aged == pytest.approx(1.3 * r)
    r_cold = fn(capacity_factor=1.0, resistance_factor=1.0, battery_temp_degc=0.0, **PACK)[1]
    assert r_cold / r == pytest.approx(math.exp(25000 / 8.314 * (1 / 273.15 - 1 / 298.15)))


@pytest.mark.parametrize("fn", both("rint_battery", "state"))
def test_battery_state(fn):
    ocv_table, r_table = battery_tables()
    r_pack = 1e-3 * 204 / 3 * 1.2
    def state(soc_frac, **limits):
        return fn(soc_frac=soc_frac, bms_open=0.0, charger_connected=0.0, capacity_ah=300.0,
                  pack_resistance_ohm=r_pack, dt_s=0.1, **{**LIMITS, **limits},
                  ocv_cell_v=ocv_table, resistance_soc_factor=r_table)

    ocv, r, charge_a, charge_w, discharge_w = state(0.5)
    assert ocv == pytest.approx(204 * 3.270)  # A123 OCV at 50 %
    assert r == pytest.approx(r_pack)  # f(50 %) = 1
    assert charge_a == 900.0 and charge_w == pytest.approx(900 * (ocv + r * 900))
    assert discharge_w == pytest.approx(1500 * (ocv - r * 1500))
    # the SoC factor: an empty cell has the larger resistance
    assert state(0.0)[1] > r
    # a full pack accepts no charge; an empty one gives no power
    assert state(1.0)[2] == 0.0
    assert state(0.05, soc_min_frac=0.1)[4] == 0.0


@pytest.mark.parametrize("fn", both("rint_battery", "state"))
def test_the_cell_voltage_window_caps_discharge_and_charge_current(fn):
    """A cold pack (ten times the resistance) at 30 % SoC: the discharge current is the one
    that puts a cell at V_min (its share of the resistance, without busbars, R / N_s k_conn);
    the charge current the one that puts it at V_max; both far below the C-rates."""
    ocv_table, r_table = battery_tables()
    r_cold = 10 * 1e-3 * 204 / 3 * 1.2
    closed = {"bms_open": 0.0, "charger_connected": 0.0}
    ocv, r, charge_a, charge_w, discharge_w = fn(
        soc_frac=0.3, capacity_ah=300.0, pack_resistance_ohm=r_cold, dt_s=0.1, **LIMITS,
        **closed, ocv_cell_v=ocv_table, resistance_soc_factor=r_table)
    ocv_cell, per_cell_ohm = ocv / 204, r / (204 * 1.2)
    discharge_a = (ocv_cell - 2.0) / per_cell_ohm
    assert discharge_a < 1500 and discharge_w == pytest.approx(discharge_a * (ocv - r * discharge_a))
    assert charge_a == pytest.approx((3.6 - ocv_cell) / per_cell_ohm) and charge_a < 900
    # a looser window lets more through; V_max at or below the OCV lets no charge in
    looser = {**LIMITS, "cell_voltage_min_v": 1.5}
    assert fn(soc_frac=0.3, capacity_ah=300.0, pack_resistance_ohm=r_cold, dt_s=0.1, **looser,
              **closed, ocv_cell_v=ocv_table, resistance_soc_factor=r_table)[4] > discharge_w
    full = {**LIMITS, "cell_voltage_max_v": 3.3}
    assert fn(soc_frac=0.9, capacity_ah=300.0, pack_resistance_ohm=r_cold, dt_s=0.1, **full,
              **closed, ocv_cell_v=ocv_table, resistance_soc_factor=r_table)[2] == 0.0
    # a pack the BMS holds open gives and takes nothing, until a charger connects
    held = {"bms_open": 1.0, "charger_connected": 0.0}
    assert fn(soc_frac=0.3, capacity_ah=300.0, pack_resistance_ohm=r_cold, dt_s=0.1, **LIMITS,
              **held, ocv_cell_v=ocv_table, resistance_soc_factor=r_table)[2:] == (0.0, 0.0, 0.0)
    plugged = {"bms_open": 1.0, "charger_connected": 1.0}
    assert fn(soc_frac=0.3, capacity_ah=300.0, pack_resistance_ohm=r_cold, dt_s=0.1, **LIMITS,
              **plugged, ocv_cell_v=ocv_table, resistance_soc_factor=r_table)[2] == charge_a


@pytest.mark.parametrize("fn", both("rint_battery", "update"))
def test_battery_update_current_and_soc(fn):
    ocv, r, q = 660.0, 0.08, 300.0
    cells = {"cells_series": 204.0, "connection_factor": 1.2, "bms_open": 0.0,
             "charger_connected": 0.0, "soc_min_frac": 0.0}
    current, voltage, soc_next, ohmic, coulombic, shortfall, cell_v, open_next = fn(
        battery_power_w=100e3, soc_frac=0.5, ocv_v=ocv, resistance_ohm=r, capacity_ah=q, dt_s=0.1,
        coulombic_efficiency=0.998, **cells)
    assert current * voltage == pytest.approx(100e3)
    # a cell's voltage: its share of the OCV less its share of the drop, busbars left out
    assert cell_v == pytest.approx((ocv - r * current / 1.2) / 204) and cell_v > voltage / 204
    assert open_next == 0.0
    # the step that empties the pack off a charger opens it; a charger closes it again
    emptied = {**cells, "soc_min_frac": 0.49999}
    assert fn(battery_power_w=100e3, soc_frac=0.5, ocv_v=ocv, resistance_ohm=r, capacity_ah=q,
              dt_s=0.1, coulombic_efficiency=0.998, **emptied)[-1] == 1.0
    assert fn(battery_power_w=0.0, soc_frac=0.5, ocv_v=ocv, resistance_ohm=r, capacity_ah=q,
              dt_s=0.1, coulombic_efficiency=0.998, **{**cells, "bms_open": 1.0,
                                                     "charger_connected": 1.0})[-1] == 0.0
    assert voltage == pytest.approx(ocv - r * current)
    assert ohmic == pytest.approx(r * current**2)
    assert soc_next == pytest.approx(0.5 - current * 0.1 / (3600 * q))
    assert coulombic == 0.0 and shortfall == 0.0
    # charging: coulombic efficiency applies to the stored charge
    current, _, soc_next, _, coulombic, _, _, _ = fn(battery_power_w=-100e3, soc_frac=0.5, ocv_v=ocv,
                                                  resistance_ohm=r, capacity_ah=q, dt_s=0.1,
                                                  coulombic_efficiency=0.998, **cells)
    assert current < 0 and soc_next == pytest.approx(0.5 - 0.998 * current * 0.1 / (3600 * q))
    assert coulombic == pytest.approx(0.002 * ocv * -current)
    # beyond the pack's maximum power OCV^2 / 4R the shortfall is reported, not hidden
    *_, shortfall, _, _ = fn(battery_power_w=2e6, soc_frac=0.5, ocv_v=ocv, resistance_ohm=r,
                          capacity_ah=q, dt_s=0.1, coulombic_efficiency=0.998, **cells)
    assert shortfall == pytest.approx(2e6 - ocv**2 / (4 * r))


@pytest.mark.parametrize("fn", both("grid_charger"))
def test_grid_charger(fn):
    ocv, r = 660.0, 0.08
    base = dict(charger_connected=1.0, charger_rating_w=math.nan, cc_current_a=900.0,
                cv_taper=1.0, charge_current_max_a=900.0, ocv_v=ocv, resistance_ohm=r,
                motor_power_w=0.0, dc_load_w=5000.0, time_s=0.0, power_kw=450.0,
                efficiency=0.95, delivered_frac=1.0, pulse_period_s=10.0, pulse_duty=1.0,
                pulse_low_frac=0.0)
    dc, grid = fn(**base)
    assert dc == pytest.approx(450e3) and grid == pytest.approx(450e3 / 0.95)
    assert fn(**{**base, "charger_connected": 0.0}) == (0.0, 0.0)
    # the profile's rating wins over the parameter; CC-limited below it
    dc, _ = fn(**{**base, "charger_rating_w": 18e3})
    assert dc == pytest.approx(18e3)
    # a rating stated on the grid side delivers its share to the bus, which the grid pays
    # the charger's losses on
    dc, grid = fn(**{**base, "charger_rating_w": 300e3, "delivered_frac": 0.93})
    assert dc == pytest.approx(279e3) and grid == pytest.approx(279e3 / 0.95)
    assert fn(**{**base, "delivered_frac": 0.93})[0] == pytest.approx(0.93 * 450e3)
    dc, _ = fn(**{**base, "cc_current_a": 100.0})
    assert dc == pytest.approx(100 * (ocv + r * 100) + 5000.0)
    # two separate limits: a depot charger rated below what the pack accepts at high SoC
    # (I_cc taper = 900 A x 0.56 at 90 %) delivers its rating; a fast one is held to it
    taper = math.exp(-0.23 * 2.5)
    dc, _ = fn(**{**base, "charger_rating_w": 18e3, "cv_taper": taper})
    assert dc == pytest.approx(18e3)
    dc, _ = fn(**{**base, "cv_taper": taper})
    assert dc == pytest.approx(900 * taper * (ocv + r * 900 * taper) + 5000.0)
    # the pack's own limit (C-rate, SoC ceiling, cell voltage window) caps it too
    dc, _ = fn(**{**base, "charge_current_max_a": 50.0})
    assert dc == pytest.approx(50 * (ocv + r * 50) + 5000.0)
    # pulsed: off in the second half of each period
    pulsed = {**base, "pulse_duty": 0.5}
    assert fn(**{**pulsed, "time_s": 2.0})[0] == pytest.approx(450e3)
    assert fn(**{**pulsed, "time_s": 7.0})[0] == pytest.approx(5000.0)


def test_lookups_interpolate_and_clamp():
    from ebus_env.effects.tables import encode1, encode2

    t1 = encode1("t", [0.0, 1.0, 3.0], [0.0, 10.0, 30.0])  # resampled to a step of 1
    assert lookup1(t1, 2.5) == pytest.approx(25.0)
    assert lookup1(t1, -1.0) == 0.0 and lookup1(t1, 9.0) == 30.0
    t2 = encode2("t", [0.0, 1.0], [0.0, 2.0], [[0.0, 2.0], [10.0, 12.0]])
    assert lookup2(t2, 0.5, 1.0) == pytest.approx(6.0)
    assert lookup2(t2, 5.0, -5.0) == pytest.approx(10.0)


def test_ocv_table_reproduced_exactly_on_its_breakpoints():
    data = battery.OCV_CELL.presets["lfp_a123"]
    table = data.encode("ocv")
    for soc, volts in zip(data.x, data.y, strict=True):
        assert lookup1(table, soc) == pytest.approx(volts, abs=1e-12)


def test_effects_in_a_batched_run_match_their_equations(model12):
    """The same equations hold per member when a batch of parameter sets runs at once."""
    from tests.conftest import constant_profile

    coefs = np.array([0.5, 0.7, 0.9])
    loads = np.array([0.0, 0.5, 1.0])
    rows = [{"aero_drag.drag_coef": c, "passenger_load.load_frac": f}
            for c, f in zip(coefs, loads, strict=True)]
    batch = model12.simulate_batch(constant_profile(10.0, 60.0), rows, soc_start=0.9,
                                   record=["aero_drag_n", "speed_mps", "mass_kg"], record_every=1)
    v = batch.record("speed_mps")
    np.testing.assert_allclose(batch.record("aero_drag_n"),
                               0.5 * 1.2 * coefs[:, None] * 7.5 * v**2, rtol=1e-5)
    np.testing.assert_allclose(batch.record("mass_kg")[:, 0], 13000 + 68 * 85 * loads, rtol=1e-6)


def test_tables_off_any_small_grid_are_approximated_not_exploded():
    from ebus_env.effects.tables import MAX_POINTS, encode1

    table = encode1("t", [0.0, 5.5, 5.5001, 24.0], [1.0, 1.0, 0.0, 0.0])
    assert int(table[2]) == MAX_POINTS
    assert lookup1(table, 2.0) == 1.0 and lookup1(table, 10.0) == 0.0


@pytest.mark.parametrize("fn", both("regen_soc_limit"))
def test_regen_soc_limit_derates_the_charge_limit_at_high_soc(fn):
    def share(speed_mps, soc_frac, demand_n=-10_000.0, max_decel_mps2=5.0):
        return fn(speed_mps=speed_mps, soc_frac=soc_frac, wheel_force_demand_n=demand_n,
                  road_force_n=1_000.0, effective_mass_kg=14_000.0, max_brake_decel_mps2=5.0,
                  regen_force_max_n=20_000.0, cutoff_speed_mps=1.5, max_share=1.0,
                  max_decel_mps2=max_decel_mps2, derate_soc_pct=90.0)

    assert share(1.0, 0.5) == 0.0  # below the cutoff
    assert share(5.0, 0.5) == 1.0
    # at 95 % the limit is half the drive's 20 kN: 10 kN, so 10 kN of braking stays regenerative
    assert share(5.0, 0.95) == pytest.approx(1.0)
    assert share(5.0, 0.975) == pytest.approx(0.5)  # 5 kN of 10
    assert share(5.0, 0.95, demand_n=-28_000.0) == pytest.approx(10.0 / 28.0)
    assert share(5.0, 1.0) == 0.0
    # the motor's 0.8 m/s^2 of a 14 t bus, 11.2 kN, binds below the derated limit (12 kN) at 94 %
    assert share(5.0, 0.94, demand_n=-28_000.0, max_decel_mps2=0.8) == pytest.approx(0.4)
    assert share(5.0, 0.98, demand_n=-28_000.0, max_decel_mps2=0.8) == pytest.approx(4.0 / 28.0)


@pytest.mark.parametrize("fn", both("passenger_schedule"))
def test_passenger_schedule_peaks(fn):
    from ebus_env.effects.vehicle import COMMUTER_SHAPE

    table = COMMUTER_SHAPE.resolve().encode("load_shape")
    assert fn(passenger_count=math.nan, time_of_day_h=8.0, base_frac=0.2, peak_frac=0.9,
              max_passengers=100.0, load_shape=table) == pytest.approx(90.0)
    assert fn(passenger_count=math.nan, time_of_day_h=12.0, base_frac=0.2, peak_frac=0.9,
              max_passengers=100.0, load_shape=table) == pytest.approx(100 * (0.2 + 0.7 * 0.4))
    assert fn(passenger_count=math.nan, time_of_day_h=2.0, base_frac=0.2, peak_frac=0.9,
              max_passengers=100.0, load_shape=table) == pytest.approx(20.0)
    assert fn(passenger_count=33.0, time_of_day_h=8.0, base_frac=0.2, peak_frac=0.9, max_passengers=100.0,
              load_shape=table) == 33.0


@pytest.mark.parametrize("fn", both("ambient_battery", "heat"))
def test_ambient_battery_follows_the_ambient_and_its_own_heat(fn):
    def heat(temp, loss_w, dt_s, tau_h=1.0, capacity=2e6):
        return fn(cell_temp_degc=temp, ambient_degc=0.0, battery_loss_w=loss_w, dt_s=dt_s,
                  time_constant_h=tau_h, heat_capacity_j_per_k=capacity)

    assert heat(20.0, 0.0, 3600.0) == pytest.approx(0.0)  # one time constant in one step
    assert heat(20.0, 0.0, 36.0) == pytest.approx(20.0 - 20.0 * 0.01)
    # 10 kW into 2 MJ/K for 100 s: +0.5 K
    assert heat(0.0, 10e3, 100.0) == pytest.approx(0.5)
    # steady state: the loss leaves through hA = C / tau, T - T_amb = Q tau / C = 3.6 K
    assert heat(3.6, 2e3, 100.0, tau_h=1.0) == pytest.approx(3.6)


def test_ambient_battery_reads_the_state_and_heats_after_the_battery(bus12):
    eff = get_effect("ambient_battery")
    assert eff.calls["main"].function(cell_temp_degc=-3.0) == -3.0
    # the heat call comes after the battery's update, whose loss it reads; the managed pack
    # leaves the optional call out and its step has none
    source = bus12.with_effect(eff).build().layout.source
    assert source.index("fx__rint_battery__update(") < source.index("fx__ambient_battery__heat(")
    assert "heat" not in get_effect("managed_temperature").calls
    assert "__heat(" not in bus12.build().layout.source


def test_a_slot_effect_may_leave_out_only_the_optional_calls():
    from ebus_env.effects.base import Call, Effect

    def temperature():
        return 20.0

    with pytest.raises(ValueError, match="call sites"):  # 'main' is not optional
        Effect("no_main", slot="battery_thermal",
               calls={"heat": Call(temperature, ("cell_temp_degc_next",))})
    with pytest.raises(ValueError, match="call sites"):  # no such call site
        Effect("extra_call", slot="battery_thermal",
               calls={"main": Call(temperature, ("battery_temp_degc",)),
                      "cool": Call(temperature, ("x",))})


def test_an_effect_offers_handles_by_name_and_unit():
    from ebus_env.effects.base import Param, effect
    from ebus_env.errors import ConfigError

    assert get_effect("grid_charger").handles["charge_pulse_duty"] == "pulse_duty"
    assert get_effect("cabin_hvac").handles == {"cabin_setpoint_degc": "setpoint_degc"}

    def heater(heater_kw):
        return 1e3 * heater_kw

    def declare(**handles):
        return effect("my_heater", sink="dc_load_w", register_effect=False, handles=handles,
                      params=[Param("heater_kw", 5.0, "kW", (0.0, 20.0), "Heater power")])(heater)

    assert declare().handles == {} and declare(charger_power_kw="heater_kw").handles
    with pytest.raises(ConfigError, match="Unknown handle.*'cabin_setpoint'.*cabin_setpoint_degc"):
        declare(cabin_setpoint="heater_kw")
    with pytest.raises(ValueError, match="'charge_pulse_duty' is in 1; parameter 'heater_kw' in kW"):
        declare(charge_pulse_duty="heater_kw")


def test_an_effect_numba_cannot_compile_is_named_with_its_file_line_and_fix():
    """From Python as from the CLI: which effect, file and line, and what to do."""
    from pathlib import Path

    from ebus_env.config import load_bus
    from ebus_env.errors import CompositionError

    source = Path(__file__).parent / "user_effects" / "uncompilable.py"
    model = load_bus("12m").with_effect(f"{source}:linear_drag").build()
    with pytest.raises(CompositionError) as info:
        model.compile()
    text = str(info.value)
    call_line = source.read_text().splitlines().index(
        "    return drag_of(coef_n_per_mps, speed_mps)") + 1
    assert "'linear_drag'" in text and f"{source}, line {call_line}" in text
    assert "@helper" in text and len(text.splitlines()) == 1


@pytest.mark.parametrize(("name", "returned", "expected"), [
    ("two_values", "returns 2 value(s) (float, float)", "must return 1 number(s): its contribution"),
    ("text_value", "returns 1 value(s) (str)", "must return 1 number(s): its contribution"),
    ("forgotten_state", "returns 1 value(s) (float)",
     "must return 2 number(s): its contribution, run_s_next"),
])
def test_an_effect_that_returns_what_its_sink_does_not_take_is_named(name, returned, expected):
    """Numba fails in the generated loop, where it names no line of the user's: the effect is
    found by calling it once in Python."""
    from pathlib import Path

    from ebus_env.config import load_bus
    from ebus_env.errors import CompositionError

    source = Path(__file__).parent / "user_effects" / "wrong_returns.py"
    model = load_bus("12m").with_effect(f"{source}:{name}").build()
    with pytest.raises(CompositionError) as info:
        model.compile()
    text = str(info.value)
    assert f"Effect '{name}' ({source}, line" in text and returned in text and expected in text



def test_an_effect_that_returns_nan_or_inf_fails_the_run_and_names_its_term():
    from pathlib import Path

    from ebus_env.config import load_bus
    from ebus_env.cycles import service_day
    from ebus_env.errors import EbusError

    bus = load_bus("12m").with_effect(
        f"{Path(__file__).parent / 'user_effects' / 'wrong_returns.py'}:divides_by_zero")
    model = bus.build()
    with pytest.raises(EbusError) as info:
        model.simulate(service_day("sort2", 0.1, model.dt_s, bus.service), soc_start=0.9)
    assert "produced NaN or infinite values in: " in str(info.value)
    assert "divides_by_zero" in str(info.value)
