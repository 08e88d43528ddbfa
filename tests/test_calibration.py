"""Calibration: iSOPT itself, synthetic twins (known truth, degraded like real logs), sparse
logs, windowed tuning, bad input and the command line."""

from __future__ import annotations

import json
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from ebus_env.calibration import CalibrationProblem, ISOPTSettings, calibrate, isopt
from ebus_env.calibration.calibrate import evaluate_fit
from ebus_env.config import load_bus
from ebus_env.cycles import service_day
from ebus_env.errors import ConfigError
from ebus_env.io.measured import load_log
from ebus_env.io.sparse import load_sparse_log
from ebus_env.synthetic import synthetic_log
from tests.conftest import DT

ROOT = Path(__file__).resolve().parent.parent
TRUTH = {"passenger_load.load_frac": 0.7, "cabin_hvac.setpoint_degc": 21.5,
         "static_rcd.rcd_frac": 0.12, "cccv_taper.cv_soc_pct": 90.0,
         "cccv_taper.decay_per_pct": 0.35, "grid_charger.power_kw": 300.0,
         "regen_cutoff.cutoff_speed_mps": 2.5}


# -- iSOPT on its own ------------------------------------------------------------------------
def sphere(u, threshold=np.inf):
    return np.sum((u - 0.3) ** 2, axis=1)


def test_isopt_converges_and_reports_its_budget():
    run = isopt(sphere, 7, ISOPTSettings(seed=3))
    assert run.cost < 1e-4
    assert np.allclose(run.x, 0.3, atol=0.01)
    assert run.evaluations == ISOPTSettings().budget + 5 * len(run.history.escapes)  # 5 re-drawn
    assert ISOPTSettings().budget == 1111
    assert len(run.history.best_cost) == 51
    assert np.all(np.diff(run.history.best_cost) <= 0)  # elitist: the best never gets worse


def test_isopt_is_reproducible_and_seeded():
    a, b = isopt(sphere, 5, ISOPTSettings(seed=7)), isopt(sphere, 5, ISOPTSettings(seed=7))
    c = isopt(sphere, 5, ISOPTSettings(seed=8))
    np.testing.assert_array_equal(a.x, b.x)
    assert a.history.best_cost == b.history.best_cost
    assert not np.array_equal(a.x, c.x)


def test_isopt_escapes_a_stalled_population():
    def plateau(u, threshold=np.inf):  # flat almost everywhere: the population stalls
        return np.where(np.all(u > 0.9, axis=1), 0.0, 1.0)

    run = isopt(plateau, 2, ISOPTSettings(seed=0, iterations=60, stall_iterations=5))
    assert run.history.escapes, "a stalled population must be re-seeded"


def test_isopt_keeps_the_best_so_far_on_ctrl_c():
    calls = {"n": 0}

    def interrupted(u, threshold=np.inf):
        calls["n"] += 1
        if calls["n"] == 30:
            raise KeyboardInterrupt
        return sphere(u)

    run = isopt(interrupted, 3, ISOPTSettings(seed=1))
    assert run.interrupted and np.isfinite(run.cost)
    assert run.cost == min(run.history.best_cost)


# -- twins -----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def bus12():
    return load_bus("12m")


@pytest.fixture(scope="module")
def model(bus12):
    m = bus12.build()
    m.compile(sample=True)
    return m


def twin_day(bus12, hours, charging=True, ambient=(-2.0, 12.0)):
    service = replace(bus12.service, layover_charger_kw=None, charge_at_layovers=charging)
    day = service_day("sort2", hours, DT, service)
    return day.with_channels(ambient_degc=np.linspace(*ambient, day.n_steps))


def write_log(tmp_path, frame, name="log.csv"):
    path = tmp_path / name
    frame.to_csv(path, index=False)
    return path


@pytest.mark.slow
def test_twin_day_recovers_identifiable_parameters(tmp_path, bus12, model):
    """13.5 h at 1 Hz, SoC quantised to 0.1 %: the fit reaches NRMSE < 0.02, every parameter
    reported as well determined is within 10 % of its range of the truth, and the charging
    parameters (which the day's twelve charging events pin down) are among them."""
    frame = synthetic_log(model, twin_day(bus12, 13.5), TRUTH, soc_start=0.95, period_s=1.0,
                          soc_step_pct=0.1)
    result = calibrate(model, load_log(write_log(tmp_path, frame)).profiles,
                       settings=ISOPTSettings(seed=1))
    assert result.fit["nrmse"] < 0.02
    assert result.fit["correlation"] > 0.99
    for name, d in result.determinacy.items():
        low, high = result.bounds[name]
        if d.status == "well determined":
            assert abs(result.values[name] - TRUTH[name]) <= 0.1 * (high - low), name
    for name in ("cccv_taper.cv_soc_pct", "cccv_taper.decay_per_pct", "grid_charger.power_kw",
                 "static_rcd.rcd_frac"):
        assert result.determinacy[name].status == "well determined", name


