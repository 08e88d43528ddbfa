"""The out-of-family truth bench in CI: a small fixed subset of its days and buses
(``benchmarks.out_of_family.ci_jobs``: from each truth source a few single days, the last
2.5 h of each, and one multi-day bus of 6 one-hour days, each from its BMS log and its
SoC-only log), diagnosed
calibrated on the bench's baseline bus. On every day and bus the diagnosis may abstain, but
never names a wrong effect (and names none on a control day or for a load or force outside
the library); on the jobs of ``NAMED_RIGHT`` the bench's run named the hidden effect, and
must go on naming it. The bench's own machinery (caching, shards, scoring) is tested with
stand-ins, without a diagnosis."""

from __future__ import annotations

import importlib
import importlib.util
import sys
from dataclasses import replace
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parent.parent

bench = pytest.importorskip("benchmarks.out_of_family", reason="benchmarks/ not in this checkout")

NAMED_RIGHT = {
    # (source, log, case or bus) the CI subset's run named right (docs/truth_bench.md)
    ("truthsim", "soc", "road_grade_00"), ("truthsim", "bms", "road_grade_00"),
    ("fastsim", "soc", "fastsim_road_grade_00"), ("backward", "soc", "backward_road_grade_00"),
    ("fastsim", "bms", "fastsim_bus_cabin_heating_00-last1h"),
    ("fastsim", "soc", "fastsim_bus_cabin_heating_00-last1h"),
}


def _available(source: str) -> str:
    """Why a truth source cannot run here ('' when it can)."""
    if importlib.util.find_spec("benchmarks.truth") is None:
        return "benchmarks/truth is not in this checkout"
    if source == "fastsim" and importlib.util.find_spec("fastsim") is None:
        return "fastsim is not installed (pip install 'fastsim>=3')"
    return bench.truth_module(source)[1]


def _ci_jobs():
    out = []
    for source in bench.SOURCES:
        why = _available(source)
        if why:
            out.append(pytest.param(None, marks=pytest.mark.skip(reason=why),
                                    id=f"{source}-unavailable"))
            continue
        for job in bench.ci_jobs(Path("."), (source,)):
            out.append(pytest.param(job, id="-".join(job.key)))
    return out


@pytest.mark.slow
@pytest.mark.parametrize("job", _ci_jobs())
def test_the_ci_subset_gets_no_wrong_verdict(job, tmp_path_factory):
    folder = tmp_path_factory.getbasetemp() / "truth-days"
    folder.mkdir(exist_ok=True)
    row = bench.run_job(replace(job, folder=str(folder)), ladder=False)  # verdicts only
    expected = row["expected"] if row["expected"] != "outside_library" else None
    assert row["verdict"] in (None, expected), (row["verdict"], row["why"])
    assert not bench.scoring.wrong(row)
    key = (job.source, job.log, row["case"])
    if key in NAMED_RIGHT:
        assert row["verdict"] == expected, (row["status"], row["why"])
    for name, (low, high) in row["interval"].items():
        assert low <= row["estimate"][name] <= high
    if row["energy_kwh"] is not None:  # the named effect's energy over the day
        low, high = row["energy_interval_kwh"]
        assert low <= row["energy_kwh"] <= high
    if job.kind == "bus":  # one diagnosis of all the bus's days, each with its own date
        assert row["days"] == 6 and len(set(row["dates"])) == 6
        assert row["start_day"] is not None or row["condition_kind"] != "from_day"


@pytest.mark.slow
@pytest.mark.skipif(bool(_available("backward")), reason="the backward model cannot run here")
def test_the_power_domain_dates_a_weak_cell_group_from_the_logged_voltage(tmp_path):
    """The backward model's first weak-cell-group bus, its six days cut to their last hour,
    read second by second: its pack's resistance rises from the day the group fails, and the
    diagnosis names the library's ageing from that day, with an RCD interval that holds the
    truth's capacity loss (k_R from 1 to 2)."""
    bus = next(b for b in bench.truth_buses("backward", 1, 0) if b.condition == "capacity_step")
    job = bench.Job("backward", "bms", "bus", bench.CutBus(bus, 1.0), str(tmp_path),
                    domain="power")
    row = bench.run_job(job, ladder=False)
    assert (row["status"], row["verdict"]) == ("voltage", "static_rcd"), row["why"]
    assert row["since"] == row["start_date"], (row["since"], row["start_date"])
    low, high = row["interval"]["static_rcd.rcd_frac"]
    assert low <= row["truth"]["static_rcd.rcd_frac"] <= high


@pytest.mark.slow
@pytest.mark.parametrize("job", _ci_jobs())
def test_the_power_domain_names_no_wrong_effect_on_the_ci_subset(job, tmp_path_factory):
    """The CI subset's days and buses in the power domain (``diagnose(domain="power")``):
    BMS logs second by second, SoC-only logs by the SoC's count in each window. It may
    abstain, but names no wrong effect, and none on a control day or for a force outside the
    library; a bus's six days keep their dates."""
    folder = tmp_path_factory.getbasetemp() / "truth-days"
    folder.mkdir(exist_ok=True)
    row = bench.run_job(replace(job, folder=str(folder), domain="power"), ladder=False)
    assert row["domain"] == "power"
    expected = row["expected"] if row["expected"] != "outside_library" else None
    assert row["verdict"] in (None, expected), (row["verdict"], row["why"])
    assert not bench.scoring.wrong(row)
    if job.kind == "bus":
        assert row["days"] == 6 and len(set(row["dates"])) == 6


