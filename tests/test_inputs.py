"""Every bad input gets one clear line of the project's own type; unusual ones a warning.

The ranges live in ``ebus_env.inputs``; ``docs/inputs.md`` shows them as one table.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import gymnasium
import numpy as np
import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

import ebus_env  # noqa: F401  (registers the envs)
from ebus_env.cli import app
from ebus_env.config import load_bus
from ebus_env.errors import ConfigError, EbusError, EnvError, InputWarning, LogError
from ebus_env.inputs import RANGES, check, markdown_table
from ebus_env.io.measured import load_log
from tests.conftest import DT

ROOT = Path(__file__).resolve().parent.parent
runner = CliRunner()


def invoke(*args):
    result = runner.invoke(app, [str(a) for a in args], catch_exceptions=False)
    return result.exit_code, result.output


def test_docs_show_the_declared_ranges_as_one_table():
    assert markdown_table() in (ROOT / "docs" / "inputs.md").read_text()
    assert "](docs/inputs.md)" in (ROOT / "README.md").read_text()  # the README links the table


def test_a_range_refuses_outside_warns_in_the_margin_and_passes_inside():
    with pytest.raises(ConfigError, match=r"outside the accepted range \(0, 100\] km/h"):
        check("mean_speed_kmh", 0.0, "--mean-speed-kmh")
    for bad in (float("nan"), float("inf"), "fast", None, True):
        with pytest.raises(ConfigError):
            check("hours", bad)
    with pytest.warns(InputWarning, match="60 km/h is outside the usual 5-50 km/h"):
        assert len(check("mean_speed_kmh", 60.0)) == 1
    assert check("mean_speed_kmh", 20.0) == []
    assert RANGES["hours"].text() == "(0, 48] h"


@pytest.mark.parametrize(("args", "words"), [
    (["--hours", "1e6"], "hours = 1000000.0 is outside the accepted range (0, 48] h"),
    (["--hours", "0"], "(0, 48] h"),
    (["--hours", "-1"], "(0, 48] h"),
    (["--hours", "nan"], "hours = nan"),
    (["--dt", "0"], "[0.01, 1] s"),
    (["--dt", "-0.1"], "[0.01, 1] s"),
    (["--dt", "60"], "dt_s = 60.0"),
    (["--hours", "48", "--dt", "0.01"], "steps"),
    (["--ambient-degc", "inf"], "[-50, 60] degC"),
    (["--ambient-degc", "285"], "not kelvin"),
    (["--mean-speed-kmh", "0"], "(0, 100] km/h"),
    (["--mean-speed-kmh", "500"], "(0, 100] km/h"),
    (["--soc-start-pct", "150"], "[0, 100] %"),
    (["--load", "2"], "[0, 1]"),
    (["--set", "aero_drag.drag_coef=fast"], "not a number"),
])
def test_simulate_refuses_values_outside_their_range(args, words):
    code, out = invoke("simulate", *args)
    assert code == 2 and "error:" in out and words in out, out
    assert "Traceback" not in out and "consumption" not in out


@pytest.mark.parametrize(("args", "words"), [
    (["--soc-start-pct", "0.9"], "--soc-start-pct = 0.9 % is below the usual 5 %"),
    (["--mean-speed-kmh", "60"], "mean_speed_kmh = 60 km/h is outside the usual 5-50 km/h"),
    (["--dt", "0.5"], "dt_s = 0.5 s is above the usual 0.2 s"),
])
def test_simulate_warns_once_for_unusual_values_and_runs(args, words):
    code, out = invoke("simulate", "--hours", "0.2", *args)
    assert code == 0, out
    assert out.count(words) == 1 and "consumption" in out


def test_calibrate_and_diagnose_refuse_their_bad_settings(tmp_path):
    log = ROOT / "data/measured/bmw_i3_tum/TripB02_1hz.csv"
    for option, value, words in (("--population", 0, "[2, 1,000]"),
                                 ("--iterations", 0, "[1, 100,000]")):
        code, out = invoke("calibrate", log, "--bus", "bmw_i3", option, value)
        assert code == 2 and words in out, out
    for value in ("0", "-60"):
        code, out = invoke("diagnose", log, "--bus", "bmw_i3", "--window-s", value)
        assert code == 2 and "[10, 86,400] s" in out, out
    code, out = invoke("diagnose", log, "--bus", "bmw_i3", "--set", "aero_drag.drag_coef=x")
    assert code == 2 and "not a number" in out


def _log_without_soc(tmp_path) -> Path:
    t = np.arange(900.0)
    path = tmp_path / "nosoc.csv"
    pd.DataFrame({"time_s": t, "speed_kmh": np.clip(30 * np.sin(t / 60), 0, None)}).to_csv(
        path, index=False)
    return path


def test_a_log_without_soc_is_an_error_for_diagnose_and_a_note_for_simulate(tmp_path):
    path = _log_without_soc(tmp_path)
    code, out = invoke("diagnose", path)
    assert code == 2 and "compares simulated with measured SoC" in out and "nosoc" in out
    code, out = invoke("simulate", "--measured", path)
    assert code == 0, out
    assert "the log has no SoC: the battery started at 90.0 %" in out
    assert "no clock time: its first row is taken as 00:00" in out


def test_a_start_time_sets_the_clock_of_a_log_without_one(tmp_path):
    path = _log_without_soc(tmp_path)
    log = load_log(path, DT, start_h=7.5)
    assert log.profiles[0].start_time_h == 7.5
    time_of_day = log.profiles[0].channel("time_of_day_h")
    assert time_of_day[0] == pytest.approx(7.5) and time_of_day[-1] == pytest.approx(7.75, abs=1e-3)
    assert not any("00:00" in line for line in log.report.changes)
    code, out = invoke("simulate", "--measured", path, "--start-time", "07:30")
    assert code == 0 and "00:00" not in out, out
    for bad, words in (("7h30", "needs HH:MM"), ("24:10", "not a time of day")):
        code, out = invoke("simulate", "--measured", path, "--start-time", bad)
        assert code == 2 and words in out, out
    with pytest.raises(ConfigError, match="log_start_h"):
        load_log(path, DT, start_h=25.0)
    stamped = tmp_path / "stamped.csv"
    pd.DataFrame({"timestamp": pd.date_range("2025-05-01 06:00", periods=60, freq="s"),
                  "speed_kmh": 0.0, "soc_pct": 80.0}).to_csv(stamped, index=False)
    assert load_log(stamped, DT).profiles[0].start_time_h == 6.0
    with pytest.raises(LogError, match="first row at 06:00:00") as err:
        load_log(stamped, DT, start_h=7.5)
    assert "leave out the start time" in str(err.value)


def _bus_file(tmp_path, edit) -> Path:
    data = yaml.safe_load((ROOT / "configs/bus/12m.yaml").read_text())
    edit(data)
    path = tmp_path / "bus.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(("edit", "words"), [
    (lambda d: d["params"]["vehicle_body"].update(curb_mass_kg="12 t"),
     "params vehicle_body.curb_mass_kg = '12 t' is not a number"),
    (lambda d: d["params"]["vehicle_body"].update(curb_mass_kg=None), "= None is not a number"),
    (lambda d: d["params"]["vehicle_body"].update(curb_mass_kg=[1, 2]), "is not a number"),
    (lambda d: d.pop("contributions"), "lists no contributions"),
    (lambda d: d["service"].update(soc_start_pct=150), "service.soc_start_pct = 150"),
    (lambda d: d["service"].update(layover_min=-6), "service.layover_min = -6"),
    (lambda d: d["service"].update(layover_every_min=0), "service.layover_every_min = 0"),
    (lambda d: d["service"].update(ambient_degc=285.0), "not kelvin"),
    (lambda d: d["service"].update(passenger_profile={0: 40, 8: 5000}),
     "service.passenger_profile[8] = 5000 is outside the accepted range [0, 300]"),
])
def test_bus_configs_with_bad_values_name_file_and_key(tmp_path, edit, words):
    path = _bus_file(tmp_path, edit)
    with pytest.raises(ConfigError) as info:
        load_bus(path)
    assert words in str(info.value) and str(path) in str(info.value)


def test_a_duplicated_yaml_key_is_an_error_with_its_line(tmp_path):
    path = tmp_path / "dup.yaml"
    path.write_text("name: a\ncontributions: [aero_drag]\nname: b\n")
    with pytest.raises(ConfigError, match="the key 'name' is given twice.*line 3"):
        load_bus(path)


def test_yaml_numbers_in_exponent_form_are_numbers(tmp_path):
    """YAML 1.1 (PyYAML) reads ``3e-4`` as a string; a config must not turn it into an error
    about a string where a number was written."""
    from ebus_env.config import read_yaml

    path = tmp_path / "n.yaml"
    path.write_text("a: 3e-4\nb: 1E6\nc: -2.5e+1\nd: 12\ne: 1e\n")
    assert read_yaml(path) == {"a": 3e-4, "b": 1e6, "c": -25.0, "d": 12, "e": "1e"}
    overlay = tmp_path / "overlay.yaml"
    overlay.write_text("params: {aero_drag: {drag_coef: 6.5e-1}}\n")
    model = load_bus("12m", overlays=[overlay]).build()
    assert model.params[model.param_index("aero_drag.drag_coef")] == 0.65


def test_the_shipped_bus_without_layovers_is_accepted():
    assert load_bus("bmw_i3").service.layover_min == 0


def _frame(period_s=1.0, n=600):
    t = np.arange(n) * period_s
    return pd.DataFrame({"time_s": t, "speed_kmh": np.clip(30 * np.sin(t / 60), 0, None),
                         "soc_pct": 90 - 0.002 * t})


def test_time_in_milliseconds_is_named(tmp_path):
    frame = _frame()
    frame["time_s"] *= 1000
    frame.to_csv(tmp_path / "ms.csv", index=False)
    with pytest.raises(LogError, match="Times look like milliseconds"):
        load_log(tmp_path / "ms.csv", DT)


def test_logs_slower_than_half_a_hertz_are_refused_and_faster_than_20_hz_warned(tmp_path):
    _frame(10.0).to_csv(tmp_path / "slow.csv", index=False)
    with pytest.raises(LogError, match=r"\[0.001, 2\] s.*--sparse"):
        load_log(tmp_path / "slow.csv", DT)
    _frame(0.01, 3000).to_csv(tmp_path / "fast.csv", index=False)
    log = load_log(tmp_path / "fast.csv", DT)
    assert any("below the usual 0.05 s" in w for w in log.report.warnings)


def test_a_kelvin_ambient_column_is_refused_with_its_rows(tmp_path):
    frame = _frame()
    frame["ambient_degc"] = 285.0
    frame.to_csv(tmp_path / "k.csv", index=False)
    with pytest.raises(LogError, match="ambient_degc.*not kelvin"):
        load_log(tmp_path / "k.csv", DT)


def test_unknown_columns_are_named_with_the_preset_that_maps_them():
    log = load_log(ROOT / "data/measured/bmw_i3_tum/TripB02_1hz.csv", DT)
    assert any("'throttle_pct'" in c for c in log.report.changes)
    assert any("preset 'bmw_i3_tum' maps 'ambient_temp_c'" in w for w in log.report.warnings)
    mapped = load_log(ROOT / "data/measured/bmw_i3_tum/TripB02_1hz.csv", DT,
                      columns="bmw_i3_tum")
    assert not any("preset" in w for w in mapped.report.warnings)


def test_a_user_effect_numba_cannot_compile_is_named_with_file_and_line(tmp_path):
    path = tmp_path / "gusts.py"
    path.write_text(
        "from ebus_env import Param, effect\n\n\n"
        "def gust(speed_mps):\n    return speed_mps * 0.1\n\n\n"
        '@effect("gusts_unhelped", sink="road_force_n", params=[\n'
        '    Param("k_n_per_mps", 10.0, "N/(m/s)", (0.0, 100.0), "Gust force per speed"),\n'
        "])\n"
        "def gusts_unhelped(speed_mps, k_n_per_mps):\n"
        '    """Force of gusts [N]."""\n'
        "    return k_n_per_mps * gust(speed_mps)\n")
    code, out = invoke("simulate", "--hours", "0.1", "--with", f"{path}:gusts_unhelped")
    assert code == 2, out
    assert "Effect 'gusts_unhelped'" in out and f"{path}, line 13" in out and "@helper" in out


def test_the_hidden_case_writer_answers_help_without_writing(tmp_path):
    done = subprocess.run([sys.executable, "-m", "ebus_env.diagnostics.hidden", "--help"],
                          cwd=tmp_path, capture_output=True, text=True, check=True,
                          env={"PYTHONPATH": str(ROOT), "PATH": ""})
    assert "usage:" in done.stdout
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("key", "value"), [("service_h", 0), ("dt_s", 0), ("decision_s", 0),
                                            ("soc_start_pct", 150), ("layover_min", -1)])
def test_env_configs_out_of_range_are_refused(key, value):
    with pytest.raises(ConfigError, match=f"env config {key}"):
        gymnasium.make("EBus-v0", **{key: value})


def test_env_step_after_termination_is_an_error_and_reset_starts_again():
    env = gymnasium.make("EBus-v0", service_h=0.5, decision_s=600)
    env.reset(seed=0)
    action = np.zeros(5, np.float32)
    terminated = False
    for _ in range(20):
        *_, terminated, truncated, _ = env.step(action)
        if terminated:
            break
    assert terminated
    with pytest.raises(EnvError, match="call reset"):
        env.step(action)
    env.reset(seed=1)
    env.step(action)


def test_a_delay_beyond_its_observation_bound_is_in_info_and_warned():
    env = gymnasium.make("EBus-v0", layover_min=2.5, decision_s=600)
    env.reset(seed=0)
    slowest = -np.ones(5, np.float32)
    with pytest.warns(UserWarning, match="schedule_delay_min.*true value"):
        for _ in range(200):
            obs, _, terminated, truncated, info = env.step(slowest)
            if info["clipped_observations"]:
                break
    assert info["clipped_observations"] == ["schedule_delay_min"]
    assert info["schedule_delay_min"] > 60.0 and obs[7] == pytest.approx(60.0)


def test_every_error_here_is_the_projects_own():
    assert issubclass(ConfigError, EbusError) and issubclass(LogError, EbusError)
    assert issubclass(EnvError, EbusError)


def test_cycle_day_options_with_a_measured_log_are_refused_not_ignored():
    log = ROOT / "data/measured/bmw_i3_tum/TripB02_1hz.csv"
    code, out = invoke("simulate", "--bus", "bmw_i3", "--measured", log, "--hours", "2",
                       "--ambient-degc", "5")
    assert code == 2 and "--hours, --ambient-degc shape(s) a cycle day" in out


def test_a_calibration_range_with_low_above_high_is_refused():
    log = ROOT / "data/measured/bmw_i3_tum/TripB02_1hz.csv"
    code, out = invoke("calibrate", log, "--bus", "bmw_i3", "--range",
                       "vehicle_body.curb_mass_kg=1500:1200")
    assert code == 2 and "low must be below high" in out


@pytest.mark.parametrize(("edit", "words"), [
    (lambda f: f.assign(soc_pct=f["soc_pct"] / 100), "looks like a fraction"),
    (lambda f: f.assign(time_s=f["time_s"] / 10_000), "closer than one time step"),
    (lambda f: f.assign(distance_km=f["distance_km"] * 1000), "more than 400 km/h"),
    (lambda f: f.assign(ambient_degc=285.0), "not kelvin"),
    (lambda f: f.assign(soc_pct=150.0), "soc_pct"),
])
def test_sparse_logs_with_implausible_values_are_refused(tmp_path, edit, words):
    from ebus_env.io.sparse import load_sparse_log

    t = np.arange(0, 3600 * 3, 300.0)
    frame = pd.DataFrame({"time_s": t, "distance_km": 0.004 * t, "soc_pct": 90 - t / 1000})
    frame.to_csv(tmp_path / "ok.csv", index=False)
    assert load_sparse_log(tmp_path / "ok.csv", DT).profile.n_steps > 1000
    edit(frame).to_csv(tmp_path / "bad.csv", index=False)
    with pytest.raises(LogError, match=words):
        load_sparse_log(tmp_path / "bad.csv", DT)


@pytest.mark.parametrize(("text", "words"), [
    (None, "does not exist"),
    ("time_s,speed\n0,1\n1,2\n", "the columns time_s, speed_kmh"),
    ("time_s,speed_kmh\n0,1\n", "at least two rows"),
    ("time_s,speed_kmh\n0,1\n1,-5\n", "speed_kmh outside [0, 400]"),
    ("time_s,speed_kmh,grade_frac\n0,1,0\n1,2,5\n", "grade_frac beyond"),
])
def test_a_users_cycle_file_with_problems_is_refused(tmp_path, text, words):
    from ebus_env.cycles import load_cycle

    path = tmp_path / "mine.csv"
    if text is not None:
        path.write_text(text)
    with pytest.raises(ConfigError, match=re.escape(words)):
        load_cycle(str(path))


def test_a_route_file_without_its_columns_is_refused(tmp_path):
    from ebus_env.routes import load_route

    (tmp_path / "r.csv").write_text("distance_m,elevation_m\n0,1\n10,2\n")
    with pytest.raises(ConfigError, match="speed_limit_kmh"):
        load_route(tmp_path / "r.csv")
    with pytest.raises(ConfigError, match="cannot be read"):
        load_route(tmp_path / "missing.csv")


@pytest.mark.parametrize(("overrides", "words"), [
    ({"laps_per_trip": 2.5}, "whole number"), ({"passengers_peak_frac": "x"}, "not a number"),
    ({"ambient_random_k": -5}, "[0, 30] K"), ({"jerk_mps3": 0}, "(0, 10] m/s^3"),
    ({"reward": {"nope": 1}}, "Unknown reward weight"), ({"bus": 3}, "must name a config"),
    ({"charge_at_terminal": "maybe"}, "true or false"),
])
def test_env_config_values_of_the_wrong_kind_are_refused(overrides, words):
    with pytest.raises(ConfigError, match=re.escape(words)):
        gymnasium.make("EBus-v0", **overrides).reset(seed=0)