@pytest.mark.slow
def test_twin_with_coarse_noisy_sparse_sampling_and_a_gap(tmp_path, bus12, model):
    """0.5 Hz, SoC quantised to 1 % with noise, a 5-minute gap: still NRMSE < 0.02 over a
    drive with a wide SoC range, and the parameters the drive cannot show are flagged."""
    frame = synthetic_log(model, twin_day(bus12, 5.0, charging=False), TRUTH, soc_start=0.95,
                          period_s=2.0, soc_step_pct=1.0, soc_noise_pct=0.2,
                          gap_s=(3600.0, 3900.0))
    log = load_log(write_log(tmp_path, frame), gaps="split")
    assert len(log.profiles) == 2
    result = calibrate(model, log.profiles, settings=ISOPTSettings(seed=2))
    assert result.fit["nrmse"] < 0.02
    # no charging in this drive: the charging parameters cannot be determined
    for name in ("cccv_taper.cv_soc_pct", "cccv_taper.decay_per_pct", "grid_charger.power_kw"):
        assert result.determinacy[name].status == "not determined", name


def test_a_parameter_without_influence_is_flagged_not_a_value(tmp_path, bus12, model):
    """The log gives the charger's rating, so the charger power parameter has no effect: named
    free, it is reported not determined and a note says so; by default the share of the
    rating the charger delivers takes its place among the paper's parameters, and a charger
    stated on its grid side (93 % delivered) is fitted as such."""
    day = twin_day(bus12, 3.0).with_channels(charger_rating_w=250e3)
    share = "grid_charger.delivered_frac"
    frame = synthetic_log(model, day, {**TRUTH, share: 0.93}, soc_start=0.95)
    profiles = load_log(write_log(tmp_path, frame)).profiles
    free = ["grid_charger.power_kw", "static_rcd.rcd_frac"]
    known = {k: v for k, v in TRUTH.items() if k not in free}
    result = calibrate(model, profiles, free=free, fixed={**known, share: 0.93},
                       settings=ISOPTSettings(seed=0, iterations=15))
    assert result.determinacy["grid_charger.power_kw"].status == "not determined"
    assert result.determinacy["static_rcd.rcd_frac"].status == "well determined"
    assert result.values["static_rcd.rcd_frac"] == pytest.approx(0.12, abs=0.03)
    assert any("grid_charger.power_kw moves nothing" in n and share in n for n in result.notes)
    default = CalibrationProblem(model, profiles)
    assert share in default.free and "grid_charger.power_kw" not in default.free
    assert any(share in n for n in default.notes)
    free = [share, "static_rcd.rcd_frac"]
    result = calibrate(model, profiles, free=free, fixed=known,
                       settings=ISOPTSettings(seed=0, iterations=15))
    assert result.values[share] == pytest.approx(0.93, abs=0.02)
    assert result.values["static_rcd.rcd_frac"] == pytest.approx(0.12, abs=0.03)
    assert not any("moves nothing" in n for n in result.notes)
    # a log without the rating keeps the paper's charging power
    plain = synthetic_log(model, twin_day(bus12, 3.0), TRUTH, soc_start=0.95)
    assert "grid_charger.power_kw" in CalibrationProblem(
        model, load_log(write_log(tmp_path, plain, "plain.csv")).profiles).free


def test_upper_bound_strategy_changes_work_not_results(tmp_path, bus12, model):
    frame = synthetic_log(model, twin_day(bus12, 2.0), TRUTH, soc_start=0.95)
    profiles = load_log(write_log(tmp_path, frame)).profiles
    settings = ISOPTSettings(seed=4, iterations=8)
    with_ubs = CalibrationProblem(model, profiles, chunks=8)
    without = CalibrationProblem(model, profiles, chunks=1)
    a = isopt(with_ubs.cost, len(with_ubs.free), settings)
    b = isopt(without.cost, len(without.free), settings)
    np.testing.assert_allclose(a.x, b.x)
    assert a.cost == pytest.approx(b.cost, rel=1e-12)
    assert with_ubs.simulated_steps < 0.9 * without.simulated_steps