@pytest.mark.slow
def test_the_hidden_effects_own_power_is_named_on_an_oracle_day(tmp_path_factory):
    """``--oracle``: with the grade day's own extra power in the log, replayed as a load, the
    diagnosis names the grade (the library's form or the replayed power): the day is right."""
    if _available("truthsim"):
        pytest.skip(_available("truthsim"))
    case = next(c for c in bench.truth_cases("truthsim", smoke=True) if c.hidden == "road_grade")
    folder = tmp_path_factory.getbasetemp() / "truth-days"
    folder.mkdir(exist_ok=True)
    row = bench.diagnose_truth_day(("truthsim", case, str(folder), False, True), ladder=False)
    assert row["right"] and row["verdict"] in ("road_grade", bench.ORACLE), row["why"]


def test_what_no_parameter_takes_up_of_a_load_is_what_the_clue_ceiling_reads():
    """``clue_ceiling.left_over``: a load made of the parameters' signatures leaves nothing;
    any other leaves a part that no signature correlates with (weighted): the ceiling reads
    only what the calibration cannot take up."""
    import numpy as np

    from benchmarks.clue_ceiling import left_over

    rng = np.random.default_rng(3)
    signatures = rng.normal(size=(200, 3))
    weight = rng.uniform(0.5, 2.0, 200)
    made = signatures @ np.array([2.0, -1.0, 0.5])
    assert np.allclose(left_over(made, signatures, weight), 0.0, atol=1e-9)
    own = rng.normal(size=200)
    left = left_over(made + own, signatures, weight)
    assert np.allclose(signatures.T @ (weight * left), 0.0, atol=1e-9)
    assert np.allclose(left, left_over(own, signatures, weight))


@pytest.mark.slow
def test_a_chillers_own_power_is_read_in_a_charging_mode(tmp_path_factory):
    """The clue ceiling on the smoke run's chiller day (its last 4 h): the chiller draws only
    while the bus charges, so its own power, read by operating mode as the diagnosis reads
    missing power, lies in a charging mode and in no driving mode; the calibration leaves a
    part of it, not all and not none."""
    if _available("truthsim"):
        pytest.skip(_available("truthsim"))
    from benchmarks.clue_ceiling import ceiling_day

    case = next(c for c in bench.truth_cases("truthsim", smoke=True)
                if c.hidden == "battery_chiller")
    folder = tmp_path_factory.getbasetemp() / "truth-days"
    folder.mkdir(exist_ok=True)
    row = ceiling_day(("truthsim", case, str(folder), False))
    assert row["own_clue"] in ("CC charging", "CV charging"), row["by_mode_kw"]
    for mode in ("accelerating", "cruising", "braking/regen", "idle"):
        assert abs(row["by_mode_kw"][mode][0]) < 0.1, (mode, row["by_mode_kw"])
    assert 0.0 < row["kept_frac"] < 1.0


def test_a_part_of_the_bench_is_its_first_days():
    """``--per-effect N --controls M`` runs the whole bench's first N days of each effect and
    first M control days: the same days (same seeds), not a new draw."""
    if _available("truthsim"):
        pytest.skip(_available("truthsim"))
    whole = bench.truth_cases("truthsim", smoke=False)
    part = bench.truth_cases("truthsim", smoke=False, per_effect=2, controls=3)
    effects = {c.hidden for c in whole if c.hidden is not None}
    assert len(part) == 2 * len(effects) + 3
    assert all(c in whole for c in part)
    for hidden in effects | {None}:
        first = [c for c in whole if c.hidden == hidden][:3 if hidden is None else 2]
        assert [c for c in part if c.hidden == hidden] == first


def test_a_cut_day_and_its_whole_day_are_cached_apart(tmp_path, monkeypatch):
    """The smoke run's cut days share their case ids with the whole bench's days: in one
    cache folder each must still read back its own log, and neither is made twice."""
    import numpy as np
    import pandas as pd

    if _available("truthsim"):
        pytest.skip(_available("truthsim"))
    made = []

    class Source:  # a stand-in truth source: a standing bus, as long as the case
        @staticmethod
        def generate(case, current_voltage=False, oracle=False):
            made.append(case.hours)
            n = int(round(case.hours * 3600))
            log = pd.DataFrame({"time_s": np.arange(n, dtype=float), "speed_kmh": 0.0,
                                "soc_pct": 80.0})
            return log, {"start_clock_h": case.start_clock_h, "hours": case.hours,
                         "columns": list(log.columns)}

    day = bench.truth_cases("truthsim", smoke=False)[0]
    monkeypatch.setattr(bench, "truth_module", lambda source: (Source, ""))
    whole = replace(day, start_clock_h=8.0, hours=0.1)
    cut = replace(day, start_clock_h=8.05, hours=0.05)
    for case in (whole, cut, whole, cut):
        profiles, truth = bench.truth_day("truthsim", case, tmp_path)
        assert (truth["hours"], truth["start_clock_h"]) == (case.hours, case.start_clock_h)
        assert sum(p.duration_s for p in profiles) == pytest.approx(case.hours * 3600, abs=2)
    assert made == [0.1, 0.05]
    assert not list(tmp_path.glob("*.tmp"))


