"""A timetable (GTFS) study: the shipped example feed's route 45, its blocks driven at 10 Hz
with and without terminal chargers, the depot planned three ways, the report."""

from __future__ import annotations

import json
import math

import pytest
import yaml

from ebus_env import paths
from ebus_env.errors import ConfigError
from ebus_env.study.runner import run_scenario
from ebus_env.study.scenarios import scenarios
from ebus_env.study.study_file import load_study


def example(**gtfs) -> dict:
    data = yaml.safe_load(paths.configs("studies").joinpath("gtfs_example.yaml").read_text())
    for key in ("feed", "altitude", "speed_limits"):
        data["gtfs"][key] = str(paths.data("gtfs", data["gtfs"][key].split("/")[-1]))
    data["gtfs"].update(routes=["45"], terminals=["kc45_A"], **gtfs)
    data["infrastructure"].update(terminal_chargers=[0, 1], terminal_charger_kw=300,
                                  depot_chargers=6)
    return data


@pytest.fixture(scope="module")
def rows():
    spec = load_study(example())
    return spec, {s.name: run_scenario(spec, s, [0])[0] for s in scenarios(spec)}


def test_terminal_chargers_keep_the_blocks_going(rows):
    _, r = rows
    bare, charged = r["T0x300kW_D6x100kW_L1200kW__optimal"], r["T1x300kW_D6x100kW_L1200kW__optimal"]
    assert bare["terminal_grid_kwh"] == 0.0 < charged["terminal_grid_kwh"]
    assert charged["lowest_soc_pct"] > bare["lowest_soc_pct"]
    assert charged["trips_not_served"] <= bare["trips_not_served"]
    # one plug per terminal: used part of the day, some buses wait for it; none: all wait
    assert 0.0 < charged["charger_utilisation"] <= 1.0
    assert bare["charger_utilisation"] == 0.0 < bare["charger_wait_bus_h"]
    assert charged["charger_wait_bus_h"] < bare["charger_wait_bus_h"]
    blocks = {b["block"]: b for b in json.loads(bare["block_results"])}
    more = {b["block"]: b for b in json.loads(charged["block_results"])}
    for name, b in blocks.items():  # block by block: a charger never lowers the lowest SoC
        assert more[name]["lowest_soc_pct"] >= b["lowest_soc_pct"] - 1e-6
    # a stranded block: it ran empty, its later trips are listed, and it says what it needs
    stranded = [b for b in blocks.values() if b["empty_at"]]
    assert bare["buses_short"] == len(stranded)
    for b in stranded:
        assert b["not_served"] and not b["feasible"] and b["needs"]
        assert b["lowest_soc_pct"] <= 1.0  # at its floor (the pack's soc_min_frac is 0)


def test_the_depot_plans_share_the_day_and_the_optimal_one_is_cheapest(rows):
    _, r = rows
    option = [v for k, v in r.items() if k.startswith("T0x300kW")]
    assert {v["strategy"] for v in option} == {"optimal", "on_arrival", "flat"}
    assert len({v["distance_km"] for v in option}) == 1  # one physics day, three plans
    assert len({v["lowest_soc_pct"] for v in option}) == 1
    recharged = [v for v in option if v["buses_not_recharged"] == 0]
    best = min(v["cost_per_km"] for v in recharged)
    assert r["T0x300kW_D6x100kW_L1200kW__optimal"]["cost_per_km"] == pytest.approx(best)
    for v in option:  # the site's figures hold together
        assert v["site_peak_kw"] >= v["site_peak_15min_kw"] - 1e-6
        assert v["grid_kwh"] == pytest.approx(v["terminal_grid_kwh"] + v["depot_grid_kwh"],
                                              rel=1e-6)
        assert v["depot_peak_kw"] <= 1200.0 + 1e-6  # the depot's grid limit
        parts = sum(v[f"cost_{p}_per_km"] for p in ("energy", "demand", "chargers",
                                                    "battery_wear"))
        assert v["cost_per_km"] == pytest.approx(parts)
        assert len(v["depot_load_kw"]) == 96 and len(v["site_load_kw"]) == 1440
        assert not math.isnan(v["lowest_soc_pct"])


@pytest.mark.slow
def test_the_study_command_writes_the_timetable_report(tmp_path):
    from ebus_env.study.backends import run_study
    from ebus_env.study.summary import write_summary

    data = example()
    data["infrastructure"].update(terminal_chargers=1)
    spec = load_study(data)
    out = tmp_path / "study"
    summary = write_summary(spec, run_study(spec, out, say=lambda _: None), out)
    assert len(summary) == 3 and summary["feasible"].dtype == bool
    html = (out / "report.html").read_text()
    for heading in ("Timetable read", "What the blocks need", "Depot load timeline",
                    "Pareto front"):
        assert heading in html
    assert "grade zero" not in html  # the altitude file covers every shape
    assert (out / "rows").is_dir()


@pytest.mark.parametrize("change, says", [
    ({"strategies": [{"name": "x", "depot_plan": "whenever"}]}, "depot_plan = 'whenever'"),
    ({"gtfs.date": "12/03/2024"}, "YYYY-MM-DD"),
    ({"lines": [{"name": "x", "buses": 1}]}, "not both"),
    ({"gtfs.feed": "/nonexistent/feed.zip"}, "does not exist"),
    ({"gtfs.reserve_soc_pct": 99}, "must lie below"),
])
def test_a_timetable_study_file_is_checked_before_any_work(change, says):
    bad = example()
    for key, value in change.items():
        where, _, name = key.rpartition(".")
        (bad[where] if where else bad)[name] = value
    with pytest.raises(ConfigError, match=says):
        load_study(bad)


def test_the_three_depot_plans_are_the_default_strategies():
    default = example()
    del default["strategies"]
    assert [s.depot_plan for s in load_study(default).strategies] == ["optimal", "on_arrival",
                                                                      "flat"]