@pytest.mark.slow
def test_a_batch_runs_in_lanes_only_once_their_loop_is_compiled(tmp_path, bus12, monkeypatch):
    """On an empty kernel cache a calibration's batches run one by one (a lane loop would cost
    more to compile than it saves); once another process has compiled the lane loop into the
    cache, a new model uses it, and the costs are the same to the last bit."""
    import subprocess
    import sys

    monkeypatch.setenv("EBUS_CACHE_DIR", str(tmp_path / "cache"))
    model = bus12.build()
    frame = synthetic_log(model, twin_day(bus12, 0.5), TRUTH, soc_start=0.95)
    profiles = load_log(write_log(tmp_path, frame)).profiles
    free = ["static_rcd.rcd_frac", "grid_charger.power_kw"]
    u = np.random.default_rng(0).random((30, 2))
    problem = CalibrationProblem(model, profiles, free=free)
    one_by_one = problem.cost(u)
    assert not model._lane_kernels and not model.lanes_ready(problem.params(u))
    compile_lanes = (  # the same model, its lane loop for batches that differ in ``free``
        "import numpy as np; from ebus_env.config import load_bus; m = load_bus('12m').build(); "
        f"rows = np.repeat(m.params[None], 30, 0); j = [m.param_index(n) for n in {free!r}]; "
        "rows[:, j] += np.linspace(0.0, 0.01, 30)[:, None]; "
        "m.compile(sample=True, lanes=True, params=rows)")
    subprocess.run([sys.executable, "-c", compile_lanes], check=True, env=dict(os.environ))
    fresh = bus12.build()
    again = CalibrationProblem(fresh, profiles, free=free)
    assert fresh.lanes_ready(again.params(u))
    np.testing.assert_array_equal(again.cost(u), one_by_one)
    assert fresh._lane_kernels  # it ran in lanes


@pytest.mark.slow
def test_windowed_tuning_is_cheaper_and_fits(tmp_path, bus12, model):
    frame = synthetic_log(model, twin_day(bus12, 8.0), TRUTH, soc_start=0.95)
    profiles = load_log(write_log(tmp_path, frame)).profiles
    offline = calibrate(model, profiles, settings=ISOPTSettings(seed=5), polish_starts=0)
    windowed = calibrate(model, profiles, settings=ISOPTSettings(seed=5), windowed=True)
    assert windowed.simulated_steps < 0.6 * offline.simulated_steps
    assert windowed.fit["nrmse"] < 0.02
    assert windowed.windows and all("prediction_nrmse" in w for w in windowed.windows[1:])


# -- sparse logs -------------------------------------------------------------------------------
def test_sparse_log_is_rebuilt_from_distance_and_fitted_at_its_samples(tmp_path, bus12, model):
    day = twin_day(bus12, 4.0)
    dense = synthetic_log(model, day, TRUTH, soc_start=0.95, period_s=1.0)
    distance = np.concatenate([[0.0], np.cumsum(dense.speed_kmh.to_numpy()[1:] / 3.6)]) / 1000
    every = dense.iloc[::300].copy()  # a sample every 5 minutes
    every["distance_km"] = distance[::300]
    sparse = every[["time_s", "distance_km", "soc_pct", "charging", "ambient_degc"]]
    log = load_sparse_log(write_log(tmp_path, sparse), DT, max_speed_kmh=80.0)
    profile = log.profile
    rows = profile.sample_rows()
    assert len(rows) == len(sparse)
    travelled = np.cumsum(profile.channels["speed_ref_mps"]) * DT / 1000
    np.testing.assert_allclose(travelled[rows[1:] - 1], sparse.distance_km.to_numpy()[1:],
                               rtol=1e-6, atol=1e-3)  # every interval covers its distance
    assert any("scaled to their mean speed" in c for c in log.report.changes)
    result = calibrate(model, [profile], settings=ISOPTSettings(seed=0, iterations=20))
    assert result.fit["nrmse"] < 0.05
    assert result.fit["samples"] == len(sparse)


# -- bad input -------------------------------------------------------------------------------
def test_bad_inputs_say_what_to_do(tmp_path, bus12, model):
    day = twin_day(bus12, 1.0)
    frame = synthetic_log(model, day, TRUTH, soc_start=0.95)
    without_soc = frame.drop(columns="soc_pct")
    profiles = load_log(write_log(tmp_path, without_soc)).profiles
    with pytest.raises(ConfigError, match="has no measured SoC.*'soc_pct'"):
        CalibrationProblem(model, profiles)
    flat = frame.assign(soc_pct=80.0)
    with pytest.raises(ConfigError, match="never changes"):
        CalibrationProblem(model, load_log(write_log(tmp_path, flat)).profiles)
    good = load_log(write_log(tmp_path, frame)).profiles
    with pytest.raises(ConfigError, match="excludes its current value 0.*--fix"):
        CalibrationProblem(model, good, bounds={"static_rcd.rcd_frac": (0.1, 0.2)})
    with pytest.raises(ConfigError, match="never widen"):
        CalibrationProblem(model, good, bounds={"static_rcd.rcd_frac": (0.0, 0.5)})
    with pytest.raises(ConfigError, match="Unknown parameter 'static_rcd.rcd'"):
        CalibrationProblem(model, good, free=["static_rcd.rcd"])
    with pytest.raises(ConfigError, match="shorter than one window"):
        calibrate(model, good, windowed=True)