@pytest.mark.slow
def test_the_users_effects_for_the_outside_loads_draw_what_they_say():
    """The effects a user writes for the bench's loads outside the library
    (``benchmarks/user_effects.py``), run in the compiled model: the chiller draws its power
    exactly while on a charger, and the compressor runs at its power for the run time that
    open doors, braking and leaks owe it (what it still owes at the end excepted)."""
    import numpy as np

    from ebus_env import load_effects_file
    from ebus_env.config import load_bus
    from ebus_env.cycles import service_day

    user = load_effects_file(ROOT / "benchmarks" / "user_effects.py")
    bus = load_bus("12m")
    day = service_day("sort2", 1.0, 0.1, replace(bus.service, layover_every_min=20.0))
    standing = (day.channels["speed_ref_mps"] < 0.01) & (day.channels["charger_connected"] < 0.5)
    day = day.with_channels(door_open=standing.astype(float))
    on_charger = day.channels["charger_connected"] >= 0.5
    assert on_charger.any() and standing.any()

    chiller = bus.with_effect(user.pack_chiller).build(0.1).simulate(
        day, {"pack_chiller.power_w": 6000.0})
    assert np.array_equal(chiller.trace("pack_chiller_w"), np.where(on_charger, 6000.0, 0.0))

    params = {"air_compressor.power_w": 5000.0, "air_compressor.run_per_open_s": 1.0,
              "air_compressor.run_per_braked_mps": 2.0, "air_compressor.leak_duty": 0.02}
    run = bus.with_effect(user.air_compressor).build(0.1).simulate(day, params)
    power_w, speed = run.trace("air_compressor_w"), run.trace("speed_mps")
    assert set(np.unique(power_w)) == {0.0, 5000.0}
    braked_mps = np.maximum(speed[:-1] - speed[1:], 0.0).sum()
    owed_s = (1.0 * day.channels["door_open"].sum() * 0.1 + 2.0 * braked_mps
              + 0.02 * day.duration_s)
    ran_s = (power_w > 0).sum() * 0.1
    assert braked_mps > 10.0  # the day brakes: this term is tested
    assert ran_s == pytest.approx(owed_s - run.trace("air_debt_s")[-1], abs=2.0)


def test_the_figures_count_an_outside_load_only_with_its_mode_and_show_controls_alike():
    """An outside-library day counts when the report says "no library effect" and names one
    of the load's modes; control days that end "no library effect" all the same are counted
    apart, so that the outside figure can be read against them."""
    def row(expected, status, clue=None, modes=()):
        return {"expected": expected, "status": status, "clue": clue, "verdict": None,
                "right": expected is None, "estimate": {}, "truth": {}, "energy_kwh": None,
                "truth_kwh": None, "time_s": 30.0, "cpu_s": 30.0, "hours": 10.0,
                "added": "user_effects.py:Load" if expected else None, "fall": 0.1,
                "outside_modes": list(modes), "range_ends": {}}

    rows = [row("outside_library", "outside library", "idle", ["idle", "accelerating"]),
            row("outside_library", "outside library", "idle", ["CC charging"]),
            row("outside_library", "tie", "CC charging", ["CC charging"]),
            row(None, "outside library", "idle"), row(None, "outside library"),
            row(None, "noise")]
    f = bench.figures(rows)
    assert f["outside"] == (1 / 3, 3)
    assert f["control_outside"] == (2 / 3, 3)
    assert f["control_clue"] == (1 / 3, 3)
    assert f["false_alarms"] == (0.0, 3)


def test_the_footprint_table_counts_the_days_named_right_in_each_bin(capsys):
    """Library-effect days grouped by how far the hidden effect moves the SoC; control and
    outside-library days are left out."""
    def row(expected, footprint, right, source="truthsim"):
        return {"expected": expected, "footprint_pct": footprint, "right": right,
                "source": source}

    bench.footprint_table([row("road_grade", 3.0, True), row("passenger_mass", 0.3, False),
                           row("regen_soc_limit", 0.4, True), row(None, 0.0, True),
                           row("outside_library", 0.2, False),
                           row("cabin_hvac", 6.0, False, "fastsim")])
    out = capsys.readouterr().out
    assert "truthsim: 0 to 0.5 percentage points" in out and "1 of 2" in out
    assert "passenger_mass 0/1" in out and "regen_soc_limit 1/1" in out
    assert "truthsim: 2 to 5 percentage points" in out and "road_grade 1/1" in out
    assert "fastsim: >= 5 percentage points" in out and "cabin_hvac 0/1" in out
    assert "0.5 to 1 " not in out  # no days there


