"""Measured-log loader: every bad input gives its error; resampling keeps the physics."""

from __future__ import annotations

import datetime
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ebus_env.config import load_bus
from ebus_env.cycles import service_day
from ebus_env.errors import LogError
from ebus_env.grade import grade_from_altitude
from ebus_env.io.measured import load_log
from tests.conftest import DT

ROOT = Path(__file__).resolve().parent.parent


def write(tmp_path, frame: pd.DataFrame, name="log.csv") -> Path:
    path = tmp_path / name
    frame.to_csv(path, index=False)
    return path


def good_frame(n=600, period=1.0):
    t = np.arange(n) * period
    speed = np.clip(30 * np.sin(2 * np.pi * t / 120), 0, None)  # km/h, 2-minute hops
    soc = 90 - 0.002 * t
    return pd.DataFrame({"time_s": t, "speed_kmh": speed, "soc_pct": np.round(soc, 1),
                         "ambient_degc": 5.0})


def test_good_log_loads_and_reports_its_resampling(tmp_path):
    log = load_log(write(tmp_path, good_frame()), DT)
    p = log.profile
    assert p.dt_s == DT and p.n_steps == 5991  # 599 s at 0.1 s, both ends included
    assert p.measured["soc_frac"][0] == pytest.approx(0.90)
    assert p.channels["ambient_degc"][0] == 5.0
    assert any("resampled from 1 s to 0.1 s" in c for c in log.report.changes)


def test_missing_speed_column_names_the_fix(tmp_path):
    frame = good_frame().rename(columns={"speed_kmh": "speed_km_h"})
    with pytest.raises(LogError, match="No speed column. The file has 'speed_km_h'.*columns="):
        load_log(write(tmp_path, frame))


def test_a_column_name_given_twice_names_both_places(tmp_path):
    """pandas would rename the second 'soc_pct' to 'soc_pct.1' and the loader would take the
    first in silence; which one holds the SoC is the user's call."""
    frame = good_frame()
    frame.insert(1, "soc_pct_copy", frame["soc_pct"] - 1.0)
    path = tmp_path / "twice.csv"
    frame.rename(columns={"soc_pct_copy": "soc_pct"}).to_csv(path, index=False)
    with pytest.raises(LogError, match=r"appears 2 times \(columns 2, 4\).*column 'soc_pct'"
                                       r".*keep one of them"):
        load_log(path)
    frame.rename(columns={"soc_pct_copy": "soc_pct"}).to_csv(path, index=False, sep=";")
    with pytest.raises(LogError, match="appears 2 times"):
        load_log(path)


def test_missing_time_column(tmp_path):
    frame = good_frame().drop(columns="time_s")
    with pytest.raises(LogError, match="No time column"):
        load_log(write(tmp_path, frame))


def test_non_numeric_values_name_column_rows_and_values(tmp_path):
    frame = good_frame().astype({"speed_kmh": object})
    frame.loc[[5, 6], "speed_kmh"] = "fast"
    with pytest.raises(LogError, match=r"Non-numeric values \('fast'.*column 'speed_kmh', rows 5-6"):
        load_log(write(tmp_path, frame))


def test_time_not_increasing_or_duplicated(tmp_path):
    frame = good_frame()
    frame.loc[10, "time_s"] = frame.loc[9, "time_s"]
    with pytest.raises(LogError, match="Duplicated times.*row 10"):
        load_log(write(tmp_path, frame))
    frame = good_frame()
    frame.loc[20, "time_s"] = 5.0
    with pytest.raises(LogError, match="Time goes backwards.*row 20"):
        load_log(write(tmp_path, frame))


