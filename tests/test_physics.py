"""Physics properties of whole runs, per operating condition."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ebus_env.cycles import load_cycle, service_day
from tests.conftest import DT, constant_profile, standing_profile

ROOT = Path(__file__).resolve().parent.parent


def test_driving_lowers_soc(model12, sort2_hour):
    profile = sort2_hour.with_channels(charger_connected=0.0)
    result = model12.simulate(profile, soc_start=0.9)
    soc = result.trace("soc_frac")
    assert soc[-1] < soc[0] - 0.05
    # on every lap (two minutes) the SoC falls
    per_lap = soc[:: int(180 / DT)]
    assert np.all(np.diff(per_lap) < 0)


def test_standing_with_auxiliaries_lowers_soc_slowly(model12):
    result = model12.simulate(standing_profile(3600.0, ambient_degc=20.0), soc_start=0.9)
    s = result.summary()
    drop_pct = s["soc_start_pct"] - s["soc_end_pct"]
    loads_kwh = s["breakdown_kwh"]["auxiliaries"] + s["breakdown_kwh"]["cabin_hvac"]
    assert 0.5 < drop_pct < 5.0  # a few %/h: 4 kW auxiliaries + fans on 200 kWh
    assert s["distance_km"] == 0.0
    # the SoC drop is what the loads took, plus the pack's own losses
    assert s["battery_energy_kwh"] == pytest.approx(loads_kwh, rel=0.01)


def test_charging_raises_soc_and_never_past_full(model12):
    profile = standing_profile(3600.0, charger_connected=1.0, ambient_degc=20.0)
    result = model12.simulate(profile, soc_start=0.6)
    soc = result.trace("soc_frac")
    assert soc[-1] > 0.99
    assert soc.max() <= 1.0
    assert result.final_state[model12.state_names.index("soc_frac")] <= 1.0
    assert np.all(np.diff(soc) >= 0)  # on the charger the pack only gains
    assert result.summary()["peak_grid_kw"] == pytest.approx(450 / 0.95, rel=1e-6)


def test_charge_power_non_increasing_above_cccv_cutoff(model12):
    profile = standing_profile(3600.0, charger_connected=1.0, ambient_degc=20.0)
    result = model12.simulate(profile, soc_start=0.8)
    soc = result.trace("soc_frac")
    current = -result.trace("battery_current_a")
    above = soc > 0.875 + 1e-4
    assert above.sum() > 100
    assert np.all(np.diff(current[above]) <= 1e-3)
    # below the cutoff the current is flat (CC, capped by the charger's 450 kW)
    below = (soc < 0.87) & (soc > 0.81)
    assert np.ptp(current[below]) / current[below].mean() < 0.02


def test_regen_is_zero_below_cutoff_speed(model12, sort2_hour):
    result = model12.simulate(sort2_hour)
    speed = result.trace("speed_mps")
    motor = result.trace("motor_force_n")
    cutoff = model12.params[model12.param_index("regen_cutoff.cutoff_speed_mps")]
    braking = result.trace("wheel_force_n") < 0
    assert np.all(motor[braking & (speed <= cutoff)] == 0.0)
    assert np.any(motor[braking & (speed > cutoff)] < 0)  # and it does regenerate above


def test_series_blending_caps_the_motors_deceleration(model12, sort2_hour):
    """With the motor allowed 0.5 m/s^2 alone, harder braking goes to the friction brakes: the
    motor's braking force never exceeds m_eff a_regen, the pack recovers less, and the braking
    energy the motor gives up is what the friction brakes take."""
    limited = model12.param_vector(model12.carry_over({"regen_cutoff.max_decel_mps2": 0.5}))
    free, capped = model12.simulate(sort2_hour), model12.simulate(sort2_hour, limited)
    motor = capped.trace("motor_force_n")
    limit_n = capped.trace("effective_mass_kg") * 0.5
    assert np.all(-motor <= limit_n * (1 + 1e-6))
    assert np.any(free.trace("motor_force_n") < -limit_n * 1.4)  # SORT 2 brakes at 0.83 m/s^2
    b_free, b_capped = free.summary()["breakdown_kwh"], capped.summary()["breakdown_kwh"]
    assert b_capped["friction_brake"] > b_free["friction_brake"] + 2.0  # of ~20 kWh an hour
    assert capped.summary()["battery_energy_kwh"] > free.summary()["battery_energy_kwh"] + 2.0
    # the same wheel: the speed trace is followed as closely with friction as with the motor
    assert np.allclose(capped.trace("speed_mps"), free.trace("speed_mps"), atol=1e-6)


def test_an_unmanaged_pack_warms_by_its_own_losses(bus12, sort2_hour):
    """A pack without thermal management, driven an hour at -5 degC from the ambient: its heat
    balance C dT = (R I^2 - C/tau (T - T_amb)) dt closes over the run, it ends warmer than the
    air, and warmer with a smaller heat capacity (the same losses heat less mass more)."""
    from ebus_env.effects import get_effect

    model = bus12.with_effect(get_effect("ambient_battery")).build()
    profile = sort2_hour.with_channels(ambient_degc=-5.0, charger_connected=0.0)
    capacity_j_per_k, tau_s = 2e6, 3 * 3600.0
    run = model.simulate(profile, soc_start=0.9)
    temp = run.trace("battery_temp_degc").astype(np.float64)
    loss_w = run.trace("battery_loss_w").astype(np.float64)
    end = run.final_state[model.state_names.index("cell_temp_degc")]
    heat_j = np.sum(loss_w - capacity_j_per_k / tau_s * (temp + 5.0)) * DT
    assert temp[0] == pytest.approx(-5.0)
    assert capacity_j_per_k * (end - temp[0]) == pytest.approx(heat_j, rel=1e-4)
    assert 0.3 < end + 5.0 < 10.0  # a few kW of loss into 2 MJ/K for an hour
    light = model.param_vector(model.carry_over({"ambient_battery.heat_capacity_j_per_k": 1e6}))
    warmer = model.simulate(profile, light, soc_start=0.9)
    assert warmer.final_state[model.state_names.index("cell_temp_degc")] > end + 0.2
    assert warmer.trace("resistance_ohm")[-1] < run.trace("resistance_ohm")[-1]


def test_energy_balance_closes_over_a_full_day(model12, sort2_day):
    """Battery energy from the SoC trace (OCV x dSoC x capacity) equals the sum of every
    contribution and loss the summary reports, within 0.1 % of the pack's throughput."""
    result = model12.simulate(sort2_day, soc_start=0.95)
    s = result.summary()
    soc = result.trace("soc_frac").astype(np.float64)
    ocv = result.trace("ocv_v").astype(np.float64)
    capacity = result.trace("capacity_ah")[0]
    soc_next = np.append(soc[1:], result.final_state[model12.state_names.index("soc_frac")])
    chemical = np.sum(ocv * (soc - soc_next)) * capacity * 3600.0 / 3.6e6
    throughput = np.sum(np.abs(ocv * (soc - soc_next))) * capacity * 3600.0 / 3.6e6
    b = s["breakdown_kwh"]
    uses = (b["inertia_net"] + b["aero_drag"] + b["rolling_resistance"] + b["road_grade"]
            + b["friction_brake"] + b["drivetrain_loss"] + b["auxiliaries"] + b["cabin_hvac"]
            + b["battery_ohmic_loss"] + b["coulombic_loss"] - b["charging"])
    assert throughput > 100.0  # the day cycles the pack a lot: a meaningful test
    assert abs(chemical - uses) < 1e-3 * throughput
    assert s["battery_energy_kwh"] == pytest.approx(chemical, abs=1e-3 * throughput)
    # the kinetic energy term is the change of 1/2 m_eff v^2 (zero over a day from rest to rest)
    assert abs(b["inertia_net"]) < 1e-3 * b["traction"]