def test_a_stopped_bench_resumes_and_rows_files_report_together(tmp_path, monkeypatch, capsys):
    """``--resume`` runs only the days its ``--rows`` file lacks (here: none, so nothing is
    diagnosed), and ``--from-rows`` reports several rows files as one bench, the first file's
    row of a day kept."""
    import json

    if _available("truthsim"):
        pytest.skip(_available("truthsim"))

    def row(case, verdict, right):
        return {"source": "truthsim", "case": case, "hidden": "road_grade",
                "expected": "road_grade", "outside_modes": [], "truth": {},
                "verdict": verdict, "status": "named" if verdict else "outside library",
                "clue": None, "estimate": {}, "energy_kwh": None, "truth_kwh": None,
                "footprint_pct": 3.0, "time_s": 30.0, "cpu_s": 30.0, "hours": 10.0,
                "right": right, "added": "road_grade", "fall": 0.5, "range_ends": {}}

    first, second = tmp_path / "first.json", tmp_path / "second.json"
    first.write_text(json.dumps([row("road_grade_00", "road_grade", True)]))
    second.write_text(json.dumps([row("road_grade_00", None, False),
                                  row("road_grade_01", None, False)]))
    monkeypatch.setattr(bench, "diagnose_truth_day", lambda job: pytest.fail("ran a done day"))
    bench.out_of_family(tmp_path, smoke=False, sources=("truthsim",), per_effect=1, controls=0,
                        rows_path=first, effects=("road_grade",), resume=True, logs=("soc",),
                        kinds=("day",))
    out = capsys.readouterr().out
    assert "1 days and buses from" in out and "0 to run" in out
    assert "top-1 right over the library's effects" in out and "100 %" in out
    monkeypatch.setattr(sys, "argv", ["bench_diagnose.py", "--from-rows", str(first),
                                      "--from-rows", str(second)])
    from benchmarks import bench_diagnose

    bench_diagnose.main()
    f = bench.figures([row("road_grade_00", "road_grade", True),
                       row("road_grade_01", None, False)])
    assert f["top1"] == (0.5, 2)
    # rows without a log type and no voltage reading are SoC-only logs: their bar is 80 %
    assert "50 %  bar >= 80 %; 2 days" in capsys.readouterr().out


def test_with_the_truths_bus_and_forms_the_library_drives_its_day_alike(tmp_path_factory):
    """Two independent simulators, one bus: driven through a control day's log with the truth
    simulator's own bus, its brake blending and its one drivetrain efficiency, the library
    draws within 4 % of the truth's energy while accelerating and returns within 10 % of its
    braking energy to the DC bus; with the motor braking up to the configured limit it
    returns over 20 % more (``benchmarks/compare_braking.py``)."""
    if _available("truthsim"):
        pytest.skip(_available("truthsim"))
    compare = importlib.import_module("benchmarks.compare_braking")
    from benchmarks.truth import cases as truth_cases

    case = next(c for c in bench.truth_cases("truthsim", smoke=True) if c.hidden is None)
    folder = tmp_path_factory.getbasetemp() / "truth-days"
    folder.mkdir(exist_ok=True)
    _, base, _, _, trace = truth_cases.day_trace(case)
    profile = bench.truth_day("truthsim", case, folder)[0][0]
    truth_w = compare.truth_power_w(trace, "battery")
    truth_back_w = -compare.truth_power_w(trace, "drive_dc").clip(max=0.0)
    accelerating = truth_cases.modes(trace)[: len(truth_w)] == truth_cases.MODES.index(
        "accelerating")

    def ratios(decel_mps2, one_efficiency):
        lib = compare.library_power_w(profile, base, decel_mps2, one_efficiency)
        n = min(len(truth_w), len(lib["battery"]))
        acc = accelerating[:n]
        return (lib["battery"][:n][acc].sum() / truth_w[:n][acc].sum(),
                -lib["motor"][:n].clip(max=0.0).sum() / truth_back_w[:n].sum())

    accelerating_ratio, back_ratio = ratios(base["regen_max_decel_mps2"], True)
    assert abs(accelerating_ratio - 1.0) < 0.04
    assert abs(back_ratio - 1.0) < 0.10
    assert ratios(None, False)[1] > 1.2


def test_the_rules_frontier_runs_from_the_shipped_rules_to_the_loose_end():
    """``attribution_rules --frontier``: step 0 is the shipped rules, step 1 ``LOOSE``, each
    step in between lies between them; a day's label counts a control day's verdict apart
    from a hidden effect's, and a tie of the library's effect and its perfect form as right."""
    rules = importlib.import_module("benchmarks.attribution_rules")
    from ebus_env.diagnostics import attribution

    assert rules.loosened(0.0) == {k: getattr(attribution, k) for k in rules.LOOSE}
    assert rules.loosened(1.0) == pytest.approx(rules.LOOSE)
    half = rules.loosened(0.5)
    for name, loose in rules.LOOSE.items():
        shipped = getattr(attribution, name)
        assert min(shipped, loose) < half[name] < max(shipped, loose)
    assert rules.label(None, "cabin_hvac", "named", ["cabin_hvac"], False) == "control named"
    assert rules.label(None, None, "outside library", [], False) == "control quiet"
    assert rules.label("road_grade", "road_grade", "named", ["road_grade"], False) == "right"
    assert rules.label("road_grade", "cabin_hvac", "named", ["cabin_hvac"], False) == "wrong"
    assert rules.label("road_grade", None, "tie", ["road_grade", "cabin_hvac"],
                       False) == "abstained"
    assert rules.label("road_grade", None, "tie", ["road_grade", bench.ORACLE],
                       True) == "right"
    _, (right, total, wrong, named, controls) = rules.tally(
        [("truthsim", "road_grade"), ("truthsim", None), ("truthsim", "air_compressor")],
        ["right", "control named", "wrong"])
    assert (right, total, wrong, named, controls) == (1, 1, 1, 1, 1)