# -- command line ----------------------------------------------------------------------------
def test_cli_calibrate_writes_overlay_json_and_plots(tmp_path, bus12, model):
    from typer.testing import CliRunner

    from ebus_env.cli import app

    a = write_log(tmp_path, synthetic_log(model, twin_day(bus12, 2.0), TRUTH), "a.csv")
    b = write_log(tmp_path, synthetic_log(model, twin_day(bus12, 2.0, ambient=(5, 9)), TRUTH),
                  "b.csv")
    runner = CliRunner()
    result = runner.invoke(app, ["calibrate", str(a), "--validate", str(b), "--iterations", "10",
                                 "--params", "static_rcd.rcd_frac,cabin_hvac.setpoint_degc",
                                 "--fix", "auxiliaries.base_power_w=4000",
                                 "--out", str(tmp_path / "cal.yaml"),
                                 "--json", str(tmp_path / "cal.json"),
                                 "--plot", str(tmp_path / "fit.png"),
                                 "--history", str(tmp_path / "hist.csv")],
                           catch_exceptions=False)
    assert result.exit_code == 0, result.output
    data = json.loads((tmp_path / "cal.json").read_text())
    for key in ("params", "nrmse", "rmse_pct", "max_abs_error_pct", "correlation", "validation",
                "wall_time_s", "evaluations", "at_range_end"):
        assert key in data, key
    assert set(data["params"]) == {"static_rcd.rcd_frac", "cabin_hvac.setpoint_degc"}
    assert data["validation"]["nrmse"] < 0.05
    for name in ("fit.png", "fit_history.png", "fit_determinacy.png"):
        assert (tmp_path / name).stat().st_size > 5000, name
    # the overlay holds the known value the fit held, and its header the command that
    # simulates the calibrated bus with this very file
    text = (tmp_path / "cal.yaml").read_text()
    overlay = yaml.safe_load(text)
    assert overlay["params"]["auxiliaries"]["base_power_w"] == 4000.0
    assert set(overlay["params"]["static_rcd"]) == {"rcd_frac"}
    assert f"ebus simulate --bus 12m --overlay {tmp_path / 'cal.yaml'}" in text.splitlines()[1]
    # the overlay is a bus overlay that simulate accepts
    sim = runner.invoke(app, ["simulate", "--cycle", "sort2", "--hours", "0.2", "--overlay",
                              str(tmp_path / "cal.yaml"), "--json", str(tmp_path / "s.json")],
                        catch_exceptions=False)
    assert sim.exit_code == 0, sim.output
    bad = runner.invoke(app, ["calibrate", str(a), "--range", "static_rcd.rcd_frac=0.1:0.2"])
    assert bad.exit_code == 2 and "excludes its current value" in bad.output
    missing = runner.invoke(app, ["calibrate", str(tmp_path / "nope.csv")])
    assert missing.exit_code == 2 and "does not exist" in missing.output
    unknown = runner.invoke(app, ["calibrate", str(a), "--params", "static_rcd.rcd"])
    assert unknown.exit_code == 2 and "Unknown parameter 'static_rcd.rcd'" in unknown.output
    assert "iSOPT" not in unknown.output  # refused before the search starts
    no_soc = tmp_path / "no_soc.csv"
    pd.read_csv(b).drop(columns="soc_pct").to_csv(no_soc, index=False)
    result = runner.invoke(app, ["calibrate", str(a), "--validate", str(no_soc)])
    assert result.exit_code == 2 and "has no measured SoC: a validation log" in result.output
    assert "evaluations" not in result.output  # refused before the search, not after it


@pytest.mark.slow
def test_bmw_trip_calibration_improves_on_the_defaults():
    """Real data: the BMW i3 on trip B16 (not a reserved trip)."""
    model = load_bus("bmw_i3").build()
    log = load_log(ROOT / "data/measured/bmw_i3_tum/TripB16_1hz.csv", model.dt_s,
                   columns="bmw_i3_tum")
    before = model.simulate(log.profile).summary()["soc_nrmse"]
    result = calibrate(model, log.profiles, settings=ISOPTSettings(seed=0, iterations=20))
    assert result.fit["nrmse"] < 0.5 * before
    assert result.fit["correlation"] > 0.99


