"""The out-of-family truth simulator (benchmarks/truth): physics, degradation, reproducibility."""

from __future__ import annotations

import ast
import dataclasses
import io
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from benchmarks.truth import cases as truth_cases
from benchmarks.truth.days import PLAN_COLUMNS, route_day
from benchmarks.truth.degrade import SOC_STEP_PCT, degrade
from benchmarks.truth.sim import OCV_TABLES, ocv_cell_v, simulate
from benchmarks.truth.vehicles import AIR_DENSITY_KG_PER_M3, GRAVITY_MPS2, nominal

TRUTH_DIR = Path(__file__).resolve().parents[1] / "benchmarks" / "truth"


def flat_plan(seconds: int, speed_mps: float = 0.0, *, charging: bool = False,
              charger_kw: float = 0.0, ramp_s: float = 0.0) -> pd.DataFrame:
    """A hand-made plan: flat, mild, empty; speed ramps from 0 over ``ramp_s``."""
    t = np.arange(seconds, dtype=float)
    speed = speed_mps * np.clip(t / ramp_s, 0.0, 1.0) if ramp_s else np.full(seconds, speed_mps)
    plan = pd.DataFrame({
        "time_s": t, "clock_h": 10.0 + t / 3600.0, "speed_target_mps": speed,
        "grade_frac": 0.0, "altitude_m": 50.0, "door_open": 0, "charging": int(charging),
        "charger_kw": charger_kw if charging else 0.0, "ambient_degc": 15.0, "passengers": 0,
        "solar_w_per_m2": 0.0, "distance_m": np.cumsum(speed), "leg": 0})
    plan.attrs["date"] = "2025-05-01"
    return plan