def test_the_residual_floors_buses_carry_the_days_pack_and_drivetrain_form():
    """``benchmarks/residual_floor.py`` calibrates the control days with the library's bus
    closer to the day's: with the pack's data sheet the model has the truth's cells in series,
    rated capacity and charge C-rate, and an open-circuit voltage of the same chemistry (another
    cell's table, within 3 % of the truth's from 20 to 95 % SoC); with one drivetrain
    efficiency its drivetrain is the constant-efficiency form, in place of the loss map."""
    if _available("truthsim"):
        pytest.skip(_available("truthsim"))
    floor = importlib.import_module("benchmarks.residual_floor")
    import numpy as np

    from benchmarks.truth import sim, vehicles
    from ebus_env.effects.battery import OCV_CELL

    for chemistry, pack in vehicles.PACKS.items():
        bus = floor.library_bus("both", chemistry)
        model = bus.build(0.1)
        value = {name: model.params[model.param_index(name)] for name in (
            "rint_battery.cells_series", "rint_battery.cell_capacity_ah",
            "rint_battery.max_charge_c_rate", "cccv_taper.cc_c_rate",
            "constant_efficiency.motor_efficiency")}
        assert value["rint_battery.cells_series"] == pack["cells_series"]
        assert value["rint_battery.cell_capacity_ah"] * model.params[model.param_index(
            "rint_battery.cells_parallel")] == pytest.approx(pack["capacity_ah"])
        assert value["rint_battery.max_charge_c_rate"] == pack["max_charge_c"]
        assert value["cccv_taper.cc_c_rate"] == pack["max_charge_c"]
        assert value["constant_efficiency.motor_efficiency"] == floor.MOTOR_EFFICIENCY
        assert bus.slots["drivetrain"] == "constant_efficiency"
        table = OCV_CELL.presets[bus.tables["rint_battery"]["ocv_cell_v"]]
        soc_pct = np.arange(20.0, 96.0, 5.0)
        library_v = np.interp(soc_pct, table.x, table.y)
        truth_v = [sim.ocv_cell_v(chemistry, s / 100.0) for s in soc_pct]
        assert np.allclose(library_v, truth_v, rtol=0.03)
    assert floor.library_bus("shipped", "NMC").tables["rint_battery"]["ocv_cell_v"] == \
        "lfp_a123"
    shipped = floor.library_bus("shipped", None).build(0.1)
    assert "efficiency_map.gearbox_efficiency" in shipped.param_names


def test_days_of_one_bus_are_diagnosed_together_with_their_effect_energy_summed(
        tmp_path, monkeypatch, capsys):
    """``--days-per-bus 3``: a case's day and two more days of its bus go to one diagnosis,
    and the truth's effect energy is theirs together; FASTSim's days, which draw their hidden
    effect each day, are skipped."""
    from types import SimpleNamespace

    import numpy as np
    import pandas as pd

    if _available("truthsim"):
        pytest.skip(_available("truthsim"))
    made = []

    class Source:  # a stand-in truth source: a standing bus, its effect 1.5 kWh a day
        @staticmethod
        def generate(case, current_voltage=False, oracle=False):
            made.append((case.case_id, case.bus_seed))
            log = pd.DataFrame({"time_s": np.arange(360, dtype=float), "speed_kmh": 0.0,
                                "soc_pct": np.linspace(80.0, 79.0, 360)})
            return log, {"start_clock_h": case.start_clock_h, "hours": case.hours,
                         "expected_verdict": "passenger_mass", "strength": {},
                         "columns": list(log.columns),
                         "summary": {"effect_kwh": 1.5, "soc_footprint_pct": len(made)}}

    seen = []

    def diagnose(bus, profiles, **options):
        seen.append(len(profiles))
        return SimpleNamespace(verdict=None, status="outside library", mode_clue=None,
                               to_json=lambda: {"modes": {}, "clues": []}, resistance=None,
                               ranking=[], named={}, why="", range_ends={},
                               domain=options.get("domain", "soc"))

    case = replace(bench.truth_cases("truthsim", smoke=False, per_effect=1, controls=0,
                                     effects=("passenger_mass",))[0], hours=0.1)
    monkeypatch.setattr(bench, "truth_module", lambda source: (Source, ""))
    monkeypatch.setattr(bench, "diagnose", diagnose)
    row = bench.diagnose_truth_day(("truthsim", case, str(tmp_path), False, False, False,
                                    False, 3), ladder=False)
    assert seen == [3] and row["days"] == 3
    assert [m[0] for m in made] == [case.case_id, f"{case.case_id}_day1", f"{case.case_id}_day2"]
    assert {m[1] for m in made[1:]} == {case.seed}
    assert row["truth_kwh"] == pytest.approx(4.5) and row["footprint_pct"] == 3
    assert row["hours"] == pytest.approx(3 * 359 / 3600, abs=0.01)  # three 6-min logs
    reported = []
    monkeypatch.setattr(bench, "report", lambda rows, *args: reported.append(rows))
    bench.out_of_family(tmp_path, smoke=False, sources=("fastsim",), per_effect=1, controls=0,
                        days=3)
    assert reported == [[]]
    assert "fastsim: its days draw their hidden effect each day" in capsys.readouterr().out


