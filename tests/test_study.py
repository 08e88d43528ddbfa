"""Fleet studies: the study file's checks, the cost model, the site simulation (charger
queueing, site limit, depot), streamed results with resume, and the summary."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from ebus_env import paths
from ebus_env.errors import ConfigError
from ebus_env.study import load_study, read_results
from ebus_env.study.backends import run_study
from ebus_env.study.costs import CostModel
from ebus_env.study.rows import rows_dir
from ebus_env.study.runner import depot, forget_batches, run_scenario
from ebus_env.study.scenarios import scenarios
from ebus_env.study.summary import pareto_front, write_summary

EXAMPLE = paths.configs("studies") / "example.yaml"
COSTS = yaml.safe_load(EXAMPLE.read_text())["costs"]
SMALL = {  # three buses for 2 h from 70 % SoC (so that they charge): seconds per scenario
    "name": "small",
    "lines": [{"name": "sort2", "cycle": "sort2", "buses": 3, "service_h": 2.0,
               "layover_min": 6.0, "laps_per_trip": 3, "soc_start_pct": 70.0}],
    "infrastructure": {"terminal_chargers": [1, 3], "terminal_charger_kw": 450,
                       "depot_chargers": 1, "depot_charger_kw": 100, "site_limit_kw": 500},
    "strategies": [{"name": "baseline"}, {"name": "eco_charging", "charge_power_frac": 0.5}],
    "days": {"count": 2, "seed": 3},
    "costs": COSTS,
}


def small(**changes) -> dict:
    data = copy.deepcopy(SMALL)
    for path, value in changes.items():
        node = data
        *head, last = path.split(".")
        for key in head:
            node = node[int(key)] if isinstance(node, list) else node[key]
        if value is None:
            del node[last]
        else:
            node[last] = value
    return data


# -- the study file ------------------------------------------------------------------------------
def test_example_study_loads_into_its_grid():
    spec = load_study(EXAMPLE)
    assert len(spec.infrastructure) == 4 and len(spec.strategies) == 3
    assert len(scenarios(spec)) == 12 and spec.climate == {"place": "gothenburg", "month": 1}
    assert spec.costs.energy_price_per_kwh[18] == 0.28


@pytest.mark.parametrize("changes, message", [
    ({"infrastructure.site_limt_kw": 3}, "unknown key 'site_limt_kw'. Did you mean 'site_limit_kw'"),
    ({"costs.demand_charge_per_kw_month": None}, "costs: missing demand_charge_per_kw_month"),
    ({"costs.energy_price_per_kwh": [0.1] * 23}, "24 hourly prices"),
    ({"lines.0.headway_min": 70.0}, "would not all depart within service_h"),
    ({"infrastructure.terminal_chargers": 0, "infrastructure.depot_chargers": 0},
     "no terminal and no depot charger"),
    ({"strategies.1.charge_power_frac": 1.5}, "charge_power_frac = 1.5: give a number in [0.1, 1]"),
    ({"lines.0.buses": 0}, "lines[0].buses = 0"),
    ({"lines.0.bus": "13m"}, "13m"),
    ({"days.count": 1.5}, "days.count = 1.5"),
    ({"strategies.0.decision_s": 70}, "divisor of 900"),
    ({"days.seed": -1}, "days.seed = -1: give an integer >= 0"),
    ({"infrastructure.depot_charger_kw": 5000},
     "infrastructure.depot_charger_kw = 5000.0 is outside the accepted range (0, 1,000] kW"),
    ({"strategies.1.pulse_duty": True}, "pulse_duty = True: give a number"),
])
def test_bad_study_is_one_clear_line_before_any_work(changes, message, tmp_path):
    with pytest.raises(ConfigError) as err:
        load_study(small(**changes))
    text = str(err.value)
    assert message in text and "\n" not in text and text.startswith("study: ")


def test_bad_study_file_names_the_file(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(small(**{"lines.0.colour": "red"})))
    with pytest.raises(ConfigError, match=rf"^{path}: lines\[0\]: unknown key 'colour'"):
        load_study(path)
    path.write_text("name: s\nlines: [\n")
    with pytest.raises(ConfigError, match=rf"^{path} is not valid YAML: .* at line 3"):
        load_study(path)
    with pytest.raises(ConfigError, match=rf"^{tmp_path} is a folder"):
        load_study(tmp_path)


def test_a_shipped_study_is_found_by_name_or_by_its_path_in_the_docs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a folder without configs/, as after installing the wheel
    assert load_study("example") == load_study("configs/studies/example.yaml") == load_study(
        EXAMPLE)
    with pytest.raises(ConfigError, match="Unknown studies config 'exampel'. Did you mean"):
        load_study("exampel")
    from ebus_env.envs.common import EnvConfig
    from ebus_env.study.fleet_calibration import fleet_logs

    assert len(fleet_logs("data/measured/bmw_i3_tum")) == 8
    assert EnvConfig.load("configs/env/gothenburg_may.yaml") == EnvConfig.load("gothenburg_may")


# -- costs -------------------------------------------------------------------------------------
def test_cost_of_a_day_by_hand():
    costs = CostModel.load({**COSTS, "energy_price_per_kwh": 0.2, "interest_rate": 0.05,
                            "charger_life_years": 10, "operating_days_per_year": 300})
    assert costs.annuity_factor == pytest.approx(0.05 / (1 - 1.05 ** -10))  # 0.1295
    load_kw = np.full(96, 100.0)  # 100 kW for 24 h in 15-min steps
    day = costs.day(load_kw, 0.25, 5.0, 100.0, 1000.0, 500.0)
    assert day["energy"] == pytest.approx(2400 * 0.2)
    assert day["demand"] == pytest.approx(100 * COSTS["demand_charge_per_kw_month"] * 12 / 300)
    assert day["chargers"] == pytest.approx(1000 * COSTS["charger_capex_per_kw"] * 0.129505 / 300,
                                            rel=1e-5)
    assert day["battery_wear"] == pytest.approx(500 * COSTS["battery_price_per_kwh"]
                                                / COSTS["battery_cycle_life_efc"])
    prices = CostModel.load(COSTS)  # time of use: the same energy costs more at 18:00
    evening = prices.day(np.array([100.0]), 1.0, 18.0, 0, 0, 0)["energy"]
    assert evening == pytest.approx(28.0) and prices.day(np.array([100.0]), 1.0, 2.0, 0, 0,
                                                         0)["energy"] == pytest.approx(12.0)


def test_depot_queues_on_its_plugs_behind_the_site_limit():
    # two plugs of 100 kW, three buses of 150, 50 and 100 kWh, 1 h steps
    load, short, busy_h = depot(np.array([150.0, 50.0, 100.0]), 2, 100.0, 1e6, 1.0, 8.0)
    # hour 1: buses 0 and 1 (100 + 50 kWh); hour 2: bus 2 on bus 1's plug, bus 0's last 50
    assert load[:4].tolist() == [150.0, 150.0, 0.0, 0.0]
    assert short == 0 and busy_h == 4.0 and load.sum() == 300.0
    load, short, _ = depot(np.array([150.0, 50.0, 100.0]), 2, 100.0, 120.0, 1.0, 2.0)
    assert load.max() <= 120.0 and short == 2  # the limit stretches it past the window


# -- the site ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def small_rows():
    spec = load_study(small())
    return spec, pd.DataFrame([r for s in scenarios(spec) for r in run_scenario(spec, s)])


def test_site_load_respects_the_limit_and_balances(small_rows):
    spec, rows = small_rows
    for _, r in rows.iterrows():
        assert r["site_load_kw"].max() <= r["site_limit_kw"] + 1e-6
        assert r["grid_kwh"] == pytest.approx(r["terminal_grid_kwh"] + r["depot_grid_kwh"])
        assert r["grid_kwh"] == pytest.approx(r["site_load_kw"].sum() * r["load_step_s"] / 3600)
        assert r["kwh_per_km"] == pytest.approx(r["grid_kwh"] / r["distance_km"])
        assert r["distance_km"] > 3 * 20  # 3 buses, 2 h, 60 % of it driving at ~20 km/h
        assert r["cost_per_km"] == pytest.approx(sum(r[f"cost_{p}_per_km"] for p in (
            "energy", "demand", "chargers", "battery_wear")))


def test_buses_queue_at_a_busy_charger(small_rows):
    _, rows = small_rows
    base = rows[rows["strategy"] == "baseline"].set_index(["terminal_chargers", "day"])
    one, three = base.loc[1], base.loc[3]
    # each bus lays over 6 of every 14.8 min: three buses need 1.2 plugs, so with one plug it
    # is always taken and buses wait; with three, nobody waits and each plug is used 40 %
    assert (one["charger_wait_bus_h"] > 0.2).all() and (three["charger_wait_bus_h"] < 1e-9).all()
    assert one["charger_utilisation"].to_numpy() == pytest.approx(1.0)
    assert three["charger_utilisation"].to_numpy() == pytest.approx(1.2 / 3, abs=0.02)
    # the same seeded days in every scenario: the buses drive the same kilometres
    assert one["distance_km"].to_numpy() == pytest.approx(three["distance_km"].to_numpy(),
                                                          rel=1e-3)


def test_lower_charging_power_lowers_the_terminal_peak(small_rows):
    _, rows = small_rows
    by = rows.groupby("strategy")
    assert by["terminal_grid_kwh"].mean()["eco_charging"] < by["terminal_grid_kwh"].mean()[
        "baseline"]
    one = rows[rows["terminal_chargers"] == 1].groupby("strategy")["site_peak_kw"].max()
    assert one["baseline"] == pytest.approx(450 / 0.95, rel=1e-3)  # one plug, its grid draw
    assert one["eco_charging"] == pytest.approx(0.5 * 450 / 0.95, rel=1e-3)


def test_a_study_is_deterministic(small_rows):
    spec, rows = small_rows
    again = pd.DataFrame(run_scenario(spec, scenarios(spec)[0]))
    first = rows[rows["scenario"] == scenarios(spec)[0].name].reset_index(drop=True)
    assert again["cost_per_km"].tolist() == first["cost_per_km"].tolist()


def test_parallel_study_equals_a_serial_one(tmp_path):
    # two threads, and batches handed from one scenario to the next: the rows stay bit-identical
    spec = load_study(small(**{"infrastructure.terminal_chargers": [1, 2, 3]}))
    serial = run_study(spec, tmp_path / "serial", workers=1, say=lambda _: None)
    parallel = run_study(spec, tmp_path / "parallel", workers=2, say=lambda _: None)
    assert len(serial) == 2 * len(scenarios(spec)) == 12
    pd.testing.assert_frame_equal(parallel.drop(columns="site_load_kw"),
                                  serial.drop(columns="site_load_kw"), check_exact=True)
    for a, b in zip(parallel["site_load_kw"], serial["site_load_kw"], strict=True):
        assert np.array_equal(a, b)
    fresh = []
    for s in scenarios(spec):  # each on new batches
        forget_batches()
        fresh += run_scenario(spec, s)
    assert [r["cost_per_km"] for r in fresh] == serial["cost_per_km"].tolist()


def test_a_scenarios_days_split_over_threads_equal_one_run(tmp_path):
    spec = load_study(small(**{"infrastructure.terminal_chargers": 2, "strategies": [
        {"name": "baseline"}], "days.count": 3}))
    said = []
    split = run_study(spec, tmp_path / "split", workers=2, say=said.append)
    assert said.count("  T2x450kW_D1x100kW_L500kW__baseline: done") == 1  # one file, when whole
    whole = pd.DataFrame(run_scenario(spec, scenarios(spec)[0]))
    assert split["day"].tolist() == [0, 1, 2]
    assert split["cost_per_km"].tolist() == whole["cost_per_km"].tolist()
    assert split["site_peak_15min_kw"].tolist() == whole["site_peak_15min_kw"].tolist()


# -- results on disk ---------------------------------------------------------------------------
@pytest.mark.parametrize("workers, tasks, share", [(1, 2, 1), (2, 1, 2), (2, 2, 1),
                                                    (4, 2, 2), (2, 5, 1)])
def test_workers_mean_cpus_in_all_each_task_gets_its_share(workers, tasks, share,
                                                           monkeypatch):
    """--workers N: N threads in all, a task's own batches included (a task alone may split
    its batches over all N; N tasks get one each)."""
    from ebus_env.model.threads import default_threads, thread_budget
    from ebus_env.study.backends import map_tasks

    monkeypatch.setenv("EBUS_THREADS", "8")
    seen: list[int] = []
    map_tasks(default_threads, [()] * tasks, lambda _, got: seen.append(got), workers=workers)
    assert seen == [share] * tasks
    assert default_threads() == 8  # the caller's thread keeps the machine's count
    with thread_budget(3):
        assert default_threads() == 3
    assert default_threads() == 8


def test_rows_stream_per_scenario_and_resume_skips_finished(tmp_path):
    spec = load_study(small(**{"infrastructure.terminal_chargers": 2, "days.count": 1}))
    full = run_study(spec, tmp_path, say=lambda _: None)
    files = sorted(rows_dir(tmp_path).glob("*.parquet"))
    assert len(files) == 2 and len(full) == 2
    with pytest.raises(ConfigError, match="--resume"):
        run_study(spec, tmp_path, say=lambda _: None)
    files[1].unlink()  # as if stopped before the second scenario finished
    said = []
    resumed = run_study(spec, tmp_path, resume=True, say=said.append)
    assert "1 already done, 1 to run" in said[0]
    pd.testing.assert_frame_equal(resumed.drop(columns="site_load_kw"),
                                  full.drop(columns="site_load_kw"))
    assert sorted(p.name for p in rows_dir(tmp_path).iterdir()) == [f.name for f in files]
    assert not list(tmp_path.rglob("*.tmp"))


def test_another_study_in_the_folder_is_not_reused(tmp_path):
    spec = load_study(small(**{"infrastructure.terminal_chargers": 2, "days.count": 1}))
    run_study(spec, tmp_path, say=lambda _: None)
    other = load_study(small(**{"infrastructure.terminal_chargers": 2, "days.count": 1,
                                "costs.interest_rate": 0.08}))
    said = []
    rows = run_study(other, tmp_path, resume=True, say=said.append)
    assert "2 scenario(s) in" in said[0] and "left out of its summary" in said[0]
    assert "0 already done, 2 to run" in said[1]
    # the summary holds this study's two scenarios, not the other study's rows beside them
    assert len(list(rows_dir(tmp_path).glob("*.parquet"))) == 4
    assert len(rows) == 2 and set(rows["scenario_key"]) == {s.key(other) for s in scenarios(other)}


# -- summary -----------------------------------------------------------------------------------
def test_pareto_front_by_hand():
    cost = np.array([1.0, 2.0, 1.5, 0.5, 3.0])
    peak = np.array([500., 300., 400., 600., 200.])
    ok = np.array([True, True, False, False, True])
    # 2 and 3 are infeasible; 0, 1, 4 trade cost for peak
    assert pareto_front(cost, peak, ok).tolist() == [True, True, False, False, True]
    assert pareto_front(cost, peak + np.array([0, 0, 0, 0, 400.]), ok).tolist() == [
        True, True, False, False, False]


def test_summary_and_report(small_rows, tmp_path):
    spec, rows = small_rows
    summary = write_summary(spec, rows, tmp_path)
    assert len(summary) == 4 and summary["cost_per_km"].is_monotonic_increasing
    assert summary["pareto"].any() and (summary.loc[summary["pareto"], "feasible"]).all()
    page = (tmp_path / "report.html").read_text()
    assert page.count('src="data:image/png;base64,') == 4 and "Pareto front" in page
    assert "Cheapest feasible" in page and summary.iloc[0]["scenario"] in page
    assert {p.name for p in tmp_path.glob("*.png")} == {"pareto.png", "cost_split.png",
                                                         "site_load.png", "utilisation.png"}
    assert pd.read_csv(tmp_path / "summary.csv")["scenario"].tolist() == summary[
        "scenario"].tolist()


def test_read_results_of_an_empty_folder_is_empty(tmp_path):
    assert read_results(tmp_path).empty


# -- command line ------------------------------------------------------------------------------
def test_study_command_runs_and_refuses_a_bad_file(tmp_path):
    from typer.testing import CliRunner

    from ebus_env.cli import app

    runner = CliRunner()
    good = tmp_path / "small.yaml"
    good.write_text(yaml.safe_dump(small(**{"infrastructure.terminal_chargers": 2,
                                            "days.count": 1})))
    result = runner.invoke(app, ["study", str(good), "--out", str(tmp_path / "out"),
                                 "--workers", "1"])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "out" / "report.html").exists() and "Pareto" in result.output
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(small(**{"costs.currency": None})))
    result = runner.invoke(app, ["study", str(bad), "--out", str(tmp_path / "bad_out")])
    assert result.exit_code != 0 and "costs: missing currency" in result.output
    assert not (tmp_path / "bad_out").exists()  # nothing started
    # an --out folder that holds the study file would have its study.yaml written over it
    inside = tmp_path / "inside"
    inside.mkdir()
    (inside / "study.yaml").write_bytes(good.read_bytes() + b"# my notes\n")
    before = (inside / "study.yaml").read_bytes()
    result = runner.invoke(app, ["study", str(inside / "study.yaml"), "--out", str(inside)])
    assert result.exit_code != 0 and "holds the input" in result.output
    assert (inside / "study.yaml").read_bytes() == before and not (inside / "rows").exists()
    result = runner.invoke(app, ["study", str(good), "--out", str(good)])
    assert result.exit_code != 0 and "is a file, not a folder" in result.output
    result = runner.invoke(app, ["study", str(good), "--out", str(tmp_path / "w"),
                                 "--workers", "0"])
    assert result.exit_code != 0 and "--workers 0: give a number of threads" in result.output


def test_a_policy_that_holds_the_baseline_equals_the_fixed_baseline(monkeypatch):
    monkeypatch.syspath_prepend(str(Path(__file__).parent))  # tests/study_faults.py
    spec = load_study(small(**{"infrastructure.terminal_chargers": 1, "days.count": 1,
                               "strategies": [{"name": "baseline"},
                                              {"name": "held", "policy": "study_faults:die_once"}]}))
    fixed, held = (pd.DataFrame(run_scenario(spec, s)) for s in scenarios(spec))
    columns = [c for c in fixed.columns if c not in ("scenario", "strategy", "site_load_kw")]
    pd.testing.assert_frame_equal(fixed[columns], held[columns])
    with pytest.raises(ConfigError, match="policy = 'no_such_module:f': give 'module:factory'"):
        load_study(small(**{"strategies": [{"name": "x", "policy": "no_such_module:f"}]}))
    typo = load_study(small(**{"strategies": [{"name": "x", "policy": "study_faults:die_onse"}]}))
    with pytest.raises(ConfigError, match="policy 'study_faults:die_onse'"):
        run_scenario(typo, scenarios(typo)[0])


def test_a_bus_that_runs_its_pack_empty_strands_and_the_study_counts_it():
    """Three buses from 8 % SoC with no terminal charger: each empties its pack within the
    2 h, the BMS opens it and the bus stands; the study counts the buses short and the service
    hours they lose, and their lowest SoC is the pack's floor."""
    spec = load_study(small(**{"lines.0.soc_start_pct": 8.0,
                               "infrastructure.terminal_chargers": 0}))
    (row,) = run_scenario(spec, scenarios(spec)[0], days=[0])
    assert row["buses_short"] == 3
    assert 0.3 < row["service_hours_lost"] < 3 * 2.0
    assert row["lowest_soc_pct"] == pytest.approx(0.0, abs=0.01)
    enough = load_study(small(**{"infrastructure.terminal_chargers": 0}))
    (full,) = run_scenario(enough, scenarios(enough)[0], days=[0])
    assert full["buses_short"] == 0 and full["service_hours_lost"] == 0.0