def test_12m_on_sort2_without_hvac_in_published_range(model12_nohvac, sort2_day):
    s = model12_nohvac.simulate(sort2_day, soc_start=0.95, record=False).summary()
    assert 0.8 <= s["kwh_per_km"] <= 1.6
    assert s["distance_km"] == pytest.approx(13.5 * 18.6 * 0.91, rel=0.05)  # layovers: ~9 %


def test_18m_uses_more_than_12m(bus12, bus18, model12, sort2_hour):
    model18 = bus18.build()
    s12 = model12.simulate(sort2_hour, soc_start=0.9, record=False).summary()
    s18 = model18.simulate(sort2_hour, soc_start=0.9, record=False).summary()
    assert s18["kwh_per_km"] > 1.2 * s12["kwh_per_km"]


def test_consumption_rises_with_mean_speed_on_scaled_cycles(bus12, model12_nohvac):
    """SORT 2 scaled to higher mean speeds: drag and braking losses grow; the constant
    auxiliary load per km shrinks, so at low speeds the total can stay flat."""
    cycle = load_cycle("sort2")
    totals, driving = [], []
    for factor in (0.7, 0.85, 1.0, 1.15, 1.3):
        profile = service_day(cycle, 2.0, DT, bus12.service, cycle.mean_speed_kmh * factor)
        s = model12_nohvac.simulate(profile, soc_start=0.9, record=False).summary()
        totals.append(s["kwh_per_km"])
        driving.append((s["consumed_energy_kwh"] - s["breakdown_kwh"]["auxiliaries"])
                       / s["distance_km"])
    assert np.all(np.diff(driving) > 0)
    assert np.all(np.diff(totals[2:]) > 0)