def test_the_whole_bench_is_every_source_log_type_day_and_bus_and_its_shards_cover_it():
    """The plain bench: single days (10 per effect, 30 controls per source) and multi-day
    buses (5 per condition and source, 4 control buses per source) of the three sources,
    each from its BMS log and its SoC-only log; ``--shard i/n`` splits them without a
    gap or an overlap."""
    sources = tuple(s for s in bench.SOURCES if not _available(s))
    if "truthsim" not in sources or "backward" not in sources:
        pytest.skip("the truth sources are not all here")
    listed = bench.jobs(Path("."), smoke=False, sources=sources, say=lambda _: None)
    keys = [j.key for j in listed]
    assert len(set(keys)) == len(keys)
    for source in sources:
        for log in bench.LOGS:
            days = [j for j in listed if (j.source, j.log, j.kind) == (source, log, "day")]
            hidden = pd.Series([j.item.hidden or "control" for j in days]).value_counts()
            assert hidden["control"] == 30 and (hidden.drop("control") == 10).all()
            buses = [j for j in listed if (j.source, j.log, j.kind) == (source, log, "bus")]
            kinds = pd.Series([j.item.condition or "control" for j in buses]).value_counts()
            assert (kinds.drop("control") == 5).all() and len(kinds) >= 5
            assert kinds["control"] == 4
    assert sum(1 for j in listed if j.kind == "bus" and j.item.condition is None
               and j.log == "soc") >= 10
    shards = [bench.shard_of(listed, (i, 7)) for i in range(7)]
    assert sorted(k for part in shards for k in (j.key for j in part)) == sorted(keys)
    assert max(map(len, shards)) - min(map(len, shards)) <= 1
    # a shard takes days and buses of every source alike (the list alternates them)
    assert {j.kind for j in shards[0]} == {"day", "bus"}


def test_a_day_is_generated_once_and_each_log_type_is_its_log_less_columns(tmp_path,
                                                                             monkeypatch):
    """Both log types and the oracle column come from one generation: the SoC-only log is
    the BMS log without the pack's current and voltage, and neither has the oracle column
    unless asked; the record's columns say what each has."""
    import numpy as np

    made = []

    class Source:
        @staticmethod
        def generate(case, current_voltage=False, oracle=False):
            assert current_voltage and oracle  # the whole log, once
            made.append(case.case_id)
            n = 600
            log = pd.DataFrame({"time_s": np.arange(n, dtype=float), "speed_kmh": 0.0,
                                "soc_pct": 80.0, "battery_current_a": 10.0,
                                "battery_voltage_v": 650.0, "logged_load_kw": 0.5})
            return log, {"start_clock_h": case.start_clock_h, "hours": case.hours,
                         "columns": list(log.columns)}

    case = replace(bench.truth_cases("truthsim", smoke=False)[0], hours=600 / 3600)
    monkeypatch.setattr(bench, "truth_module", lambda source: (Source, ""))
    soc, soc_truth = bench.truth_day("truthsim", case, tmp_path)
    bms, bms_truth = bench.truth_day("truthsim", case, tmp_path, current_voltage=True)
    oracle, _ = bench.truth_day("truthsim", case, tmp_path, oracle=True)
    assert made == [case.case_id]
    assert soc_truth["columns"] == ["time_s", "speed_kmh", "soc_pct"]
    assert bms_truth["columns"] == ["time_s", "speed_kmh", "soc_pct", "battery_current_a",
                                    "battery_voltage_v"]
    assert "battery_current_a" in bms[0].measured and "battery_current_a" not in soc[0].measured
    assert np.array_equal(bms[0].measured["soc_frac"], soc[0].measured["soc_frac"])
    assert "logged_load_w" in oracle[0].channels and "logged_load_w" not in soc[0].channels


def _bus_row(expected, verdict, since=None, start_day=3, kind="from_day", right=None):
    row = {"source": "truthsim", "log": "bms", "kind": "bus", "case": "bus_x",
           "expected": expected, "verdict": verdict, "status": "named" if verdict else "noise",
           "right": (verdict == expected) if right is None else right, "clue": None,
           "outside_modes": [], "top": verdict, "condition_kind": kind,
           "start_day": start_day, "days": 6, "time_s": 120.0,
           "dates": ["2025-11-03", "2025-11-10", "2025-11-20", "2025-12-01", "2025-12-09",
                     "2025-12-20"]}
    if since is not None:
        row["since"] = since
    return row


def test_a_buss_start_day_counts_within_one_of_its_days_and_is_not_given_without_since():
    """The diagnosis's ``since`` is scored by the bus's service day it falls nearest: the
    truth's start day or either neighbour is found; a bus diagnosis that gives no ``since``
    leaves the figure "not given"."""
    assert bench.scoring.start_day_found(_bus_row("regen_soc_limit", "regen_soc_limit",
                                                  "2025-11-30")) is True   # day 3
    assert bench.scoring.start_day_found(_bus_row("regen_soc_limit", "regen_soc_limit",
                                                  "2025-11-21")) is True   # day 2
    assert bench.scoring.start_day_found(_bus_row("regen_soc_limit", "regen_soc_limit",
                                                  "2025-11-04")) is False  # day 0
    assert bench.scoring.start_day_found(_bus_row("regen_soc_limit", None)) is None
    rows = [_bus_row("regen_soc_limit", "regen_soc_limit", "2025-12-09T00:00:00-08:00"),
            _bus_row("aux_schedule", "aux_schedule", "2025-11-03"),
            _bus_row(None, None, kind=None, start_day=None),
            _bus_row(None, "cabin_hvac", kind=None, start_day=None),
            _bus_row("outside_library", "regen_soc_limit", "2025-12-01")]
    f = bench.bus_figures(rows)
    assert f["top1_bus"] == (1.0, 2)
    assert f["start_day"] == (pytest.approx(2 / 3), 3)  # day 4 and day 3 found, day 0 not
    assert f["false_alarms"] == (0.5, 2)
    assert f["wrong"] == (0.4, 5)
    assert f["time_bus_s"] == (120.0, 5)
    undated = bench.bus_figures([_bus_row("regen_soc_limit", "regen_soc_limit")])
    assert undated["start_day"] == (bench.scoring.NOT_GIVEN, 1)