def test_a_fit_far_above_the_noise_floor_claims_nothing(tmp_path, bus12, model):
    """With the other parameters wrong, RCD alone cannot reach the log's noise: nothing may be
    reported as well determined, and the report says why."""
    frame = synthetic_log(model, twin_day(bus12, 3.0), TRUTH, soc_start=0.95)
    result = calibrate(model, load_log(write_log(tmp_path, frame)).profiles,
                       free=["static_rcd.rcd_frac"], settings=ISOPTSettings(seed=0, iterations=10))
    assert result.fit["nrmse"] > 5 * 0.002
    assert result.determinacy["static_rcd.rcd_frac"].status != "well determined"
    assert any("noise floor" in w for w in result.warnings)


def test_calibration_never_ends_worse_than_its_start():
    """The 12 m defaults already fit the project's nothing-hidden day: a search too short to
    beat them must return them (and say so), and a full one must end no worse."""
    model = load_bus("12m").build()
    profiles = load_log(ROOT / "data/measured/hidden/control.csv.gz", model.dt_s).profiles
    start = calibrate(model, profiles, settings=ISOPTSettings(seed=0, population=2,
                                                              iterations=0),
                      polish_starts=0)
    before = start.fit["nrmse"]
    assert "starting values kept" in start.method
    assert any("starting values" in n for n in start.notes)
    assert all(start.values[p] == pytest.approx(model.params[model.param_index(p)])
               for p in start.free)
    searched = calibrate(model, profiles, settings=ISOPTSettings(seed=0, iterations=5),
                         polish_starts=1)
    assert searched.fit["nrmse"] <= before * (1 + 1e-9)


def test_the_charge_counted_from_the_current_is_fitted_beside_the_soc(tmp_path, bus12, model):
    """On a BMS log of the model's own day, the charge counted from the logged current matches
    the model's at the true values (the sign, the capacity and the coulombic efficiency are
    right). A larger pack moves nearly the same charge (only its charging limits, which scale
    with it, change it): it shows in the SoC; a larger auxiliary load moves more charge and
    shows in both."""
    # logged at the model's step: the current held over each step is the model's own
    frame = synthetic_log(model, twin_day(bus12, 2.0), TRUTH, soc_start=0.95, period_s=DT,
                          soc_step_pct=0.1)
    profiles = load_log(write_log(tmp_path, frame)).profiles
    base = {**TRUTH, "rint_battery.cell_capacity_ah": model.params[
        model.param_index("rint_battery.cell_capacity_ah")],
        "auxiliaries.base_power_w": model.params[model.param_index("auxiliaries.base_power_w")]}
    free = list(base)
    soc_only = CalibrationProblem(model, profiles, free)
    both = CalibrationProblem(model, profiles, free, charge=True)
    variants = [base, {**base, "rint_battery.cell_capacity_ah":
                       1.3 * base["rint_battery.cell_capacity_ah"]},
                {**base, "auxiliaries.base_power_w": base["auxiliaries.base_power_w"] + 3000.0}]
    soc = soc_only.cost(soc_only.points(variants))
    charge = np.sqrt(np.maximum(2.0 * both.cost(both.points(variants)) ** 2 - soc**2, 0.0))
    assert charge[0] < 0.002  # the counted charge is the model's own
    assert soc[1] > 20 * soc[0] and charge[1] < 0.5 * soc[1]  # a pack 30 % larger
    assert charge[2] > 0.5 * soc[2] and charge[2] > 20 * soc[0]  # 3 kW more load
    r = both.residuals(both.points(variants))
    assert np.sqrt(np.sum(r**2, axis=1)) == pytest.approx(both.cost(both.points(variants)))
    # a fit's statistics report the counted charge's NRMSE and the cost on the same terms
    fits = [evaluate_fit(model, profiles, params, charge=True)[0]
            for params in both.params(both.points(variants))]
    assert [f["charge_nrmse"] for f in fits] == pytest.approx(charge, rel=1e-3, abs=1e-5)
    assert [f["cost"] for f in fits] == pytest.approx(both.cost(both.points(variants)), rel=1e-3)
    frame.drop(columns=["battery_current_a"]).to_csv(tmp_path / "soc.csv", index=False)
    with pytest.raises(ConfigError, match="battery current"):
        CalibrationProblem(model, load_log(tmp_path / "soc.csv").profiles, free, charge=True)
