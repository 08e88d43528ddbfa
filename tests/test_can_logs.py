"""CAN logger files (.mf4, .blf, .asc) decoded with a DBC into the canonical log: the codec
against cantools, the round trip of an encoded day, what is counted and refused."""

from __future__ import annotations

import datetime
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("cantools")
pytest.importorskip("asammdf")
pytest.importorskip("can")

import cantools  # noqa: E402

from ebus_env import paths  # noqa: E402
from ebus_env.depot.sample_days import day_table, with_unknown_id  # noqa: E402
from ebus_env.errors import ConfigError, LogError  # noqa: E402
from ebus_env.io import can_codec  # noqa: E402
from ebus_env.io.can_encode import encode_log  # noqa: E402
from ebus_env.io.can_frames import Frames, read_frames, write_frames  # noqa: E402
from ebus_env.io.can_log import decode, to_table  # noqa: E402
from ebus_env.io.can_map import load_signal_map  # noqa: E402
from ebus_env.io.measured import load_log  # noqa: E402

DBC = paths.data("can", "ebus_j1939.dbc")
# half a scale step of each column's signal: what the round trip may lose
RESOLUTION = {"speed_kmh": 1 / 256, "soc_pct": 0.0025, "battery_current_a": 0.05,
              "battery_voltage_v": 0.05, "ambient_degc": 0.03125, "charging": 0.0,
              "charger_kw": 0.1}


@pytest.fixture(scope="module")
def day():
    """25 min of the control day from 06:50 (its first charging layover at 07:00), 1 Hz."""
    return day_table("control", hours=75 / 60).iloc[3000:4500].reset_index(drop=True)


@pytest.fixture(scope="module")
def frames(day):
    return encode_log(day, "ebus_j1939", seed=3)


def _message(start: int, length: int, order: str, signed: bool) -> str:
    sign = "-" if signed else "+"
    return (f'VERSION ""\nNS_ :\nBS_:\nBU_: A\nBO_ 256 M: 8 A\n'
            f' SG_ S : {start}|{length}@{1 if order == "little_endian" else 0}{sign} '
            f'(1,0) [0|0] "" A\n')