def test_gaps_error_split_hold_interpolate(tmp_path):
    frame = good_frame()
    frame.loc[300:, "time_s"] += 120.0  # a two-minute hole
    path = write(tmp_path, frame)
    with pytest.raises(LogError, match="1 time gap.*299.0-420.0 s.*gaps='split'"):
        load_log(path)
    split = load_log(path, gaps="split")
    assert len(split.profiles) == 2
    assert split.profiles[1].measured["soc_frac"][0] == pytest.approx(frame.soc_pct[300] / 100)
    assert any("split at 1 gap" in c for c in split.report.changes)
    for policy in ("hold", "interpolate"):
        log = load_log(path, gaps=policy)
        assert len(log.profiles) == 1
        assert log.profile.duration_s == pytest.approx(719.1)  # 0-719 s, one step each
        assert any("bridged" in c for c in log.report.changes)
    held = load_log(path, gaps="hold").profile.channels["speed_ref_mps"]
    t = np.arange(len(held)) * DT
    inside = (t > 300) & (t < 418)
    assert np.all(held[inside] == held[inside][0])


def test_a_segment_of_one_sample_between_gaps_is_named_not_simulated(tmp_path):
    """Split at its gaps, a log whose last sample stands alone after a gap has a segment
    with no time step: the error names it, its row and the gap policies that keep it."""
    frame = good_frame()
    frame.loc[len(frame) - 1, "time_s"] += 120.0
    with pytest.raises(LogError, match=rf"Segments \[1\].*too short.*row {len(frame)}.*'hold'"):
        load_log(write(tmp_path, frame), gaps="split")


def test_speed_in_mps_written_as_kmh_is_caught(tmp_path):
    frame = good_frame()
    frame["speed_kmh"] = frame["speed_kmh"] / 3.6  # m/s values under a km/h name
    with pytest.raises(LogError, match="look like m/s.*rename the column 'speed_mps'"):
        load_log(write(tmp_path, frame))
    assert load_log(write(tmp_path, frame), check_units=False).profile.n_steps > 0
    renamed = frame.rename(columns={"speed_kmh": "speed_mps"})
    log = load_log(write(tmp_path, renamed))
    assert log.profile.channels["speed_ref_mps"].max() == pytest.approx(30 / 3.6, rel=1e-3)