def test_bus_falls_behind_an_infeasible_reference(bus12):
    weak = bus12.without_effect("cabin_hvac").build()
    profile = service_day("sort3", 0.5, DT, bus12.service)
    strong = weak.simulate(profile, soc_start=0.9).summary()
    slow = weak.simulate(profile, {"efficiency_map.peak_power_kw": 40.0}, soc_start=0.9)
    assert strong["max_behind_m"] < 2.0
    assert slow.summary()["max_behind_m"] > 50.0
    assert slow.summary()["distance_km"] < strong["distance_km"]
    assert np.all(slow.trace("distance_behind_m") >= -1e-3)


def test_top_speed_caps_the_reference(model12):
    result = model12.simulate(constant_profile(30.0, 200.0))
    assert result.trace("speed_mps").max() <= 80 / 3.6 + 1e-6
    assert result.summary()["max_behind_m"] > 100


def test_tracking_is_close_on_a_feasible_cycle(model12, sort2_hour):
    result = model12.simulate(sort2_hour)
    error = result.trace("speed_mps") - result.trace("speed_ref_mps")
    assert np.abs(error).max() < 0.3
    assert result.summary()["max_behind_m"] < 1.0


def test_passengers_grade_and_cold_cost_energy(model12):
    flat = constant_profile(12.0, 600.0, ambient_degc=20.0)
    base = model12.simulate(flat, soc_start=0.9, record=False).summary()
    full = model12.simulate(flat.with_channels(passenger_count=85.0), soc_start=0.9,
                            record=False).summary()
    uphill = model12.simulate(flat.with_channels(grade_frac=0.03), soc_start=0.9,
                              record=False).summary()
    downhill = model12.simulate(flat.with_channels(grade_frac=-0.03), soc_start=0.9,
                                record=False).summary()
    cold = model12.simulate(flat.with_channels(ambient_degc=-5.0), soc_start=0.9,
                            record=False).summary()
    assert full["consumed_energy_kwh"] > base["consumed_energy_kwh"]
    assert uphill["consumed_energy_kwh"] > base["consumed_energy_kwh"]
    assert downhill["battery_energy_kwh"] < 0  # 3 % down at 43 km/h: regen beats the loads
    assert uphill["breakdown_kwh"]["road_grade"] > 0 > downhill["breakdown_kwh"]["road_grade"]
    assert cold["breakdown_kwh"]["cabin_hvac"] > 3 * base["breakdown_kwh"]["cabin_hvac"]


def test_pulsed_charging_halves_charge_in_cc_phase(model12):
    profile = standing_profile(600.0, charger_connected=1.0, ambient_degc=20.0)
    steady = model12.simulate(profile, soc_start=0.3, record=False).summary()
    pulsed = model12.simulate(profile, {"grid_charger.pulse_duty": 0.5}, soc_start=0.3,
                              record=False).summary()
    gain = steady["soc_end_pct"] - 30.0
    assert (pulsed["soc_end_pct"] - 30.0) == pytest.approx(0.5 * gain, rel=0.05)
    assert pulsed["peak_grid_kw"] == pytest.approx(steady["peak_grid_kw"], rel=1e-6)