@st.composite
def layouts(draw):
    length = draw(st.integers(1, 64))
    order = draw(st.sampled_from(["little_endian", "big_endian"]))
    signed = draw(st.booleans()) and length > 1
    if order == "little_endian":
        start = draw(st.integers(0, 64 - length))
    else:  # the MSB's index from byte 0's top bit, then DBC's sawtooth numbering
        msb = draw(st.integers(0, 64 - length))
        start = 8 * (msb // 8) + 7 - msb % 8
    return start, length, order, signed


@settings(max_examples=80, deadline=None)
@given(layout=layouts(), seed=st.integers(0, 2**31))
def test_the_vectorized_codec_agrees_with_cantools_both_ways(layout, seed):
    message = cantools.database.load_string(_message(*layout), "dbc").get_message_by_name("M")
    signal = message.signals[0]
    rng = np.random.default_rng(seed)
    data = rng.integers(0, 256, (40, 8), dtype=np.uint8)
    ours = can_codec.raw_values(data, signal)
    theirs = [message.decode(bytes(row), decode_choices=False, scaling=False)["S"]
              for row in data]
    assert [int(x) for x in ours] == theirs
    encoded = can_codec.encode(message, {"S": ours}, len(ours))
    assert [message.decode(bytes(row), scaling=False)["S"] for row in encoded] == theirs
    # cantools' frames decode to the same raw values through ours
    cantools_frames = np.array([list(message.encode({"S": v}, scaling=False)) for v in theirs],
                               dtype=np.uint8)
    assert [int(x) for x in can_codec.raw_values(cantools_frames, signal)] == theirs


def test_values_that_do_not_fit_the_signal_are_refused_by_the_encoder():
    signal = load_signal_map("ebus_j1939").message("CCVS1").get_signal_by_name(
        "WheelBasedVehicleSpeed")
    with pytest.raises(ValueError, match="does not fit its 16 bits"):
        can_codec.to_raw(np.array([300.0]), signal)


@pytest.mark.parametrize("suffix", [".mf4", ".blf", ".asc"])
def test_an_encoded_day_loads_back_within_the_dbc_resolution(day, frames, tmp_path, suffix):
    path = write_frames(frames, tmp_path / f"bus{suffix}")
    log = load_log(path, columns="ebus_j1939")
    table, _ = to_table(decode(read_frames(path), load_signal_map("ebus_j1939")),
                        load_signal_map("ebus_j1939"))
    assert table["timestamp"].tolist() == day["timestamp"].tolist()
    for column, step in RESOLUTION.items():
        error = np.abs(table[column].to_numpy() - day[column].to_numpy()
                       if column in day else table[column].to_numpy())
        assert error.max() <= step / 2 + 1e-9, column
    assert day["charging"].max() == 1 and table["charger_kw"].max() == 450  # the layover
    profile = log.profile
    assert profile.date == datetime.date(2026, 1, 14)
    assert profile.start_s == 0 and len(log.profiles) == 1
    assert profile.n_steps == len(day) * 10 - 9  # 1 Hz rows on the 0.1 s grid
    np.testing.assert_allclose(profile.measured["soc_frac"][::10], day["soc_pct"] / 100,
                               atol=0.0025 / 200 + 1e-12)
    assert log.report.columns["soc_pct"] == "BMS2.PackSoC"
    assert log.report.frames["signals"]["speed_kmh"]["values"] == 10 * len(day)
    assert any("decoded" in line and "mean of the values" in line
               for line in log.report.changes)
    # PAX is not sent (the day has no passenger counts): said, not silently absent
    assert any("'passengers' (PAX.PassengerCount) has no valid value" in line
               for line in log.report.changes)


def test_asammdf_decodes_the_written_mf4_to_the_same_values(frames, tmp_path):
    """The MF4 is a standard bus log: asammdf's own DBC decoding reads it as we do."""
    from asammdf import MDF

    path = write_frames(frames, tmp_path / "bus.mf4")
    with MDF(str(path)) as mdf:
        decoded = mdf.extract_bus_logging({"CAN": [(str(DBC), 0)]})
        theirs = decoded.get("PackCurrent")
    ours = decode(read_frames(path), load_signal_map("ebus_j1939")).samples[
        "battery_current_a"]
    assert len(theirs.samples) == len(ours[1])
    np.testing.assert_allclose(theirs.samples, ours[1], atol=1e-9)


def _mangled(frames: Frames) -> Frames:
    """Frames with an unknown id, short CCVS1 frames and 'not available' speeds added."""
    f = with_unknown_id(frames, 0x18FEE900, 2.0)
    ccvs = np.flatnonzero(f.can_id == 0x18FEF100)
    f.length = f.length.copy()
    f.length[ccvs[5:12]] = 4  # 7 frames with a wrong DLC
    f.data = f.data.copy()
    f.data[ccvs[20:23], 1:3] = 0xFF  # 3 speeds 0xFFFF: J1939 "not available"
    return f


def test_unknown_ids_bad_lengths_and_out_of_range_values_are_counted_by_signal(frames,
                                                                                tmp_path):
    path = write_frames(_mangled(frames), tmp_path / "bus.mf4")
    log = load_log(path, columns="ebus_j1939")
    counts = log.report.frames
    speed = counts["signals"]["speed_kmh"]
    assert speed["bad_length"] == 7 and speed["lengths"] == {4: 7}
    assert speed["out_of_range"] == 3 and speed["example"].startswith("255.996")
    assert speed["values"] == speed["frames"] - 10
    assert counts["unknown_ids"] == {"0x18FEE900": 750}
    warning = next(w for w in log.report.warnings if w.startswith("speed_kmh"))
    assert "7 frames of another length (4 bytes) than the DBC's 8" in warning
    assert "3 values outside its range" in warning
    assert any("750 frames with ids the DBC does not have: 0x18FEE900" in line
               for line in log.report.ignored)
    assert log.profile.channels["speed_ref_mps"].max() * 3.6 < 100  # no 255.99 km/h


def test_a_required_signal_that_is_missing_names_the_signal_and_the_fix(frames, tmp_path):
    keep = np.flatnonzero(frames.can_id != 0x18FF11F3)  # no BMS2: no SoC
    path = write_frames(frames.take(keep), tmp_path / "bus.mf4")
    with pytest.raises(LogError, match=r"required signal BMS2\.PackSoC \(soc_pct\) is missing: "
                                       r"no frame of BMS2 \(id 0x18FF11F3\).*required: false"):
        load_log(path, columns="ebus_j1939")


def test_a_logger_file_needs_a_signal_map_and_a_table_a_column_map(frames, tmp_path, day):
    path = write_frames(frames, tmp_path / "bus.mf4")
    with pytest.raises(LogError, match="--columns ebus_j1939"):
        load_log(path)
    with pytest.raises(ConfigError, match="column map for CSV"):
        load_log(path, columns="bmw_i3_tum")
    csv = tmp_path / "day.csv"
    day.to_csv(csv, index=False)
    with pytest.raises(ConfigError, match="is a CAN signal map"):
        load_log(csv, columns="ebus_j1939")


def test_without_the_can_extra_the_error_names_the_pip_command(frames, tmp_path, monkeypatch):
    path = write_frames(frames, tmp_path / "bus.mf4")
    monkeypatch.setitem(sys.modules, "cantools", None)  # as if not installed
    with pytest.raises(ConfigError, match=r"pip install 'ebus-env\[can\]'"):
        load_log(path, columns="ebus_j1939")


def _map(**signals):
    return {"dbc": str(DBC), "signals": signals}


def test_signal_map_mistakes_are_named_with_the_close_match():
    with pytest.raises(ConfigError, match="no message 'CCVS'. Did you mean 'CCVS1'"):
        load_signal_map(_map(speed_kmh="CCVS.WheelBasedVehicleSpeed"))
    with pytest.raises(ConfigError, match="unknown key 'requierd'. Did you mean 'required'"):
        load_signal_map(_map(speed_kmh={"signal": "WheelBasedVehicleSpeed", "requierd": True}))
    with pytest.raises(ConfigError, match="is in 'V', the column in 'km/h'"):
        load_signal_map(_map(speed_kmh="BMS1.PackVoltage"))
    with pytest.raises(ConfigError, match="sample 'median' is none of"):
        load_signal_map(_map(soc_pct={"signal": "PackSoC", "sample": "median"}))
    with pytest.raises(ConfigError, match="timezone 'Berlin' is no IANA time zone"):
        load_signal_map({**_map(soc_pct="PackSoC"), "timezone": "Berlin"})


def test_a_signal_in_another_unit_is_converted_to_the_columns(frames, tmp_path, day):
    """A DBC whose speed is in m/s (declared by the map's unit:) gives km/h x 3.6 / 3.6."""
    path = write_frames(frames, tmp_path / "bus.mf4")
    smap = load_signal_map(_map(
        speed_kmh={"signal": "WheelBasedVehicleSpeed", "unit": "m/s"},
        battery_current_a={"signal": "PackCurrent", "scale": -1}))
    table, _ = to_table(decode(read_frames(path), smap), smap)
    np.testing.assert_allclose(table["speed_kmh"], 3.6 * day["speed_kmh"], atol=3.6 / 512)
    np.testing.assert_allclose(table["battery_current_a"], -day["battery_current_a"],
                               atol=0.025 + 1e-9)


def test_sampling_last_holds_only_so_long_and_a_default_fills_with_a_count(frames, tmp_path):
    # the SoC message falls silent for 20 s: 'last' holds 5 s, then the rows have none
    t = frames.time_s
    silent = (frames.can_id == 0x18FF11F3) & (t > 300) & (t < 320)
    smap = load_signal_map(_map(speed_kmh="WheelBasedVehicleSpeed",
                                soc_pct={"signal": "PackSoC", "hold_s": 5},
                                door_open={"signal": "DoorOpen", "default": 0}))
    decoded = decode(frames.take(np.flatnonzero(~silent)), smap)
    table, _ = to_table(decoded, smap)
    missing = table.index[table["soc_pct"].isna()]
    assert 10 <= len(missing) <= 16  # 20 s silent, the last value held for 5 s
    assert (table["door_open"] == 0).all()  # PAX never sent: the default, counted
    assert decoded.counts.signals["door_open"].filled == len(table)
    path = write_frames(frames.take(np.flatnonzero(~silent)), tmp_path / "bus.mf4")
    with pytest.raises(LogError, match="Missing values"):
        load_log(path, columns="ebus_j1939")
    log = load_log(path, columns="ebus_j1939", fill="interpolate")
    assert any("'soc_pct'" in line and "filled by linear interpolation" in line
               for line in log.report.changes)


def test_a_clock_without_a_zone_takes_the_maps_timezone_or_says_it_is_utc(frames, tmp_path):
    path = write_frames(frames, tmp_path / "bus.blf")  # BLF: the logger's local clock
    smap = load_signal_map(_map(speed_kmh="WheelBasedVehicleSpeed"))
    decoded = decode(read_frames(path), smap)
    assert decoded.zone == datetime.UTC
    assert any("taken as UTC" in n for n in decoded.notes)
    table, _ = to_table(decoded, smap)
    assert table["timestamp"].iloc[0] == "2026-01-14T06:50:00+00:00"
    berlin = load_signal_map({**_map(speed_kmh="WheelBasedVehicleSpeed"),
                              "timezone": "Europe/Berlin"})
    table, _ = to_table(decode(read_frames(path), berlin), berlin)
    assert table["timestamp"].iloc[0] == "2026-01-14T06:50:00+01:00"


def test_the_shipped_examples_are_the_encoded_control_day():
    """data/can/example_day.mf4 (and .blf, its first 10 min) are what write_examples makes
    of the control day: they decode to that day's values."""
    day = day_table("control", hours=2.0)
    log = load_log(paths.data("can", "example_day.mf4"), columns="ebus_j1939")
    table, _ = to_table(decode(read_frames(paths.data("can", "example_day.mf4")),
                               load_signal_map("ebus_j1939")), load_signal_map("ebus_j1939"))
    assert len(table) == len(day) == 7200
    for column, step in RESOLUTION.items():
        assert np.abs(table[column] - day[column]).max() <= step / 2 + 1e-9, column
    assert log.report.frames["unknown_ids"] == {"0x18FECA00": 7200}  # DM1, counted
    blf = load_log(paths.data("can", "example_day.blf"), columns="ebus_j1939")
    assert blf.profile.duration_s == pytest.approx(599, abs=1)


def test_ebus_simulate_reads_a_logger_file_and_prints_what_was_decoded(tmp_path):
    from typer.testing import CliRunner

    from ebus_env.cli import app

    result = CliRunner().invoke(app, ["simulate", "--measured", "data/can/example_day.blf",
                                      "--columns", "ebus_j1939"])
    assert result.exit_code == 0, result.output
    assert "decoded" in result.output and "CCVS1.WheelBasedVehicleSpeed" in result.output
    assert "0x18FECA00" in result.output