def test_nothing_under_benchmarks_truth_imports_ebus_env():
    """The truth sources are simulators of their own: none imports the model under test (the
    bench's runner, ``benchmarks/out_of_family.py``, diagnoses their days with it)."""
    files = sorted(TRUTH_DIR.glob("*.py"))
    assert len(files) >= 9
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            else:
                continue
            assert not any(n.split(".")[0] == "ebus_env" for n in names), path.name
    # nor at run time, through another module
    code = ("import sys, benchmarks.truth.cases, benchmarks.truth.sim, "
            "benchmarks.truth.backward_source; print('ebus_env' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=TRUTH_DIR.parents[1], check=True)
    assert done.stdout.strip() == "False"


@pytest.mark.parametrize("chemistry", sorted(OCV_TABLES))
def test_ocv_tables_increase_with_soc(chemistry):
    soc, volts = (np.array(a) for a in OCV_TABLES[chemistry])
    assert soc[0] == 0.0 and soc[-1] == 1.0
    assert np.all(np.diff(soc) > 0) and np.all(np.diff(volts) > 0)
    assert ocv_cell_v(chemistry, 0.5) == pytest.approx(np.interp(0.5, soc, volts))


def test_flat_constant_speed_draws_the_road_load_power():
    base = nominal("LFP")
    speed = 10.0
    trace = simulate(flat_plan(400, speed, ramp_s=60.0), base)
    steady = trace[trace["time_s"] > 200.0]
    assert np.allclose(steady["speed_mps"], speed, atol=1e-3)
    a_coef = base["c_rr0"] * base["curb_mass_kg"] * GRAVITY_MPS2
    road_n = (a_coef * (1.0 + base["c_rr_speed_per_mps"] * speed)
              + 0.5 * AIR_DENSITY_KG_PER_M3 * base["cda_m2"] * speed**2)
    assert steady["p_wheel_w"].to_numpy() == pytest.approx(road_n * speed, rel=1e-3)
    expected_batt_w = road_n * speed / base["drive_efficiency"] + base["aux_base_w"]
    assert steady["p_battery_w"].to_numpy() == pytest.approx(expected_batt_w, rel=1e-3)


def test_standing_with_auxiliaries_drains_soc_at_the_aux_rate():
    base = nominal("NMC")
    trace = simulate(flat_plan(3601), base, soc0_frac=0.7)
    drop = 0.7 - trace["soc_frac"].iloc[-1]
    # charge drawn = E / V_t; V_t hardly moves over 1 % of SoC
    mean_v = trace["battery_voltage_v"].mean()
    expected = base["aux_base_w"] * 3600.0 / mean_v / (3600.0 * base["capacity_ah"])
    assert drop == pytest.approx(expected, rel=2e-3)
    assert (trace["speed_mps"] == 0.0).all()


def test_charging_raises_soc_at_the_chargers_power():
    base = nominal("LFP")
    trace = simulate(flat_plan(600, charging=True, charger_kw=300.0), base, soc0_frac=0.5)
    soc = trace["soc_frac"].to_numpy()
    assert np.all(np.diff(soc[1:]) > 0)
    # below the CC/CV limits the charger gives its rated power; the aux load eats part
    charge_w = -(trace["p_battery_w"].iloc[10:])
    assert charge_w.to_numpy() == pytest.approx(300e3 - base["aux_base_w"], rel=1e-6)


def test_charging_stops_at_the_stop_soc():
    trace = simulate(flat_plan(1200, charging=True, charger_kw=450.0), nominal("LFP"),
                     soc0_frac=0.85, charge_stop_frac=0.9)
    assert 0.9 <= trace["soc_frac"].max() < 0.902
    assert trace["soc_frac"].iloc[-1] < trace["soc_frac"].max()  # then the aux load drains
    # the session, and with it the logged charging flag, ends; the bus stays plugged
    after = trace["soc_frac"].to_numpy().argmax() + 1
    assert (trace["plugged"] == 1).all()
    assert (trace["charging"].iloc[:after] == 1).all() and (trace["charging"].iloc[after:] == 0).all()
    assert (trace["charger_kw"].iloc[after:] == 0.0).all()


@pytest.fixture(scope="module")
def hilly_day():
    plan = route_day(np.random.default_rng(5), 1.5, 7.0, "rt45")
    base = nominal("NMC")
    return plan, base, simulate(plan, base, "road_grade")


def test_energy_balance_closes(hilly_day):
    _, base, tr = hilly_day
    end = tr.iloc[-1]
    wheel = end["e_road_j"] + end["e_grade_j"] + end["e_friction_j"] + end["e_kinetic_j"]
    assert end["e_wheel_j"] == pytest.approx(wheel, rel=1e-9, abs=1.0)
    assert end["e_battery_j"] == pytest.approx(end["e_ocv_j"] - end["e_battery_loss_j"],
                                               rel=1e-9)
    dc = end["e_drive_dc_j"] + end["e_aux_j"] + end["e_hidden_j"] - end["e_charger_j"]
    assert end["e_battery_j"] == pytest.approx(dc, rel=1e-9)
    # the grade's work is m g times the climb
    climb = tr["altitude_m"].iloc[-1] - tr["altitude_m"].iloc[0]
    assert end["e_grade_j"] == pytest.approx(base["curb_mass_kg"] * GRAVITY_MPS2 * climb,
                                             rel=1e-6, abs=1e3)
    assert end["e_friction_j"] > 0.0 and end["e_road_j"] > 0.0


def test_driver_follows_the_plan(hilly_day):
    plan, _, tr = hilly_day
    target = np.interp(tr["time_s"], plan["time_s"], plan["speed_target_mps"])
    assert np.sqrt(np.mean((tr["speed_mps"] - target) ** 2)) < 0.6
    assert tr["distance_m"].iloc[-1] == pytest.approx(plan["distance_m"].iloc[-1], rel=0.02)


def test_route_day_is_a_one_hertz_service_day():
    plan = route_day(np.random.default_rng(11), 3.0, 6.5, "rt44", climate="cold")
    assert list(plan.columns) == list(PLAN_COLUMNS)
    assert len(plan) == 3 * 3600 and np.all(np.diff(plan["time_s"]) == 1.0)
    moving = plan["speed_target_mps"] > 0.0
    assert not (moving & (plan["door_open"] == 1)).any()
    assert not (moving & (plan["charging"] == 1)).any()
    assert plan["charging"].sum() > 0 and plan["door_open"].sum() > 0
    assert plan["grade_frac"].abs().max() <= 0.10
    assert plan["passengers"].between(0, 85).all()
    assert plan["ambient_degc"].mean() < 8.0  # a winter day
    accel = np.diff(plan["speed_target_mps"])
    assert accel.max() < 1.4 and accel.min() > -1.5
    km_per_h = plan["distance_m"].iloc[-1] / 1000.0 / 3.0
    assert 8.0 < km_per_h < 25.0  # city-bus commercial speed, layovers included


def test_degraded_log_is_one_hertz_and_quantised(hilly_day):
    _, _, tr = hilly_day
    clean = tr[["time_s", "clock_h", "speed_mps", "soc_frac", "ambient_degc", "altitude_m",
                "charging", "charger_kw", "door_open"]].copy()
    clean.attrs["date"] = "2025-05-01"
    log = degrade(clean, np.random.default_rng(3))
    stamps = pd.to_datetime(log["timestamp"])
    assert (stamps.diff().dropna() == pd.Timedelta(seconds=1)).all()
    # King County's local time, with its summer offset
    assert log["timestamp"].iloc[0] == "2025-05-01T07:00:00-07:00"
    steps = log["soc_pct"] / SOC_STEP_PCT
    assert np.allclose(steps, np.round(steps), atol=1e-9)
    assert np.abs(log["soc_pct"] - 100.0 * tr["soc_frac"]).max() < 3.0
    assert (log["speed_kmh"][tr["speed_mps"] == 0.0] == 0.0).all()
    moving = tr["speed_mps"] > 1.0
    rel_err = log["speed_kmh"][moving] / (3.6 * tr["speed_mps"][moving]) - 1.0
    assert 0.0 < rel_err.abs().mean() < 0.1
    alt_err = log["altitude_m"] - tr["altitude_m"]
    assert 0.5 < alt_err.std() < 10.0
    assert "passengers" not in log and "battery_current_a" not in log
    rel = degrade(clean, np.random.default_rng(3), relative_time=True)
    assert "timestamp" not in rel and rel["time_s"].iloc[0] == 0.0
    assert np.all(np.diff(rel["time_s"]) == 1.0)


def test_a_bms_log_adds_current_and_voltage_and_leaves_the_rest_unchanged(hilly_day):
    """The pack's current and voltage, degraded like a Hall sensor's and a voltage
    divider's, are drawn after everything else: the other columns are the SoC-only log's."""
    _, _, tr = hilly_day
    clean = tr[["time_s", "clock_h", "speed_mps", "soc_frac", "ambient_degc", "charging",
                "charger_kw", "door_open", "battery_current_a", "battery_voltage_v"]].copy()
    clean.attrs.update(date="2025-05-01", capacity_ah=nominal("NMC")["capacity_ah"],
                       chemistry="NMC")
    soc_only = degrade(clean, np.random.default_rng(3))
    bms = degrade(clean, np.random.default_rng(3), current_voltage=True)
    pd.testing.assert_frame_equal(bms[soc_only.columns], soc_only)
    current, true_a = bms["battery_current_a"].to_numpy(), tr["battery_current_a"].to_numpy()
    gain, offset = np.polyfit(true_a, current, 1)  # the sensor's error, back from the log
    assert abs(gain - 1.0) <= 0.0105 and abs(offset) <= 0.55
    assert 0.3 < np.std(current - (gain * true_a + offset)) < 0.7  # 0.5 A rms and 0.1 A steps
    volts = bms["battery_voltage_v"].to_numpy() / tr["battery_voltage_v"].to_numpy()
    assert np.abs(volts - 1.0).max() < 0.005
    # the BMS counts that same sensor's current: its SoC moves as the logged current says
    counted = -np.cumsum(current) / (3600.0 * nominal("NMC")["capacity_ah"]) * 100.0
    moved = bms["soc_pct"].to_numpy() - bms["soc_pct"].iloc[0]
    assert np.abs(moved - (counted - counted[0])).max() < 0.1 + 0.015 * np.ptp(counted)


def test_the_bms_soc_drifts_with_its_sensor_and_is_pulled_back_at_rest():
    """Coulomb counting of the sensed current: with the sensor's offset the estimate drifts
    by offset x time / capacity; after ``REST_S`` at rest the BMS reads the OCV again and the
    estimate returns to the truth; a charge that reaches the top resets it too."""
    from benchmarks.truth import degrade as dg

    n = 7200
    capacity_ah = 300.0
    true_a = np.concatenate((np.full(3600, 60.0), np.zeros(3600)))  # 1 h at 60 A, then rest
    soc = 0.8 - np.concatenate(([0.0], np.cumsum(true_a[:-1]))) / (3600.0 * capacity_ah)
    sensed = true_a + np.where(np.arange(n) < 3600, 3.0, 0.0)  # a 3 A offset, the first hour
    rng = np.random.default_rng(1)
    est = dg.bms_soc_pct(soc, rng, sensed, true_a, capacity_ah, "NMC")
    start_error = est[0] - 100.0 * soc[0]
    # an hour in: the offset's drift, 3 A h of 300 A h = 1 point, beyond the gain's share
    drift = (est[3599] - 100.0 * soc[3599]) - start_error
    assert -1.0 - 0.015 * 20.0 - 0.1 < drift < -1.0 + 0.015 * 20.0 + 0.1
    # 20 min of rest, then the OCV reading pulls it back within a few of its time constants
    assert abs(est[3600 + int(dg.REST_S) - 10] - est[3599]) <= 0.1  # not before the rest
    assert abs(est[-1] - 100.0 * soc[-1]) < 0.1 + 3 * dg.START_ERROR_PCT["NMC"]
    assert abs((est[-1] - 100.0 * soc[-1]) - (est[3599] - 100.0 * soc[3599])) > 0.5
    # without the offset and gain error the count follows the truth exactly
    exact = dg.bms_soc_pct(soc, np.random.default_rng(1), true_a, true_a, capacity_ah / (
        1.0 + np.random.default_rng(1).uniform(-0.015, 0.015)), "NMC")
    steps = np.diff(exact[:3600])
    assert np.abs(np.cumsum(steps) - 100.0 * (soc[1:3600] - soc[0])).max() <= 0.1


def test_time_stamps_carry_the_local_offset_and_refuse_a_clock_change():
    from benchmarks.truth.degrade import time_stamps

    winter = time_stamps("2025-12-01", np.array([7.0, 23.999]), "America/Los_Angeles")
    assert list(winter) == ["2025-12-01T07:00:00-08:00", "2025-12-01T23:59:56-08:00"]
    assert time_stamps("2025-06-01", np.array([25.0]), "America/Los_Angeles")[0] == \
        "2025-06-02T01:00:00-07:00"  # after midnight: the next date
    with pytest.raises(ValueError):  # 02:30 does not exist on the spring-forward day
        time_stamps("2025-03-09", np.array([2.5]), "America/Los_Angeles")


def test_a_reference_day_is_a_normal_day_of_the_same_bus():
    """The bench's reference day of a case draws the same bus (every base parameter), drives
    another plan with another driver, and hides nothing; a case without a reference keeps
    its own streams."""
    case = truth_cases.cases(1, 0, effects=("cabin_heating",))[0]
    normal = truth_cases.reference_case(case)
    assert (normal.hidden, normal.climate, normal.route, normal.chemistry) == (
        None, "mild", case.route, case.chemistry)
    short = [dataclasses.replace(c, hours=0.3) for c in (case, normal)]
    (plan_a, base_a, *_), (plan_b, base_b, *_) = map(truth_cases.day_trace, short)
    preview = "driver_preview_s"  # the driver's, drawn with the day
    assert {k: v for k, v in base_a.items() if k != preview} == \
        {k: v for k, v in base_b.items() if k != preview}
    assert base_a[preview] != base_b[preview]
    assert not np.array_equal(plan_a["speed_target_mps"], plan_b["speed_target_mps"])
    # the plan, driver and log streams of its own seed, the bus's of the case's
    assert [s.entropy for s in truth_cases._streams(case)] == [case.seed] * 4
    assert [s.entropy for s in truth_cases._streams(normal)] == [case.seed + 1, case.seed,
                                                                 case.seed + 1, case.seed + 1]


@pytest.mark.parametrize("hidden", ["cabin_heating", "cold_battery"])
def test_another_day_of_a_bus_keeps_the_bus_and_its_effect_and_draws_the_day(hidden):
    """``--days-per-bus``: a same-bus day has the case's base parameters and the hidden
    effect's values that belong to the bus (a cabin's envelope, a pack's heat capacity); the
    plan, the start SoC and a cold pack's start above the air are the day's own."""
    case = truth_cases.cases(1, 0, effects=(hidden,))[0]
    days = [dataclasses.replace(c, hours=0.3)
            for c in (case, truth_cases.same_bus_case(case, 1), truth_cases.same_bus_case(case, 2))]
    assert len({c.case_id for c in days}) == 3 and len({c.seed for c in days}) == 3
    assert {c.bus_seed for c in days[1:]} == {case.seed}
    runs = [truth_cases.day_trace(c) for c in days]
    (plan_a, base_a, ph_a, day_a, _), (plan_b, base_b, ph_b, day_b, _) = runs[:2]
    preview = "driver_preview_s"
    assert {k: v for k, v in base_a.items() if k != preview} == \
        {k: v for k, v in base_b.items() if k != preview}
    assert not np.array_equal(plan_a["speed_target_mps"], plan_b["speed_target_mps"])
    assert day_a["soc0_frac"] != day_b["soc0_frac"]
    bus_level = set(ph_a) - truth_cases.DAY_LEVEL
    assert bus_level and all(ph_a[k] == ph_b[k] for k in bus_level)
    if hidden == "cold_battery":  # the night's: another start above the air each day
        assert len({r[2]["start_offset_k"] for r in runs}) == 3
    with pytest.raises(ValueError, match="day must be 1 or more"):
        truth_cases.same_bus_case(case, 0)


def test_a_short_case_is_byte_reproducible():
    case = dataclasses.replace(truth_cases.cases(1, 0, effects=("passenger_mass",))[0],
                               hours=0.4)
    log_a, truth_a = truth_cases.generate(case)
    log_b, truth_b = truth_cases.generate(case)
    assert truth_cases.log_bytes(log_a) == truth_cases.log_bytes(log_b)
    assert truth_a == truth_b
    back = pd.read_csv(io.BytesIO(truth_cases.log_bytes(log_a)), compression="gzip")
    assert list(back.columns) == list(log_a.columns) and "passengers" in back
    assert truth_a["expected_verdict"] == "passenger_mass"
    kg = truth_a["strength"]["passenger_mass.passenger_mass_kg"]
    assert kg == truth_a["physical"]["passenger_mass_kg"] and 65.0 <= kg <= 85.0


def test_an_oracle_log_adds_the_hidden_effects_own_power_and_leaves_the_rest_unchanged():
    """``--oracle``: ``logged_load_kw`` is the power the hidden effect adds, second by second;
    over the log it adds up to the effect's energy in the truth record."""
    case = dataclasses.replace(truth_cases.cases(1, 0, effects=("passenger_mass",))[0],
                               hours=0.4)
    log, truth = truth_cases.generate(case)
    oracle, record = truth_cases.generate(case, oracle=True)
    assert record["columns"] == truth["columns"] + ["logged_load_kw"]
    assert {**record, "columns": truth["columns"]} == truth
    pd.testing.assert_frame_equal(oracle[log.columns], log)
    load_kwh = oracle["logged_load_kw"].sum() / 3600.0
    assert load_kwh == pytest.approx(truth["summary"]["effect_kwh"], rel=0.01, abs=0.002)
    assert oracle["logged_load_kw"].min() < 0.0 < oracle["logged_load_kw"].max()  # regen too


def test_a_truths_cabin_is_the_library_ua_that_loses_the_same_heat_over_the_day():
    """The cabin's strength in the library's terms: the UA at which the library's cabin, with
    its own fresh air and door air, loses through walls, fresh air and open doors what the
    truth's cabin loses over the day, sum over t of conductance(t) (T_cab - T_amb)(t)."""
    from ebus_env.config import load_bus

    model = load_bus("12m").build()
    values = dict(zip(model.param_names, model.params, strict=True))
    cp = truth_cases.AIR_CP_J_PER_KG_K
    assert truth_cases.LIBRARY_FRESH_AIR_W_PER_K == pytest.approx(
        values["cabin_hvac.fresh_air_kg_per_s"] * cp)
    assert truth_cases.LIBRARY_DOOR_AIR_W_PER_K == pytest.approx(
        1.2 * cp * values["cabin_hvac.door_air_m3_per_s"])
    rng = np.random.default_rng(3)
    trace = pd.DataFrame({"cabin_temp_degc": 19.0 + rng.normal(0.0, 0.5, 3000),
                          "ambient_degc": rng.uniform(-8.0, 3.0, 3000),
                          "door_open": (rng.random(3000) < 0.15).astype(int)})
    ph = {"ua_w_per_k": 420.0, "fresh_air_kg_per_s": 0.33, "door_air_m3_per_s": 0.9}
    ua = truth_cases._strength("cabin_heating", ph, trace)["cabin_hvac.ua_w_per_k"]
    delta_k = (trace["cabin_temp_degc"] - trace["ambient_degc"]).to_numpy()
    door = trace["door_open"].to_numpy()
    truth_loss = np.sum((ph["ua_w_per_k"] + ph["fresh_air_kg_per_s"] * cp
                         + AIR_DENSITY_KG_PER_M3 * cp * ph["door_air_m3_per_s"] * door) * delta_k)
    library_loss = np.sum((ua + truth_cases.LIBRARY_FRESH_AIR_W_PER_K
                           + truth_cases.LIBRARY_DOOR_AIR_W_PER_K * door) * delta_k)
    assert library_loss == pytest.approx(truth_loss, rel=1e-12)
    # less fresh air than the library's (0.4 kg/s) but more door air: the two partly cancel
    assert ua == pytest.approx(420.0 - 0.07 * cp + 1.2 * cp * 0.2 * np.sum(door * delta_k)
                               / np.sum(delta_k))


def test_case_list_covers_every_effect_and_keeps_clock_bound_logs_stamped():
    listed = truth_cases.cases()
    by_effect = pd.Series([c.hidden or "control" for c in listed]).value_counts()
    assert (by_effect.drop("control") == 10).all() and by_effect["control"] == 30
    assert set(by_effect.index) - {"control"} == set(truth_cases.EFFECTS)
    assert len({c.seed for c in listed}) == len(listed)
    assert not any(c.relative_time for c in listed if c.hidden in truth_cases.CLOCK_BOUND)
    assert any(c.relative_time for c in listed)
    assert {c.chemistry for c in listed} == {"LFP", "NMC"}


@pytest.mark.parametrize("hidden", sorted(truth_cases.EFFECTS))
def test_each_hidden_effect_costs_energy_where_it_should(hidden):
    case = truth_cases.cases(1, 0, effects=(hidden,))[0]
    start = 16.0 if hidden == "aux_schedule" else case.start_clock_h  # into the dusk
    case = dataclasses.replace(case, hours=2.0, start_clock_h=start)
    log, truth = truth_cases.generate(case)
    assert truth["summary"]["effect_kwh"] > 0.2
    # a load the charger carries in full (the chiller while the charge current tapers)
    # leaves no SoC footprint; every other effect moves the SoC
    assert truth["summary"]["soc_footprint_pct"] >= 0.0
    if hidden != "battery_chiller":
        assert truth["summary"]["soc_footprint_pct"] > 0.01
    assert truth["expected_verdict"] == truth_cases.EFFECTS[hidden][0]
    assert ("altitude_m" in log) == (hidden == "road_grade")
    assert ("passengers" in log) == (hidden == "passenger_mass")
    if truth["expected_verdict"] == "outside_library":
        assert truth["strength"] == {}
        assert truth["outside_mode"] in truth_cases.MODES
        assert truth["outside_mode"] in truth["outside_modes"]
        assert sum(truth["mode_shares"].values()) == pytest.approx(1.0, abs=1e-3)
    else:
        assert truth["outside_mode"] is None
    if hidden == "battery_chiller":
        charging = truth["mode_shares"]["CC charging"] + truth["mode_shares"]["CV charging"]
        assert charging == pytest.approx(1.0)
    if hidden == "regen_soc_limit":
        assert truth["summary"]["soc_max_pct"] > truth["strength"][
            "regen_soc_limit.derate_soc_pct"]


def test_a_cold_nearly_empty_pack_holds_its_voltage_floor_and_the_bus_is_slower():
    """The voltage window: a cold NMC pack at 12 % SoC cannot give the traction a warm one
    gives; the BMS derates traction so the cells stay at 2.8 V, the bus accelerates less and
    reaches its speed later, and the trace says so (``derated``, ``p_discharge_max_w``)."""
    base = nominal("NMC")
    base["r0_ohm"] *= 1.5
    base["r1_ohm"] *= 1.5
    plan = flat_plan(120, 15.0, ramp_s=15.0)
    cold_ph = {"pack_temp0_degc": -15.0, "pack_heat_capacity_j_per_k": 1.8e6,
               "pack_ha_w_per_k": 100.0}
    warm = simulate(plan, base, None, soc0_frac=0.12)
    cold = simulate(plan, base, "cold_battery", cold_ph, soc0_frac=0.12)
    floor_v = base["cells_series"] * base["cell_v_min"]
    assert warm["derated"].sum() == 0 and cold["derated"].sum() > 5
    assert cold["battery_voltage_v"].min() >= floor_v - 1e-6
    assert cold["battery_voltage_v"].min() == pytest.approx(floor_v, abs=0.5)  # at the floor
    assert (cold["p_battery_w"] <= cold["p_discharge_max_w"] + 1.0).all()
    assert cold["speed_mps"].iloc[15] < warm["speed_mps"].iloc[15] - 1.0
    assert cold["distance_m"].iloc[-1] < warm["distance_m"].iloc[-1]
    # the floor is the power at which V_t = V_min: V_min (E - V_min) / R_0
    row = cold[cold["derated"] == 1].iloc[0]
    assert row["p_discharge_max_w"] < 200e3


def test_the_lfp_floor_is_lower_at_or_below_freezing():
    from benchmarks.truth.sim import cell_v_min

    lfp, nmc = nominal("LFP"), nominal("NMC")
    assert (cell_v_min(lfp, 5.0), cell_v_min(lfp, 0.0), cell_v_min(lfp, -10.0)) == (2.5, 2.0, 2.0)
    assert cell_v_min(nmc, -10.0) == cell_v_min(nmc, 25.0) == 2.8


def test_charge_and_regeneration_keep_the_cells_at_or_below_their_charge_voltage():
    """A 450 kW charger on a high-resistance pack near its top, and braking from speed on a
    nearly full pack: the current is capped so the terminal voltage never passes V_max."""
    for chemistry in ("LFP", "NMC"):
        base = nominal(chemistry)
        base["r0_ohm"] *= 1.5
        v_max = base["cells_series"] * base["cell_v_max"]
        charged = simulate(flat_plan(600, charging=True, charger_kw=450.0), base,
                           soc0_frac=0.93, charge_stop_frac=0.99)
        assert charged["battery_voltage_v"].max() <= v_max + 1e-6
        assert charged["cv_phase"].sum() > 0  # the voltage, not the charger, set the current
        assert (charged["p_charger_w"] < 450e3 - 1.0).any()
        t = np.arange(200, dtype=float)
        plan = flat_plan(200)
        plan["speed_target_mps"] = np.clip(15.0 - np.maximum(t - 60.0, 0.0) * 0.8, 0.0, 15.0) \
            * np.clip(t / 30.0, 0.0, 1.0)
        braked = simulate(plan, base, soc0_frac=0.985)
        assert braked["battery_voltage_v"].max() <= v_max + 1e-6
        assert braked["e_friction_j"].iloc[-1] > 0.0


def test_a_dragging_brake_costs_energy_after_each_application_and_closes_the_balance():
    """The sticking caliper: its drag is largest right after a brake application and fades
    with distance; the wheel's energy balance closes with the drag's work as a term of its
    own; the truth's mode shares read its power in the driving modes."""
    plan = route_day(np.random.default_rng(4), 1.0, 9.0, "rt44")
    base = nominal("LFP")
    ph = {"residual_n": 600.0, "fade_m": 300.0, "floor_n": 50.0}
    free = simulate(plan, base)
    drag = simulate(plan, base, "dragging_brake", ph)
    end = drag.iloc[-1]
    wheel = end["e_road_j"] + end["e_grade_j"] + end["e_friction_j"] + end["e_kinetic_j"] \
        + end["e_force_j"]
    assert end["e_wheel_j"] == pytest.approx(wheel, rel=1e-9, abs=1.0)
    assert end["e_force_j"] > 0.5 * 50.0 * end["distance_m"]  # at least half the floor's work
    assert end["e_force_j"] < (600.0 + 50.0) * end["distance_m"]
    assert drag["e_drive_dc_j"].iloc[-1] > free["e_drive_dc_j"].iloc[-1]
    # at most the residual and floor times the step's mean speed (at most 0.4 m/s above the
    # sampled one: 1.6 m/s^2 over half a step)
    assert (drag["p_force_w"] <= 650.0 * (drag["speed_mps"] + 0.4) + 1e-6).all()
    assert (drag["p_force_w"] >= 0.0).all()
    assert (drag["p_force_w"][drag["speed_mps"] == 0.0] == 0.0).all()


def test_a_weak_cell_group_makes_the_soc_swing_wider():
    """The capacity step: the same charge drawn from 12 % less capacity moves the SoC 1/0.88
    times as far, at 20 % more resistance."""
    base = nominal("LFP")
    plan = flat_plan(1800, 10.0, ramp_s=30.0)
    healthy = simulate(plan, base, soc0_frac=0.7)
    weak = simulate(plan, base, "capacity_step",
                    {"capacity_loss_frac": 0.12, "resistance_growth_frac": 0.2}, soc0_frac=0.7)
    drop_h = 0.7 - healthy["soc_frac"].iloc[-1]
    drop_w = 0.7 - weak["soc_frac"].iloc[-1]
    assert drop_w / drop_h == pytest.approx(1.0 / 0.88, rel=0.01)
    assert weak["e_battery_loss_j"].iloc[-1] > 1.15 * healthy["e_battery_loss_j"].iloc[-1]


def test_a_multi_day_bus_keeps_its_bus_and_changes_on_its_start_day():
    """A fault that starts on a day: the bus's days share its base draw and the fault's
    values; before the start day the fault does not act; the days have distinct dates over
    a winter, their weather spread from mild to freezing; the bus's truth names its start."""
    bus = next(b for b in truth_cases.buses(1, 0) if b.condition == "regen_soc_limit")
    days = truth_cases.bus_days(bus)
    assert len(days) == truth_cases.DAYS_PER_BUS and bus.start_day in truth_cases.START_DAYS
    assert [d.active for d in days] == [k >= bus.start_day for k in range(len(days))]
    dates = [d.date for d in days]
    assert dates == sorted(dates) and len(set(dates)) == len(dates)
    assert dates[0] >= "2025-11-03" and dates[-1] <= "2026-02-28"
    short = [dataclasses.replace(d, hours=0.3) for d in days]
    runs = [truth_cases.day_trace(d) for d in short]
    preview = "driver_preview_s"
    bases = [{k: v for k, v in r[1].items() if k != preview} for r in runs]
    assert all(b == bases[0] for b in bases)
    assert len({r[2]["derate_soc_frac"] for r in runs}) == 1
    records = [truth_cases.generate(d)[1] for d in short]
    assert [r["expected_verdict"] for r in records] == \
        [None if k < bus.start_day else "regen_soc_limit" for k in range(len(days))]
    assert [r["date"] for r in records] == dates
    truth = truth_cases.bus_truth(bus, records)
    assert truth["start_day"] == bus.start_day and truth["start_date"] == dates[bus.start_day]
    assert truth["expected_verdict"] == "regen_soc_limit" and truth["kind"] == "from_day"
    assert sum(truth["day_effect_kwh"][:bus.start_day]) == 0.0


def test_the_multi_day_buses_cover_every_condition_and_spread_the_weather():
    buses = truth_cases.buses()
    counts = pd.Series([b.condition or "control" for b in buses]).value_counts()
    assert (counts.drop("control") == 5).all() and counts["control"] == 4
    assert set(counts.index) - {"control"} == set(truth_cases.MULTI_DAY)
    assert len({b.seed for b in buses}) == len(buses)
    for b in buses:
        kind = truth_cases.MULTI_DAY[b.condition][1] if b.condition else None
        assert (b.start_day is not None) == (kind == "from_day")
    # a heating bus's days: the ambient spreads over more than 8 K (mild to freezing)
    heating = next(b for b in buses if b.condition == "cabin_heating")
    plans = [route_day(np.random.default_rng(truth_cases._streams(d)[0]), 1.0, d.start_clock_h,
                       d.route, climate=d.climate, date=d.date)
             for d in truth_cases.bus_days(heating)]
    means = [p["ambient_degc"].mean() for p in plans]
    assert max(means) - min(means) > 8.0
    assert [p.attrs["date"] for p in plans] == [d.date for d in truth_cases.bus_days(heating)]