def test_the_headline_is_the_worst_source_the_rules_were_not_tuned_on(capsys):
    """Per log type and figure, the worst of the held-out sources (for a bar from above, the
    highest), the tuning source's shown beside it and never taken as the headline."""
    groups = {("bms", "truthsim", "day"): {"top1": (0.95, 70), "wrong": (0.0, 120)},
              ("bms", "fastsim", "day"): {"top1": (0.70, 50), "wrong": (0.01, 80)},
              ("bms", "backward", "day"): {"top1": (0.85, 70), "wrong": (0.03, 130)},
              ("bms", "backward", "bus"): {"start_day": (bench.scoring.NOT_GIVEN, 15)}}
    bench.scoring.headline(groups, "truthsim")
    out = capsys.readouterr().out
    top = next(x for x in out.splitlines() if "top-1 right over" in x)
    assert "70 % (fastsim)" in top and "truthsim (tuning): 95 %" in top
    assert "3 % (backward)" in next(x for x in out.splitlines()
                                    if "wrong library effect named, days" in x)
    assert "not given" in next(x for x in out.splitlines() if "start day" in x)


def test_the_top1_bar_falls_to_the_ceiling_less_5_points_where_the_logs_hold_less(capsys):
    """Beside a source's top-1, the share of its library days the source's own model separates
    (a BMS log: in its power or its voltage), the top-1 on the same days, and the bar then:
    the bar, or the ceiling less 5 points where that is lower. Days the ceiling did not read
    and control days are not counted."""
    def day(case, right, expected="cabin_hvac"):
        return {"source": "fastsim", "case": case, "expected": expected, "right": right}

    def reading(separable):
        return {"windows": 100, "max_other_snr": 1.0, "snr": 5.0 if separable else 1.0,
                "margin": 20.0, "fall": 0.5, "separable": separable}

    rows = [day("a", True), day("b", True), day("c", False), day("d", False),
            day("e", True), day("control", False, None)]
    ceiling = {("fastsim", c): {"source": "fastsim", "case": c, "bms": reading(power),
                                "volt": reading(volt), "soc": reading(soc)}
               for c, power, volt, soc in (("a", True, False, True), ("b", False, True, False),
                                           ("c", False, False, True), ("d", True, True, False),
                                           ("control", False, False, False))}
    bms = bench.scoring.ceiling_figures(rows, ceiling, "bms")
    assert bms["held"] == (0.75, 4) and bms["top1"] == (0.5, 4)  # day "e" not read
    assert bms["bar"] == pytest.approx(0.70)  # 0.75 less 5 points, under the bar of 90 %
    soc = bench.scoring.ceiling_figures(rows, ceiling, "soc")
    assert soc["held"] == (0.5, 4) and soc["bar"] == pytest.approx(0.45)
    full = {k: dict(v, soc=reading(True)) for k, v in ceiling.items()}
    assert bench.scoring.ceiling_figures(rows, full, "soc")["bar"] == 0.80  # the bar itself
    groups = {("soc", "truthsim", "day"): {"top1": (0.71, 70)},
              ("soc", "fastsim", "day"): {"top1": (0.5, 4), "ceiling": soc}}
    bench.scoring.headline(groups, "truthsim")
    top = next(x for x in capsys.readouterr().out.splitlines() if "top-1 right over" in x)
    assert "fastsim's logs hold 50 %, bar then >= 45 %" in top


