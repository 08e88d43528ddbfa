"""The command line, end to end (in process)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from ebus_env.cli import app

ROOT = Path(__file__).resolve().parent.parent
runner = CliRunner()


def invoke(*args):
    result = runner.invoke(app, [str(a) for a in args], catch_exceptions=False)
    return result.exit_code, result.output


def test_simulate_cycle_writes_json_trace_and_plot(tmp_path):
    code, out = invoke("simulate", "--bus", "12m", "--cycle", "sort2", "--hours", "1",
                       "--json", tmp_path / "s.json", "--out", tmp_path / "t.parquet",
                       "--plot", tmp_path / "t.png")
    assert code == 0, out
    assert "consumption" in out and "aerodynamic drag" in out and "peak grid power" in out
    summary = json.loads((tmp_path / "s.json").read_text())
    for key in ("distance_km", "duration_h", "battery_energy_kwh", "kwh_per_km",
                "soc_start_pct", "soc_end_pct", "peak_grid_kw", "breakdown_kwh"):
        assert key in summary
    assert summary["duration_h"] == pytest.approx(1.0)
    assert set(summary["breakdown_kwh"]) >= {"aero_drag", "rolling_resistance", "road_grade",
                                             "friction_brake", "drivetrain_loss",
                                             "battery_ohmic_loss", "cabin_hvac", "auxiliaries",
                                             "charging", "charger_loss", "regen_recovered"}
    trace = pd.read_parquet(tmp_path / "t.parquet")
    assert len(trace) == 36000
    assert {"time_s", "speed_kmh", "soc_pct", "aero_drag_w", "cabin_hvac_w",
            "battery_loss_w", "grid_power_w", "distance_behind_m"} <= set(trace.columns)
    assert (tmp_path / "t.png").stat().st_size > 10_000


def test_simulate_measured_log_reports_soc_error(tmp_path):
    code, out = invoke("simulate", "--bus", "bmw_i3", "--columns", "bmw_i3_tum",
                       "--measured", ROOT / "data/measured/bmw_i3_tum/TripB03_1hz.csv",
                       "--json", tmp_path / "s.json")
    assert code == 0, out
    summary = json.loads((tmp_path / "s.json").read_text())
    assert 0 < summary["soc_rmse_pct"] < 20
    assert summary["soc_start_pct"] == pytest.approx(67.4)
    assert "SoC RMSE vs measured" in out
    assert "grade from 'altitude_m'" in out  # the loader says what it changed


def test_user_effect_on_the_command_line(tmp_path):
    code, out = invoke("simulate", "--cycle", "sort3", "--hours", "0.5",
                       "--with", ROOT / "tests/user_effects/headwind.py:headwind",
                       "--without", "cabin_hvac", "--set", "headwind.wind_speed_mps=6",
                       "--json", tmp_path / "s.json")
    assert code == 0, out
    breakdown = json.loads((tmp_path / "s.json").read_text())["breakdown_kwh"]
    assert breakdown["headwind"] > 0 and "cabin_hvac" not in breakdown


def test_errors_are_clear_and_exit_2(tmp_path):
    code, out = invoke("simulate", "--with", "aero_drg")
    assert code == 2 and "Did you mean 'aero_drag'" in out
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,speed_kmh\n0,1\n0,2\n1,3\n")
    code, out = invoke("simulate", "--measured", bad)
    assert code == 2 and "Duplicated times" in out and "row 1" in out
    code, out = invoke("simulate", "--set", "aero_drag.drag_coef=9")
    assert code == 2 and "outside its bounds" in out
    code, out = invoke("simulate", "--set", "aero_drag.drag_coef=0.6", "--set",
                       "aero_drag.drag_coef=0.7")
    assert code == 2 and "--set aero_drag.drag_coef is given twice (0.6 and 0.7)" in out
    code, out = invoke("simulate", "--load", "full", "--set", "passenger_load.load_frac=0")
    assert code == 2 and "--load and --set passenger_load.load_frac both" in out
    # a known value out of range is the user's value, not the bus config's
    log = ROOT / "data/measured/hidden/control.csv.gz"
    code, out = invoke("diagnose", log, "--set", "rint_battery.cell_capacity_ah=-5")
    assert code == 2 and "cell_capacity_ah' = -5.0 (override) lies outside" in out, out
    code, out = invoke("diagnose", log, "--set", "rint_battery.capacity_ah=90")
    assert code == 2 and "Did you mean 'rint_battery.cell_capacity_ah'" in out, out
    assert "listed by `ebus effects --bus NAME`" in out  # 65 names, too many to list


def test_a_fleet_calibration_refuses_the_options_it_does_not_take(tmp_path):
    code, out = invoke("calibrate", "--fleet", ROOT / "data/measured/bmw_i3_tum", "--bus",
                       "bmw_i3", "--without", "cabin_hvac", "--json", tmp_path / "x.json",
                       "--out", tmp_path / "t.csv")
    assert code == 2 and "it does not take --without, --json. Fix: leave them out" in out
    assert not (tmp_path / "t.csv").exists() and "fleet calibration:" not in out


def test_a_pack_run_empty_is_said():
    code, out = invoke("simulate", "--cycle", "sort2", "--hours", "0.9", "--soc-start-pct", 1)
    assert code == 0 and "warning: the pack ran empty 0." in out and "the BMS opened it" in out
    assert "pack empty (stranded) after" in out
    code, out = invoke("simulate", "--cycle", "sort2", "--hours", "0.2")
    assert code == 0 and "ran empty" not in out


def test_a_day_is_not_its_own_validation_or_reference(tmp_path):
    log = ROOT / "data/measured/hidden/control.csv.gz"
    copy = tmp_path / "copy.csv.gz"
    copy.write_bytes(log.read_bytes())
    code, out = invoke("calibrate", log, "--validate", copy)
    assert code == 2 and "--validate" in out and "is a log the fit is tuned on" in out
    code, out = invoke("diagnose", log, "--reference", copy)
    assert code == 2 and "is the log being diagnosed" in out and "another day" in out
    # 40 min of a normal day: too few windows to say what it misses in each operating mode
    pd.read_csv(log).iloc[:2400].to_csv(tmp_path / "short.csv", index=False)
    code, out = invoke("diagnose", log, "--reference", tmp_path / "short.csv")
    assert code == 2 and "The reference day has 7 usable window(s) of 300 s: too few" in out


def test_a_log_given_twice_a_window_longer_than_the_log_and_the_demo_in_the_data(tmp_path):
    log = ROOT / "data/measured/hidden/control.csv.gz"
    copy = tmp_path / "copy.csv.gz"
    copy.write_bytes(log.read_bytes())
    code, out = invoke("diagnose", log, copy)
    assert code == 2 and "is a log given already" in out and "count twice" in out
    code, out = invoke("diagnose", log, "--window-s", 86400)
    assert code == 2 and "a shorter window (--window-s" in out, out
    code, out = invoke("demo", "--out", ROOT / "data/measured/hidden")
    assert code == 2 and "holds the input" in out
    code, out = invoke("cycles")
    assert code == 0 and "vecto_urban_13m" in out and "nyc_composite" in out  # never cut


def test_the_documented_paths_into_shipped_folders_work_from_any_folder(tmp_path, monkeypatch):
    """After a wheel install there is no configs/ or data/ in the working folder: the paths
    the documentation gives name the shipped files."""
    monkeypatch.chdir(tmp_path)
    code, out = invoke("simulate", "--bus", "configs/bus/12m.yaml", "--measured",
                       "data/measured/hidden/control.csv.gz", "--json", "s.json")
    assert code == 0, out
    assert json.loads((tmp_path / "s.json").read_text())["distance_km"] > 10
    code, out = invoke("simulate", "--bus", "configs/bus/13m.yaml")
    assert code == 2 and "configs/bus/13m.yaml does not exist" in out


def test_a_log_split_at_its_gap_keeps_its_own_times_in_the_trace(tmp_path):
    t = np.delete(np.arange(1200.0), np.arange(500, 800))  # 300 s without rows
    frame = pd.DataFrame({"time_s": t, "speed_kmh": 20.0 + 10.0 * np.sin(t / 60.0),
                          "soc_pct": 90.0 - t / 600.0})
    frame.to_csv(tmp_path / "gap.csv", index=False)
    code, out = invoke("simulate", "--measured", tmp_path / "gap.csv", "--gaps", "split",
                       "--out", tmp_path / "trace.csv")
    assert code == 0, out
    trace = pd.read_csv(tmp_path / "trace.csv")
    second = trace[trace["segment"] == 1]
    assert trace.loc[trace["segment"] == 0, "time_s"].max() < 500.0
    assert second["time_s"].iloc[0] == pytest.approx(800.0)  # where it starts in the log
    assert second["time_s"].iloc[-1] == pytest.approx(1199.0, abs=0.11)


def test_unit_check_names_its_switch_and_the_switch_turns_it_off(tmp_path):
    """A crawl at <= 20 km/h with gentle accelerations looks like m/s; the error names the
    one switch that accepts it (a plain flag: there is no double negative to type)."""
    t = np.arange(0.0, 600.0)
    speed_kmh = np.clip(np.minimum(t % 200, 200 - t % 200) * 0.3, 0.0, 20.0)
    log = tmp_path / "crawl.csv"
    pd.DataFrame({"time_s": t, "speed_kmh": speed_kmh,
                  "soc_pct": np.linspace(80.0, 79.5, len(t))}).to_csv(log, index=False)
    code, out = invoke("simulate", "--measured", log)
    assert code == 2 and "look like m/s" in out and "--no-unit-check" in out
    code, out = invoke("simulate", "--measured", log, "--no-unit-check")
    assert code == 0, out
    code, out = invoke("simulate", "--measured", log, "--no-no-unit-check")
    assert code == 2


def test_effects_and_cycles_listings():
    code, out = invoke("effects", "--bus", "12m")
    assert code == 0 and "drag_coef" in out and "cabin_hvac" in out
    code, out = invoke("cycles")
    assert code == 0 and "sort2" in out and "manhattan" in out


def test_load_categories(tmp_path):
    figures = {}
    for load in ("driver", "full"):
        code, out = invoke("simulate", "--cycle", "sort1", "--hours", "0.3", "--load", load,
                           "--json", tmp_path / f"{load}.json")
        assert code == 0, out
        figures[load] = json.loads((tmp_path / f"{load}.json").read_text())["kwh_per_km"]
    assert figures["full"] > figures["driver"]
    code, out = invoke("simulate", "--load", "heavy")
    assert code == 2 and "driver, half, full" in out
    # a log that counts its passengers sets the load: --load acts on nothing, and says so
    frame = pd.DataFrame({"time_s": np.arange(600.0), "speed_kmh": 20.0, "passengers": 30})
    frame.to_csv(tmp_path / "counted.csv", index=False)
    for load in ("driver", "full"):
        code, out = invoke("simulate", "--measured", tmp_path / "counted.csv", "--load", load,
                           "--json", tmp_path / f"counted_{load}.json")
        assert code == 0 and "the log counts the passengers on board" in out, out
    assert json.loads((tmp_path / "counted_driver.json").read_text())["kwh_per_km"] == \
        json.loads((tmp_path / "counted_full.json").read_text())["kwh_per_km"]


def test_diagnose_holds_what_the_user_knows_and_frees_what_their_config_frees(tmp_path):
    """``ebus diagnose --calibrate``: a ``--set`` value and a config's fixed value are held
    (reported as such, left out of the fit), the config's params replace the paper's, and a
    config range for a parameter the calibration does not free fails by its name."""
    log = ROOT / "data/measured/hidden/control.csv.gz"
    config = tmp_path / "known.yaml"
    config.write_text("params: [regen_cutoff.max_decel_mps2]\n"
                      "ranges: {regen_cutoff.max_decel_mps2: [1.0, 5.0]}\n"
                      "fixed: {static_rcd.rcd_frac: 0.05}\n"
                      "isopt: {iterations: 2}\npolish_starts: 0\n")
    code, out = invoke("diagnose", log, "--calibrate", "--config", config,
                       "--set", "rint_battery.cell_capacity_ah=90", "--json", tmp_path / "r.json")
    assert code == 0, out
    calibration = json.loads((tmp_path / "r.json").read_text())["calibration"]
    assert calibration["fixed"] == {"static_rcd.rcd_frac": 0.05,
                                    "rint_battery.cell_capacity_ah": 90.0}
    assert set(calibration["params"]) == {
        "regen_cutoff.max_decel_mps2", "vehicle_body.curb_mass_kg",
        "rolling_resistance.rolling_coef", "auxiliaries.base_power_w",
        "efficiency_map.gearbox_efficiency", "rint_battery.cell_resistance_mohm"}
    assert 1.0 <= calibration["params"]["regen_cutoff.max_decel_mps2"] <= 5.0
    config.write_text("ranges: {static_rcd.rcd_frac: [0.0, 0.1]}\n"
                      "fixed: {static_rcd.rcd_frac: 0.05}\n")
    code, out = invoke("diagnose", log, "--calibrate", "--config", config)
    assert code == 2 and "static_rcd.rcd_frac" in out and "not a free parameter" in out


@pytest.mark.slow
def test_diagnose_holds_a_known_value_of_an_effect_it_adds(tmp_path):
    """``--set`` for a parameter of the user's own effect that ``--add`` adds: held in the
    ladder and in the effect's signatures, so that a run time per door opening a third longer
    than the one the log was made with explains less of the missing power; a misspelt one is
    named."""
    log = ROOT / "data/measured/hidden/door_compressor.csv.gz"
    effect = f"{ROOT / 'examples/my_effects.py'}:door_compressor"
    config = tmp_path / "quick.yaml"
    config.write_text("isopt: {iterations: 2}\npolish_starts: 0\n")
    name = "door_compressor.run_per_open_s"
    explained = {}
    for value in (1.5, 2.0):
        code, out = invoke("diagnose", log, "--add", effect, "--config", config, "--set",
                           f"{name}={value}", "--json", tmp_path / f"{value}.json")
        assert code == 0, out
        report = json.loads((tmp_path / f"{value}.json").read_text())
        assert report["ladder"][-1]["values"][name] == value
        assert name not in report["ladder"][-1]["free"]
        explained[value] = next(r["explained_fraction"] for r in report["ranking"]
                                if r["effect"] == "door_compressor")
    assert explained[1.5] > explained[2.0] + 0.1, explained
    code, out = invoke("diagnose", log, "--add", effect, "--set", "door_compressor.run_per_opn_s=1")
    assert code != 0 and name in out


# -- the command line stays a thin layer over the library ---------------------------------------
def test_the_command_line_stays_thin_and_starts_light():
    """cli.py parses options and calls library functions: under 400 lines, and importing it
    (what `ebus --help` does) loads neither the model, numba nor pandas."""
    import subprocess
    import sys

    assert len((ROOT / "ebus_env" / "cli.py").read_text().splitlines()) < 400
    loaded = subprocess.run(
        [sys.executable, "-c", "import sys, ebus_env.cli; print(' '.join(sorted(sys.modules)))"],
        capture_output=True, text=True, check=True).stdout.split()
    heavy = [m for m in loaded if m.split(".")[0] in ("numba", "pandas", "matplotlib", "scipy")
             or m.startswith(("ebus_env.model", "ebus_env.config", "ebus_env.simulate"))]
    assert heavy == [] and "ebus_env.cli_options" in loaded


def test_a_command_module_registers_its_commands(monkeypatch):
    """A module named in COMMAND_MODULES adds its commands through register(app), and they run
    the way every command runs: an error as one line, exit code 2."""
    import sys
    import types

    import typer

    from ebus_env import cli
    from ebus_env.cli_options import run_command
    from ebus_env.errors import ConfigError

    def hello(name: str = "bus"):
        def body():
            if name == "nobody":
                raise ConfigError("--name nobody: give a name.")
            typer.echo(f"hello {name}")

        run_command(body)

    module = types.ModuleType("fake_commands")
    module.register = lambda app: app.command()(hello)
    monkeypatch.setitem(sys.modules, "fake_commands", module)
    monkeypatch.setattr(cli, "COMMAND_MODULES", ("fake_commands",))
    monkeypatch.setattr(cli, "app", typer.Typer())
    cli._add_commands()
    result = runner.invoke(cli.app, ["hello", "--name", "depot"])
    assert result.exit_code == 0 and "hello depot" in result.output
    assert {"hello", "evaluate", "train"} <= {c.name or c.callback.__name__
                                              for c in cli.app.registered_commands}
    result = runner.invoke(cli.app, ["hello", "--name", "nobody"])
    assert result.exit_code == 2 and "error: --name nobody: give a name." in result.output


def test_each_command_is_its_python_function(tmp_path):
    """`ebus simulate` and simulate_bus give the same day; `ebus calibrate` and calibrate_logs
    the same fit and overlay; both write the same files."""
    from ebus_env.bus_choice import BusChoice
    from ebus_env.calibration import calibrate_logs
    from ebus_env.simulate import simulate_bus

    code, out = invoke("simulate", "--cycle", "sort3", "--hours", "0.5", "--without",
                       "cabin_hvac", "--set", "aero_drag.drag_coef=0.6", "--json",
                       tmp_path / "cli.json")
    assert code == 0, out
    day = simulate_bus(BusChoice("12m", without=["cabin_hvac"]), cycle="sort3", hours=0.5,
                       params={"aero_drag.drag_coef": 0.6}, json_path=tmp_path / "api.json")
    timing = ("wall_time_s", "compile_or_load_s")
    cli_day, api_day = (json.loads((tmp_path / f"{n}.json").read_text()) for n in ("cli", "api"))
    assert {k: v for k, v in cli_day.items() if k not in timing} == \
        {k: v for k, v in api_day.items() if k not in timing}
    assert day.summary["kwh_per_km"] == pytest.approx(cli_day["kwh_per_km"], rel=1e-12)
    assert "cabin_hvac" not in day.summary["breakdown_kwh"] and day.title.startswith("12m on")

    log = ROOT / "data/measured/bmw_i3_tum/TripB03_1hz.csv"
    quick = ("--params", "passenger_load.load_frac,auxiliaries.base_power_w", "--population",
             5, "--iterations", 3)
    code, out = invoke("calibrate", log, "--bus", "bmw_i3", "--columns", "bmw_i3_tum", *quick,
                       "--out", tmp_path / "cli.yaml")
    assert code == 0, out
    fit = calibrate_logs([log], "bmw_i3", free="passenger_load.load_frac,auxiliaries.base_power_w",
                         population=5, iterations=3, reading=_reading("bmw_i3_tum"),
                         out=tmp_path / "api.yaml")
    assert fit.overlay == tmp_path / "api.yaml" and fit.plots == [] and fit.json_path is None
    cli_yaml = (tmp_path / "cli.yaml").read_text().replace(str(tmp_path / "cli.yaml"), "OUT")
    api_yaml = (tmp_path / "api.yaml").read_text().replace(str(tmp_path / "api.yaml"), "OUT")
    assert cli_yaml == api_yaml and "auxiliaries" in api_yaml


def _reading(columns):
    from ebus_env.io.log_reading import LogReading

    return LogReading(columns=columns)