def test_a_steady_speed_log_loads_without_a_unit_verdict(tmp_path):
    """At a steady 20 km/h no acceleration tells km/h from m/s: the check stays silent (no
    verdict, no warning from an empty percentile)."""
    frame = good_frame().assign(speed_kmh=20.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        log = load_log(write(tmp_path, frame), DT)
    assert log.profile.channels["speed_ref_mps"] == pytest.approx(20.0 / 3.6)


@pytest.mark.parametrize(("column", "good", "bad"), [
    ("passengers", 40.0, -3.0), ("charger_kw", 450.0, 450e3), ("altitude_m", 120.0, 9000.0),
    ("grade_pct", 4.0, 45.0), ("grade_frac", 0.04, 0.45), ("solar_w_per_m2", 800.0, -5.0),
    ("battery_current_a", 200.0, 2e5), ("battery_voltage_v", 650.0, 0.0),
    ("cabin_temp_degc", 21.0, 294.0),
])
def test_every_logged_signal_has_a_physical_range(tmp_path, column, good, bad):
    """A value outside its column's range fails naming the column and the row (a kW column
    in W, feet for metres, kelvin for degC); the same log with a plausible value loads."""
    pack = {"battery_current_a": 200.0, "battery_voltage_v": 650.0}  # logged together
    frame = good_frame().assign(**{**(pack if column in pack else {}), column: good})
    load_log(write(tmp_path, frame), DT)
    frame.loc[7, column] = bad
    with pytest.raises(LogError, match=rf"Values outside .*column '{column}', row 7\b"):
        load_log(write(tmp_path, frame), DT)


def test_soc_fraction_in_percent_column_is_caught(tmp_path):
    frame = good_frame()
    frame["soc_pct"] = frame["soc_pct"] / 100
    with pytest.raises(LogError, match="SoC looks like a fraction.*'soc_frac'"):
        load_log(write(tmp_path, frame))
    log = load_log(write(tmp_path, frame.rename(columns={"soc_pct": "soc_frac"})))
    assert log.profile.measured["soc_frac"][0] == pytest.approx(0.9)


def test_nan_runs_error_or_are_filled_and_reported(tmp_path):
    frame = good_frame()
    frame.loc[100:104, "ambient_degc"] = np.nan
    path = write(tmp_path, frame)
    with pytest.raises(LogError, match="Missing values in 1 run.*'ambient_degc', rows 100-104"):
        load_log(path)
    log = load_log(path, fill="interpolate")
    assert np.all(np.isfinite(log.profile.channels["ambient_degc"]))
    assert any("5 missing values" in c and "100-104" in c for c in log.report.changes)


def test_empty_files_and_missing_file(tmp_path):
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    with pytest.raises(LogError, match="The file is empty"):
        load_log(empty)
    header = tmp_path / "header.csv"
    header.write_text("time_s,speed_kmh\n")
    with pytest.raises(LogError, match="no rows"):
        load_log(header)
    with pytest.raises(LogError, match="does not exist"):
        load_log(tmp_path / "nope.csv")


def test_flags_and_ranges_are_checked(tmp_path):
    frame = good_frame()
    frame["charging"] = 0
    frame.loc[7, "charging"] = 2
    with pytest.raises(LogError, match="Flag values other than 0 and 1.*'charging', row 7"):
        load_log(write(tmp_path, frame))
    frame = good_frame()
    frame.loc[3, "soc_pct"] = 120.0
    with pytest.raises(LogError, match=r"outside \[0, 100\].*'soc_pct', row 3"):
        load_log(write(tmp_path, frame))
    frame = good_frame()
    frame.loc[3, "speed_kmh"] = -4.0
    with pytest.raises(LogError, match="'speed_kmh', row 3"):
        load_log(write(tmp_path, frame))


def test_a_logged_load_is_a_channel_in_watts_within_its_range(tmp_path):
    frame = good_frame()
    frame["logged_load_kw"] = np.where(frame.time_s > 300, 6.5, 0.0)
    log = load_log(write(tmp_path, frame))
    load = log.profile.channels["logged_load_w"]
    assert load.max() == pytest.approx(6500.0) and load.min() == 0.0
    assert "logged_load_kw" not in log.profile.measured  # an input, not a signal to compare
    frame.loc[5, "logged_load_kw"] = 6500.0  # watts in the kW column
    with pytest.raises(LogError, match=r"outside \[-1000, 1000\].*'logged_load_kw', row 5"
                                       r".*divide by 1000"):
        load_log(write(tmp_path, frame))


def test_column_map_with_scale_and_unknown_source(tmp_path):
    frame = good_frame().rename(columns={"speed_kmh": "Velocity [km/h]"})
    frame["I [A]"] = -100.0
    path = write(tmp_path, frame)
    columns = {"Velocity [km/h]": "speed_kmh",
               "I [A]": {"column": "battery_current_a", "scale": -1}}
    log = load_log(path, columns=columns)
    assert np.all(log.profile.measured["battery_current_a"] == 100.0)
    assert any("multiplied by -1" in c for c in log.report.changes)
    with pytest.raises(LogError, match="names 'Speed', which the file lacks"):
        load_log(path, columns={"Speed": "speed_kmh"})


def test_parquet_timestamps_and_extra_columns(tmp_path):
    frame = good_frame()
    frame["timestamp"] = pd.Timestamp("2024-01-15 07:30:00") + pd.to_timedelta(frame.time_s, "s")
    frame = frame.drop(columns="time_s")
    frame["heater_kw"] = 1.5
    frame["driver"] = "anna"
    path = tmp_path / "log.parquet"
    frame.to_parquet(path)
    log = load_log(path)
    assert log.profile.start_time_h == pytest.approx(7.5)
    assert log.profile.channel("time_of_day_h")[-1] == pytest.approx(7.5 + 599 / 3600)
    assert np.all(log.profile.measured["heater_kw"] == 1.5)
    assert any("'driver' is not numeric" in i for i in log.report.ignored)


def test_vehicle_limits_are_reported(tmp_path):
    frame = good_frame()
    frame.loc[50:60, "speed_kmh"] = 95.0
    log = load_log(write(tmp_path, frame), max_speed_kmh=80.0, max_accel_mps2=3.0)
    text = " ".join(log.report.warnings)
    assert "above the vehicle's top speed 80 km/h" in text
    assert "|acceleration| above 3 m/s^2" in text


def test_grade_from_noisy_altitude_recovers_the_slope():
    rng = np.random.default_rng(0)
    distance = np.cumsum(np.full(4000, 2.0))  # 8 km at 2 m per sample
    altitude = 0.03 * distance + rng.normal(0, 1.5, distance.size)  # 3 % slope, GPS noise
    grade, clipped = grade_from_altitude(distance, altitude, window_m=200.0)
    inner = slice(500, -500)
    assert np.mean(grade[inner]) == pytest.approx(0.03, abs=0.002)
    assert np.std(grade[inner]) < 0.01
    raw = np.diff(altitude) / np.diff(distance)
    assert np.std(raw) > 50 * np.std(grade[inner])  # raw differences would be noise


def test_bmw_trip_with_preset(tmp_path):
    log = load_log(ROOT / "data/measured/bmw_i3_tum/TripB16_1hz.csv", DT, columns="bmw_i3_tum")
    p = log.profile
    assert p.measured["soc_frac"][0] == pytest.approx(0.675)
    assert p.measured["battery_current_a"].max() > 200  # discharge counted positive
    assert "grade_frac" in p.channels
    assert np.abs(p.channels["grade_frac"]).max() < 0.1
    assert any("grade from 'altitude_m'" in c for c in log.report.changes)


@pytest.mark.parametrize("cycle", ["sort2", "london"])
def test_sampling_rate_does_not_change_the_answer(tmp_path, bus12, model12, cycle):
    """The same day logged at 0.5, 1, 10 and 20 Hz: final SoC within 0.5 %-points."""
    day = service_day(cycle, 3.0, DT, bus12.service)
    t, v = day.time_s, day.channels["speed_ref_mps"]
    base = pd.DataFrame({"time_s": t, "speed_kmh": 3.6 * v,
                         "charging": day.channels["charger_connected"].astype(int),
                         "ambient_degc": 8.0})
    t20 = np.arange(0.0, t[-1] + 1e-9, 0.05)
    logs = {"10 Hz": base, "1 Hz": base.iloc[::10], "0.5 Hz": base.iloc[::20],
            "20 Hz": pd.DataFrame({"time_s": t20, "speed_kmh": np.interp(t20, t, 3.6 * v),
                                   "charging": np.interp(t20, t, base.charging).round().astype(int),
                                   "ambient_degc": 8.0})}
    end = {}
    for label, frame in logs.items():
        log = load_log(write(tmp_path, frame, f"{label}.csv"), DT)
        end[label] = model12.simulate(log.profile, soc_start=0.9, record=False).summary()
    for label in ("1 Hz", "0.5 Hz", "20 Hz"):
        assert abs(end[label]["soc_end_pct"] - end["10 Hz"]["soc_end_pct"]) < 0.5
        assert end[label]["distance_km"] == pytest.approx(end["10 Hz"]["distance_km"], rel=0.01)


def test_twizy_trip_with_preset_and_the_twizys_energy_per_km():
    """A Twizy trip read with its preset (SoC in 0.02 % steps, GPS altitude to grade, ambient
    mapped); the car's config on an hour of urban driving (SORT 2): a 549 kg quadricycle
    uses tens of Wh per km at the pack (Renault rates its 6.1 kWh for about 100 km), not the
    hundreds of a car or the thousand of a bus. The trips are reserved for validation: the
    energy is checked on a standard cycle, not on them."""
    log = load_log(ROOT / "data/measured/rsk_twizy/T3_05_31_2021_1hz.csv.gz", DT,
                   columns="rsk_twizy")
    p = log.profile
    soc = p.measured["soc_frac"]
    assert soc[0] == pytest.approx(0.546, abs=0.001) and np.nanmin(soc) < 0.25
    logged = soc[p.sample_rows("soc_frac")]  # the 1 Hz samples, not the 10 Hz interpolation
    assert np.min(np.diff(np.unique(np.round(logged * 1e4)))) == pytest.approx(2.0)  # 0.02 %
    assert np.nanmean(p.channels["ambient_degc"]) == pytest.approx(20.5, abs=2.0)
    assert np.abs(p.channels["grade_frac"]).max() <= 0.15
    bus = load_bus("twizy")
    run = bus.build(DT).simulate(service_day("sort2", 1.0, DT, bus.service))
    km = run.trace("distance_m")[-1] / 1e3
    used_wh = (run.trace("soc_frac")[0] - run.trace("soc_frac")[-1]) * 108 * 15 * 3.75
    assert 40.0 < used_wh / km < 120.0, used_wh / km


# -- gaps='hold' changes only the gaps --------------------------------------------------------
def _same_profiles(one, other):
    assert len(one.profiles) == len(other.profiles)
    for p, q in zip(one.profiles, other.profiles, strict=True):
        assert p.channels.keys() == q.channels.keys() and p.measured.keys() == q.measured.keys()
        for key in p.channels:
            np.testing.assert_array_equal(p.channels[key], q.channels[key])
        for key in p.measured:
            np.testing.assert_array_equal(p.measured[key], q.measured[key])
        assert p.notes == q.notes


def test_a_log_without_gaps_is_the_same_whatever_the_gap_policy(tmp_path):
    """Holding only bridges gaps: a log without one (the BMW trip of the audit, where 'hold'
    once held every channel between 1 Hz samples and added 0.44 kWh) is unchanged."""
    frame = good_frame().assign(ambient_degc=lambda f: 5.0 + 0.01 * f.time_s)
    for path, columns in ((write(tmp_path, frame), None),
                          (ROOT / "data/measured/bmw_i3_tum/TripB16_1hz.csv", "bmw_i3_tum")):
        reference = load_log(path, DT, columns=columns)
        assert any("linear interpolation" in c for c in reference.report.changes)
        for policy in ("split", "hold", "interpolate"):
            _same_profiles(reference, load_log(path, DT, columns=columns, gaps=policy))
    speed = load_log(write(tmp_path, frame), DT, gaps="hold").profile.channels["speed_ref_mps"]
    samples = frame.speed_kmh.to_numpy() / 3.6
    assert speed[15] == pytest.approx(0.5 * (samples[1] + samples[2]))  # 1.5 s: not held
    assert speed[15] > samples[1] + 0.1


def test_hold_holds_inside_the_gap_and_interpolates_elsewhere(tmp_path):
    frame = good_frame().assign(ambient_degc=lambda f: 5.0 + 0.01 * f.time_s)
    frame.loc[300:, "time_s"] += 120.0  # samples 299 s and 420 s with nothing between
    path = write(tmp_path, frame)
    held = load_log(path, DT, gaps="hold").profile
    linear = load_log(path, DT, gaps="interpolate").profile
    t = np.arange(held.n_steps) * DT
    inside = (t > 299.0 + 1e-6) & (t < 420.0 - 1e-6)
    assert inside.sum() == 1209
    assert np.all(held.channels["ambient_degc"][inside] == pytest.approx(5.0 + 0.01 * 299))
    assert np.all(held.channels["speed_ref_mps"][inside]
                  == pytest.approx(frame.speed_kmh[299] / 3.6))
    for key in ("ambient_degc", "speed_ref_mps"):
        np.testing.assert_array_equal(held.channels[key][~inside], linear.channels[key][~inside])
    ambient = linear.channels["ambient_degc"]  # interpolated across the gap: 7.99 -> 8.0
    assert ambient[inside][0] == pytest.approx(7.99 + 0.01 * 0.1 / 121, rel=1e-9)
    assert ambient[inside][0] > held.channels["ambient_degc"][inside][0]


def test_split_segments_each_get_their_grade_from_altitude(tmp_path):
    """The second segment's grade is computed from its own altitude samples (it once
    failed with 'fp and xp are not of the same length')."""
    t = np.arange(600.0)
    t[300:] += 120.0
    frame = pd.DataFrame({"time_s": t, "speed_kmh": 36.0, "soc_pct": 90.0,
                          "altitude_m": 100.0 + 0.2 * t})  # 10 m/s, 2 m up per 100 m: 2 %
    log = load_log(write(tmp_path, frame), DT, gaps="split")
    assert [p.n_steps for p in log.profiles] == [2991, 2991]
    for p in log.profiles:
        assert np.median(p.channels["grade_frac"]) == pytest.approx(0.02, rel=0.02)


# -- one column per quantity ------------------------------------------------------------------
def test_time_s_and_timestamp_that_agree_give_the_clock_of_the_timestamps(tmp_path):
    frame = good_frame()
    frame["timestamp"] = pd.Timestamp("2026-03-02 06:00") + pd.to_timedelta(frame.time_s, "s")
    log = load_log(write(tmp_path, frame), DT)
    assert log.profile.start_time_h == pytest.approx(6.0)  # not 00:00
    assert log.profile.duration_s == pytest.approx(599.1)  # 0-599 s, one step each
    changes = " ".join(log.report.changes)
    assert "'time_s' and 'timestamp' agree" in changes and "first row at 06:00:00" in changes
    assert "no clock time" not in changes
    frame["timestamp"] = pd.Timestamp("2026-03-02 06:00") + pd.to_timedelta(
        frame.time_s + (frame.time_s > 100) * 5.0, "s")  # 5 s apart from row 101 on
    with pytest.raises(LogError, match=r"'time_s' and 'timestamp' disagree at 499 rows \(row 101:"
                                       r" 101 s and 106 s.*rows 101-599.*keep one of them"):
        load_log(write(tmp_path, frame), DT)
    with pytest.raises(LogError, match="The log has date-times .*06:00:00.*--start-time"):
        load_log(write(tmp_path, frame.assign(timestamp=frame.timestamp.iloc[0]
                                              + pd.to_timedelta(frame.time_s, "s"))), DT,
                 start_h=7.0)


@pytest.mark.parametrize(("first", "second", "factor"), [
    ("soc_pct", "soc_frac", 100.0), ("speed_kmh", "speed_mps", 3.6),
    ("grade_pct", "grade_frac", 100.0),
])
def test_two_columns_of_one_quantity_are_used_only_when_they_agree(tmp_path, first, second,
                                                                   factor):
    frame = good_frame().assign(grade_pct=np.linspace(-2.0, 3.0, 600), soc_pct=lambda f:
                                90.0 - 0.002 * f.time_s)
    truth = frame[first].to_numpy()
    frame[first] = np.round(truth, 1)
    frame[second] = np.round(truth / factor, 5)  # finer than the first's 0.1 steps
    log = load_log(write(tmp_path, frame), DT)
    assert f"'{first}' and '{second}' agree within their rounding: '{second}' used, " \
           f"'{first}' not" in log.report.changes
    alone = load_log(write(tmp_path, frame.drop(columns=first)), DT)
    for got, want in [(log.profile.channels, alone.profile.channels),
                      (log.profile.measured, alone.profile.measured)]:
        assert got.keys() == want.keys()
        for key in got:
            np.testing.assert_array_equal(got[key], want[key])
    frame.loc[200:209, second] += 2.0 / factor  # 2 units apart: not rounding
    with pytest.raises(LogError, match=rf"'{first}' and '{second}' both give .* disagree at 10 "
                                       rf"rows \(row 200: {first} .*rows 200-209.*keep one"):
        load_log(write(tmp_path, frame), DT)


def test_grade_is_used_over_altitude_with_a_note(tmp_path):
    frame = good_frame().assign(grade_pct=2.5, altitude_m=lambda f: 300.0 + 0.1 * f.time_s)
    log = load_log(write(tmp_path, frame), DT)
    assert np.all(log.profile.channels["grade_frac"] == pytest.approx(0.025))
    assert log.profile.measured["altitude_m"][-1] == pytest.approx(359.9)
    assert any("grade from 'grade_pct', not from 'altitude_m'" in c for c in log.report.changes)


# -- date-times -------------------------------------------------------------------------------
def test_a_daylight_saving_switch_is_no_jump_back(tmp_path):
    path = tmp_path / "dst.csv"
    path.write_text("timestamp,speed_kmh,soc_pct\n2026-10-25T02:59:58+02:00,10,90\n"
                    "2026-10-25T02:59:59+02:00,10,90\n2026-10-25T02:00:00+01:00,10,90\n"
                    "2026-10-25T02:00:01+01:00,10,90\n")
    log = load_log(path, DT)
    assert log.profile.duration_s == pytest.approx(3.1)  # 1 s steps in UTC, one step each
    assert log.profile.start_time_h == pytest.approx(2 + 59 / 60 + 58 / 3600)  # local clock
    assert any("UTC offset changes within the log (+02:00 to +01:00 at row 2)" in c
               for c in log.report.changes)
    path.write_text(path.read_text().replace("02:00:01+01:00", "02:00:01"))
    with pytest.raises(LogError, match="a UTC offset and some not.*row 3"):
        load_log(path, DT)


def test_day_first_dates_and_date_times_in_time_s_name_their_cause(tmp_path):
    stamps = ["04/05/2026 23:59:58", "04/05/2026 23:59:59", "05/05/2026 00:00:00",
              "05/05/2026 00:00:01"]
    frame = pd.DataFrame({"timestamp": stamps, "speed_kmh": 10.0, "soc_pct": 90.0})
    with pytest.raises(LogError, match=r"jump by 29\.0 days from '04/05/2026 23:59:59' to "
                                       r"'05/05/2026 00:00:00': are the dates day-first.*row 2"
                                       r".*ISO 8601"):
        load_log(write(tmp_path, frame), DT)
    frame["timestamp"] = [s.replace("04/05", "12/05").replace("05/05", "13/05") for s in stamps]
    with pytest.raises(LogError, match=r"cannot be read.*rows 2-3.*day- or month-first"):
        load_log(write(tmp_path, frame), DT)
    frame = frame.rename(columns={"timestamp": "time_s"}).assign(
        time_s=["2026-05-04T23:59:58", "2026-05-04T23:59:59", "2026-05-05T00:00:00",
                "2026-05-05T00:00:01"])
    with pytest.raises(LogError, match="'time_s' holds date-times .*rename the column "
                                       "'timestamp'"):
        load_log(write(tmp_path, frame), DT)


# -- unreadable files -------------------------------------------------------------------------
def test_a_spreadsheet_workbook_is_named_with_the_fix(tmp_path):
    path = tmp_path / "day.xlsx"
    path.write_bytes(b"PK\x03\x04 not a csv")
    with pytest.raises(LogError, match=r"spreadsheet workbook \(\.xlsx\).*save the sheet as CSV"):
        load_log(path)


@pytest.mark.parametrize("damage", ["truncated", "not gzip", "bad checksum"])
def test_a_damaged_gzip_log_is_named_as_such(tmp_path, damage):
    data = (ROOT / "data/measured/hidden/control.csv.gz").read_bytes()
    damaged = {"truncated": data[:20000], "not gzip": b"time_s,speed_kmh\n0,1\n1,2\n",
               "bad checksum": data[:-8] + bytes(4) + data[-4:]}[damage]
    path = tmp_path / "log.csv.gz"
    path.write_bytes(damaged)
    with pytest.raises(LogError, match=r"truncated or not a valid gzip file .*log\.csv\.gz"):
        load_log(path, DT)


# -- sparse logs: the dense loader's checks ----------------------------------------------------
def sparse_frame():
    t = np.arange(0, 3600 * 3, 300.0)
    return pd.DataFrame({"time_s": t, "distance_km": 0.004 * t, "soc_pct": 90 - t / 1000,
                         "charging": 0, "ambient_degc": 5.0})


@pytest.mark.parametrize(("edit", "words"), [
    (lambda f: f.assign(ambient_degc=f.ambient_degc.where(f.index != 3)),
     r"Missing values \(.*column 'ambient_degc', row 3\)"),
    (lambda f: f.assign(charging=f.charging.astype(object).where(f.index != 4, "")),
     r"Missing values \(.*column 'charging', row 4\)"),
    (lambda f: f.assign(charging=f.charging.where(f.index != 5, 2)),
     r"Flag values other than 0 and 1 \(.*column 'charging', row 5\)"),
    (lambda f: f.iloc[:1], "at least two rows"),
    (lambda f: f.assign(soc_frac=f.soc_pct / 100 - 0.05),
     "'soc_pct' and 'soc_frac' both give the SoC, and disagree"),
])
def test_sparse_logs_get_the_dense_checks(tmp_path, edit, words):
    from ebus_env.io.sparse import load_sparse_log

    load_sparse_log(write(tmp_path, sparse_frame()), DT)
    with pytest.raises(LogError, match=words):
        load_sparse_log(write(tmp_path, edit(sparse_frame())), DT)


def test_sparse_log_above_top_speed_warns_and_takes_soc_frac(tmp_path):
    from ebus_env.io.sparse import load_sparse_log

    frame = sparse_frame()
    log = load_sparse_log(write(tmp_path, frame), DT, max_speed_kmh=80.0)
    assert log.report.warnings == []
    frac = load_sparse_log(write(tmp_path, frame.assign(soc_frac=frame.soc_pct / 100)
                                 .drop(columns="soc_pct")), DT, max_speed_kmh=80.0)
    np.testing.assert_allclose(frac.profile.measured["soc_frac"],
                               log.profile.measured["soc_frac"], rtol=1e-12)
    frame.loc[6:, "distance_km"] += 9.0  # 9 km more in the 300 s after row 5: 122.4 km/h
    fast = load_sparse_log(write(tmp_path, frame), DT, max_speed_kmh=80.0)
    assert any("3000 samples (300 s) above the vehicle's top speed 80 km/h (max 122.4 km/h)"
               in w for w in fast.report.warnings)


def test_a_log_with_date_times_keeps_its_date_and_a_split_segment_its_own(tmp_path):
    """Several days of one bus are told apart by their dates: a log with date-times gives its
    profile the local date of its first row; a segment after midnight the next day's."""
    t = pd.date_range("2026-01-26 23:50:00+01:00", periods=1200, freq="s")
    keep = np.r_[0:500, 900:1200]  # a gap from 23:58:20 to 00:05:00
    frame = pd.DataFrame({"timestamp": t[keep].strftime("%Y-%m-%dT%H:%M:%S%z"),
                          "speed_kmh": 20.0, "soc_pct": 80.0})
    path = tmp_path / "day.csv"
    frame.to_csv(path, index=False)
    first, second = load_log(path, gaps="split").profiles
    assert first.date == datetime.date(2026, 1, 26) and second.date == datetime.date(2026, 1, 27)
    assert second.slice(10, 20).date == second.date and first.with_channels(grade_frac=0.0).date
    frame.drop(columns="timestamp").assign(time_s=np.arange(len(keep))).to_csv(path, index=False)
    assert load_log(path).profile.date is None