def test_a_bus_s_bars_fall_to_what_its_days_together_hold(capsys):
    """On buses the ceiling's rows (by bus) set the top-1 bar of a bus's days together and
    the start-day bar of its faults: a fault counts as dated where the source's own model
    dates its start in the power or the voltage; the diagnosis's start day is scored on
    those buses; the headline names the worst source's ceiling beside both."""
    dates = ["2025-11-03", "2025-11-10", "2025-11-20", "2025-11-30", "2025-12-08", "2025-12-15"]

    def bus(case, right, start=None, since=None, expected="regen_soc_limit"):
        return {"source": "backward", "case": case, "expected": expected, "right": right,
                "kind": "bus", "condition_kind": "from_day" if start is not None else "weather",
                "start_day": start, "since": since, "dates": dates}

    def reading(separable, dated=None):
        out = {"windows": 600, "max_other_snr": 1.0, "snr": 9.0 if separable else 1.0,
               "margin": 20.0, "fall": 0.5, "separable": separable}
        return out if dated is None else {**out, "dated": dated}

    rows = [bus("heat", True, expected="cabin_hvac"),
            bus("regen0", True, 3, dates[3]), bus("regen1", False, 2, dates[5]),
            bus("brake", False, 4, dates[0], "outside_library")]
    ceiling = {("backward", "heat"): {"bms": reading(True), "volt": reading(False),
                                      "soc": reading(False)},
               ("backward", "regen0"): {"bms": reading(True, True), "volt": reading(True, False),
                                        "soc": reading(True, False)},
               ("backward", "regen1"): {"bms": reading(True, False), "volt": reading(True, True),
                                        "soc": reading(False, False)},
               ("backward", "brake"): {"bms": reading(False, False),
                                       "volt": reading(False, False),
                                       "soc": reading(False, False)}}
    bms = bench.scoring.ceiling_figures(rows, ceiling, "bms", "bus")
    assert bms["held"] == (1.0, 3) and bms["bar"] == 0.95  # every library bus: the bar stands
    assert bms["start"]["held"] == (pytest.approx(2 / 3), 3)  # the brake's start not dated
    assert bms["start"]["top1"] == (0.5, 2)  # regen1 dated by the voltage, found 3 days late
    assert bms["start"]["bar"] == pytest.approx(2 / 3 - 0.05)
    soc = bench.scoring.ceiling_figures(rows, ceiling, "soc", "bus")
    assert soc["held"] == (pytest.approx(1 / 3), 3) and soc["start"]["held"] == (0.0, 3)
    groups = {("bms", "truthsim", "bus"): {"top1_bus": (0.95, 20), "start_day": (1.0, 20)},
              ("bms", "backward", "bus"): {"top1_bus": (0.67, 3), "start_day": (0.5, 2),
                                           "ceiling": bms}}
    bench.scoring.headline(groups, "truthsim")
    out = capsys.readouterr().out.splitlines()
    assert "backward's logs hold 100 %, bar then >= 95 %" in next(
        x for x in out if "6 days together" in x)
    assert "backward's logs hold 67 %, bar then >= 62 %" in next(
        x for x in out if "start day within" in x)


def test_a_bus_is_diagnosed_from_all_its_days_at_once_with_their_dates(tmp_path,
                                                                       monkeypatch):
    """``diagnose_truth_bus``: one diagnosis of every day's profiles (each with its date),
    its ``since`` and ``since_interval`` carried into the row, the truth's start day and
    dates beside them."""
    from types import SimpleNamespace

    import numpy as np

    from benchmarks.truth import cases as truth_cases

    class Source:
        buses = staticmethod(truth_cases.buses)
        bus_days = staticmethod(truth_cases.bus_days)
        bus_truth = staticmethod(truth_cases.bus_truth)

        @staticmethod
        def generate(case, current_voltage=False, oracle=False):
            start = pd.Timestamp(f"{case.date} 08:00:00-08:00")
            stamps = start + pd.to_timedelta(np.arange(300), unit="s")
            log = pd.DataFrame({"timestamp": stamps.strftime("%Y-%m-%dT%H:%M:%S-08:00"),
                                "speed_kmh": 0.0, "soc_pct": 80.0})
            return log, {"start_clock_h": case.start_clock_h, "hours": case.hours,
                         "columns": list(log.columns), "case_id": case.case_id,
                         "date": case.date, "active": case.active, "hidden": case.hidden,
                         "expected_verdict": "regen_soc_limit" if case.active else None,
                         "ambient_mean_degc": 2.0, "strength": {}, "physical": {},
                         "base": {}, "mode_shares": None, "hours_": case.hours,
                         "summary": {"effect_kwh": 1.0 * case.active, "hidden_kwh": 0.0,
                                     "soc_footprint_pct": 0.5}}

    seen = []

    def diagnose(bus, profiles, **options):
        seen.append([p.date for p in profiles])
        return SimpleNamespace(verdict="regen_soc_limit", status="named", mode_clue=None,
                               to_json=lambda: {"modes": {}, "clues": [], "since": "2025-12-01",
                                                "since_interval": ["2025-11-20", "2025-12-09"]},
                               resistance=None, ranking=[{"effect": "regen_soc_limit"}],
                               named={"parameters": {}, "interval": {}}, why="",
                               range_ends={}, domain=options.get("domain", "soc"))

    monkeypatch.setattr(bench, "truth_module", lambda source: (Source, ""))
    monkeypatch.setattr(bench, "diagnose", diagnose)
    bus = next(b for b in truth_cases.buses(1, 0) if b.condition == "regen_soc_limit")
    days = truth_cases.bus_days(bus)
    monkeypatch.setattr(Source, "bus_days", staticmethod(  # 5-min days
        lambda b: [replace(d, hours=300 / 3600) for d in truth_cases.bus_days(b)]))
    row = bench.diagnose_truth_bus(bench.Job("truthsim", "bms", "bus", bus, str(tmp_path)))
    assert [str(d) for d in seen[0]] == [d.date for d in days]
    assert row["since"] == "2025-12-01" and row["since_interval"] == ["2025-11-20", "2025-12-09"]
    assert row["start_day"] == bus.start_day and row["dates"] == [d.date for d in days]
    assert row["right"] and row["kind"] == "bus" and row["days"] == 6
    assert row["truth_kwh"] == pytest.approx(6 - bus.start_day)