def test_battery_ageing_drains_faster(model12, sort2_hour):
    profile = sort2_hour.with_channels(charger_connected=0.0)
    new = model12.simulate(profile, soc_start=0.9, record=False).summary()
    aged = model12.simulate(profile, {"static_rcd.rcd_frac": 0.2}, soc_start=0.9,
                            record=False).summary()
    drop_new = new["soc_start_pct"] - new["soc_end_pct"]
    drop_aged = aged["soc_start_pct"] - aged["soc_end_pct"]
    assert drop_aged == pytest.approx(drop_new / 0.8, rel=0.02)


def test_auxiliary_schedule_follows_the_clock(bus12, sort2_hour):
    bus = bus12.without_effect("cabin_hvac").with_effect("aux_schedule")
    schedule = {"x": [0, 5.5, 5.6, 24], "y": [1000, 1000, 0, 0]}  # on until 05:30, off by 05:36
    model = load_bus_overlay(bus, {"tables": {"aux_schedule": {"schedule_w": schedule}}})
    result = model.simulate(sort2_hour, soc_start=0.9)  # the day starts at 05:00
    load = result.trace("aux_schedule_w")
    clock = sort2_hour.channel("time_of_day_h")
    assert np.all(load[clock < 5.49] == pytest.approx(1000.0))
    assert np.all(load[clock > 5.6] == 0.0)
    assert result.summary()["breakdown_kwh"]["aux_schedule"] == pytest.approx(0.55, rel=0.01)


def load_bus_overlay(bus, overlay):
    return bus.overlay(overlay).build()


@pytest.mark.parametrize("trip", ["B16", "B03", "B02"])
def test_ohmic_heat_explains_the_i3_packs_warming_on_winter_trips(trip):
    """Real data: on the TUM BMW i3's winter trips (not the reserved ones) the logged pack
    temperature rises 2-3 K at 3-8 degC outside. The unmanaged pack with the heat capacity of
    the i3's 230 kg pack, warmed by its R I^2, follows it within 1.1 K RMSE and halves the
    error of a pack that only follows the ambient, which ends 3 K too cold."""
    from benchmarks.compare_pack_temperature import errors_k

    rmse_ambient_k, end_ambient_k = errors_k(trip, joule_heat=False)
    rmse_heat_k, end_heat_k = errors_k(trip, joule_heat=True)
    assert end_ambient_k < -2.5 and abs(end_heat_k) < 1.0
    assert rmse_heat_k < 1.1 and rmse_heat_k < 0.6 * rmse_ambient_k


def test_a_cold_pack_is_held_at_its_cell_voltage_floor(bus12):
    """An unmanaged 12 m pack at -30 degC and 30 % SoC up a 6 % grade: the BMS derates the
    discharge so that no cell drops below V_min (2.0 V, the LFP cell's data sheet); the bus is
    slower than one whose BMS allowed 1.5 V, and the trace and summary say where."""
    model = bus12.with_effect("ambient_battery").build()
    profile = constant_profile(25.0, 90.0, ambient_degc=-30.0, grade_frac=0.06)
    values = {"ambient_battery.initial_offset_k": 0.0}
    run = model.simulate(profile, model.param_vector(model.carry_over(values)), soc_start=0.3)
    cell_v = run.trace("cell_voltage_v")
    assert cell_v.min() == pytest.approx(2.0, abs=2e-3)  # at the floor, not below it
    limited = run.trace("battery_limited") > 0.5
    assert limited.sum() > 100 and run.summary()["battery_limited_s"] > 10.0
    looser = model.param_vector(model.carry_over({**values, "rint_battery.cell_voltage_min_v": 1.5}))
    free = model.simulate(profile, looser, soc_start=0.3)
    assert free.trace("cell_voltage_v").min() < 1.9
    assert free.summary()["distance_km"] > run.summary()["distance_km"] * 1.02
    # what the pack can give and take, every step: its available power
    available = run.trace("discharge_power_max_w")[limited]
    used = (run.trace("motor_power_w") + run.trace("dc_load_w"))[limited] / available
    assert np.median(used) == pytest.approx(1.0, abs=1e-3) and used.max() < 1.001


def test_a_depot_charger_gives_its_rating_up_to_the_packs_acceptance(bus18):
    """An 18 kW depot charger on the 18 m bus's pack, from 85 % SoC: the CV taper is the
    pack's acceptance, I_cc taper (2.5 C x 184.5 Ah x taper); the charger delivers its full
    rating until that falls below the current of 18 kW (above 99 % SoC), then what the pack
    accepts. The charger and the pack are two limits, not one scaled by the other (which
    would give 18 kW x 0.18 at 95 % SoC)."""
    model = bus18.build()
    profile = standing_profile(4 * 3600.0, charger_connected=1.0, charger_rating_w=18e3,
                               ambient_degc=20.0)
    run = model.simulate(profile, soc_start=0.85)
    soc = run.trace("soc_frac")
    dc_w = run.trace("charger_power_w")
    accepts_a = np.minimum(run.trace("cc_current_a") * run.trace("cv_taper"),
                           run.trace("charge_current_max_a"))  # CC/CV, C-rate, SoC, voltage
    current_a = -run.trace("battery_current_a")
    # every step: the charger at its rating, or the pack at what it accepts (never beyond)
    at_rating = np.isclose(dc_w, 18e3, rtol=1e-4)
    at_acceptance = np.isclose(current_a, accepts_a, rtol=1e-3, atol=1e-3)
    assert np.all(at_rating | at_acceptance) and np.all(current_a <= accepts_a + 1e-3)
    assert at_rating[(soc > 0.95) & (soc < 0.96)].all()  # above the CC/CV cutoff, still rated
    assert (at_acceptance & ~at_rating).sum() > 100 and soc[~at_rating].min() > 0.99


def test_an_empty_pack_strands_the_bus_and_its_loads_stop(bus12, sort2_hour):
    """At soc_min_frac the BMS opens the pack: traction and the DC loads stop, the SoC stays
    at the floor, and the summary gives when and where the bus stranded; the energy balance
    still closes with the unserved loads counted out."""
    model = bus12.build()
    values = model.carry_over({"rint_battery.soc_min_frac": 0.1})
    profile = sort2_hour.with_channels(charger_connected=0.0)
    run = model.simulate(profile, model.param_vector(values), soc_start=0.16)
    s = run.summary()
    soc = run.trace("soc_frac")
    assert soc.min() > 0.1 - 1e-4  # one step's draw below the floor at most
    stranded = run.trace("stranded") > 0.5
    first = np.flatnonzero(stranded)[0]
    assert s["stranded_at_h"] == pytest.approx(first * DT / 3600.0, abs=DT / 3600.0)
    assert s["stranded_at_km"] == pytest.approx(run.trace("distance_m")[first] / 1e3, abs=0.01)
    # nothing charges it again: the loads stay off but while the bus rolls out on regen
    regen = run.trace("motor_power_w") < 0.0
    assert np.all(stranded[first:] | regen[first:]) and np.all(soc[first:] == soc[first])
    assert run.trace("speed_mps")[-1] == 0.0 and s["stranded_h"] > 0.1
    carried = run.trace("dc_load_w") - np.maximum(-run.trace("motor_power_w"), 0.0)
    assert np.allclose(run.trace("unserved_load_w")[stranded], carried[stranded], rtol=1e-5)
    b = s["breakdown_kwh"]
    uses = sum(b[k] for k in ("inertia_net", "aero_drag", "rolling_resistance", "friction_brake",
                              "drivetrain_loss", "auxiliaries", "cabin_hvac",
                              "battery_ohmic_loss", "coulombic_loss")) - b["charging"]
    assert s["battery_shortfall_kwh"] > 0.5
    assert s["battery_energy_kwh"] == pytest.approx(uses - s["battery_shortfall_kwh"], rel=1e-3)


def test_friction_brakes_never_propel_and_no_limit_is_written_as_missing(model12, sort2_hour):
    """Friction brakes only hold back, also in the step where a bus comes to a stop; and
    "no limit" (a charge limit off the charger) is inf inside the kernel, a missing value in
    the written trace."""
    run = model12.simulate(sort2_hour, soc_start=0.9)
    assert run.trace("friction_brake_w").min() >= 0.0
    frame = run.trace_frame()
    off = frame["charger_connected"] < 0.5
    assert frame.loc[off, "cc_current_a"].isna().all()
    assert frame.loc[~off, "cc_current_a"].notna().all()
    assert not np.isinf(frame.to_numpy(float)).any()
    assert np.isinf(run.trace("cc_current_a")[off.to_numpy()]).all()  # inside: inf
