"""Policies and the evaluator: each ECO rule moves its metric the expected way, the score
sheet is deterministic, PPO trains, saves and loads, the command writes its files."""

from __future__ import annotations

import json
import tempfile

import numpy as np
import pandas as pd
import pytest

from agents.evaluate import evaluate
from agents.ppo import PPOConfig, PPOPolicy, load_policy, train
from agents.rules import RULES, eco_setpoint_degc, rule
from ebus_env.envs.batch import OBSERVATIONS
from ebus_env.errors import ConfigError

DAY = {"service_h": 3.0}  # three trips with layovers: short, long enough for every feature


def sheet(names, episodes=3, **overrides):
    return evaluate([rule(n) for n in names], "sort2_day", episodes=episodes,
                    **{**DAY, **overrides}).by_name()


def test_eco_driving_lowers_traction_energy_per_km():
    s = sheet(["baseline", "eco_driving"])
    base, eco = s["baseline"], s["eco_driving"]
    assert eco.mean("traction_kwh_per_km") < 0.92 * base.mean("traction_kwh_per_km")
    assert eco.mean("kwh_per_km") < base.mean("kwh_per_km")
    assert eco.mean("distance_km") < base.mean("distance_km")  # slower in the same hours


@pytest.mark.parametrize("ambient_degc", [-5.0, 32.0])
def test_eco_comfort_lowers_hvac_energy_in_winter_and_summer(ambient_degc):
    s = sheet(["baseline", "eco_comfort"], ambient_mean_degc=ambient_degc)
    assert s["eco_comfort"].mean("hvac_kwh") < 0.95 * s["baseline"].mean("hvac_kwh")


def test_eco_charging_lowers_the_peak_grid_power_at_about_equal_energy():
    s = sheet(["baseline", "eco_charging"])
    base, eco = s["baseline"], s["eco_charging"]
    assert eco.mean("peak_grid_kw") < 0.8 * base.mean("peak_grid_kw")
    assert eco.mean("kwh_per_km") == pytest.approx(base.mean("kwh_per_km"), rel=0.03)


def test_eco_setpoint_follows_the_rule_of_physics_md():
    ambient = np.array([-10.0, 10.0, 18.0, 25.0, 40.0])
    np.testing.assert_allclose(eco_setpoint_degc(ambient, np.array([1.0, 0.0, 0, 0, 0])),
                               [19.0, 20.0, 20.0, 22.99, 27.0])


def test_evaluator_is_deterministic_and_writes_the_sheet(tmp_path):
    policies = [rule(n) for n in RULES]
    a = evaluate(policies, "sort2_day", episodes=2, service_h=1.0)
    b = evaluate(policies, "sort2_day", episodes=2, service_h=1.0)
    for x, y in zip(a.policies, b.policies, strict=True):
        np.testing.assert_array_equal(x.days, y.days)
    files = a.write(tmp_path)
    data = json.loads(files[0].read_text())
    assert set(data["policies"]) == set(RULES) and "eco_all" in data["savings_vs_baseline"]
    assert all(f.stat().st_size > 0 for f in files)


def test_a_tiny_ppo_run_learns_saves_loads_and_is_evaluated(tmp_path):
    cfg = PPOConfig.load(total_steps=256, num_envs=4, n_steps=32, batch_size=64, n_epochs=2,
                         env_overrides={"service_h": 0.3}, checkpoint_every=64)
    out = train(cfg, tmp_path / "run")
    assert (out / "model.zip").exists() and (out / "vecnormalize.pkl").exists()
    assert list((out / "checkpoints").glob("ppo_*_steps.zip"))
    policy = load_policy(f"ppo:{out}")
    assert isinstance(policy, PPOPolicy)
    obs = np.zeros((3, len(OBSERVATIONS)), np.float32)
    action, _ = policy.predict(obs)
    assert action.shape == (3, 5) and np.all(np.abs(action) <= 1.0 + 1e-6)
    scores = evaluate([policy], "sort2_day", episodes=2, service_h=0.3).policies[0]
    assert np.isfinite(scores.mean("reward")) and scores.mean("distance_km") > 0


class Ticks:
    """A clock that advances one second per reading: training time counted in steps."""

    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        self.now += 1.0
        return self.now


def test_training_stops_at_its_time_limit_and_records_what_it_did(tmp_path, monkeypatch):
    import torch

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # where SB3 would put a stray log
    cfg = PPOConfig.load(total_steps=1_000_000, num_envs=4, n_steps=32, batch_size=64,
                         n_epochs=1, env_overrides={"service_h": 0.3}, time_limit_min=0.75)
    out = train(cfg, tmp_path / "run", clock=Ticks())
    done = json.loads((out / "training.json").read_text())
    # the deadline lies 45 ticks after training starts: the 45th vector step (4 envs) ends it
    assert done["steps"] == 45 * 4 and done["stopped_by_time_limit"]
    assert done["torch_threads"] == 1 and torch.get_num_threads() == 1
    assert (out / "model.zip").exists()
    curve = pd.read_csv(out / "progress.csv")  # one update: the first 32 vector steps
    assert curve["time/total_timesteps"].tolist() == [32 * 4]
    assert not list(tmp_path.glob("SB3-*"))


@pytest.mark.parametrize("key, value", [("total_steps", 0), ("num_envs", 0),
                                        ("torch_threads", 0), ("time_limit_min", -1.0),
                                        ("gamma", 1.5)])
def test_a_ppo_config_out_of_range_is_one_clear_error(key, value):
    with pytest.raises(ConfigError, match=f"{key}="):
        PPOConfig.load(**{key: value})


def test_the_shipped_agent_still_beats_the_best_rule_on_held_out_days():
    """ppo:default against every rule on 4 held-out days of its env (a full day each): the
    paired reward difference to the best rule is positive beyond its 95 % CI. Fails when a
    change to the env or the reward leaves the shipped agent stale (retrain it)."""
    sheet = evaluate([rule(n) for n in RULES] + [load_policy("ppo:default")], "sort2_day",
                     episodes=4)
    (name, versus), = sheet.versus_best_rule().items()
    assert name == "ppo:default" and versus["versus"] in RULES
    gain, ci = versus["reward"]
    assert gain - ci > 0.0
    assert versus["peak_grid_kw"][0] < 0.0 and versus["depleted"][0] == 0.0


def test_paired_difference_cancels_what_the_days_share():
    from agents.evaluate import KEYS, PolicyScores, paired_difference

    day = np.linspace(-50.0, 50.0, 6)[:, None] * np.ones((1, len(KEYS)))  # large day effect
    a = PolicyScores("a", day + 1.0 + 0.1 * np.array([1, -1, 1, -1, 1, -1])[:, None])
    b = PolicyScores("b", day)
    mean, ci = paired_difference(a, b, "reward")
    assert mean == pytest.approx(1.0) and 0.0 < ci < 0.2
    assert a.ci95("reward") > 10.0  # unpaired, the day effect would swamp the difference


def test_evaluate_command_prints_and_writes(tmp_path):
    from typer.testing import CliRunner

    from ebus_env.cli import app

    result = CliRunner().invoke(app, ["evaluate", "--policy", "rule:baseline", "--policy",
                                      "rule:eco_driving", "--episodes", "2", "--set",
                                      "service_h=0.5", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "kwh_per_km" in result.output and "eco_driving" in result.output
    assert (tmp_path / "scores.json").exists()
    bad = CliRunner().invoke(app, ["evaluate", "--policy", "rule:nope", "--out", str(tmp_path)])
    assert bad.exit_code == 2 and "No rule 'nope'" in bad.output and "eco_all" in bad.output


def ebus(*args):
    from typer.testing import CliRunner

    from ebus_env.cli import app

    return CliRunner().invoke(app, [str(a) for a in args])


def test_agent_commands_refuse_bad_input_in_one_line_before_the_run(tmp_path):
    bad_yaml = tmp_path / "ppo.yaml"
    bad_yaml.write_text("num_envs: [4\nseed: 0\n")
    some_file = tmp_path / "scores.json"
    some_file.write_text("{}")
    cases = [(["train", "--steps", 0, "--out", tmp_path / "t"], "total_steps=0"),
             (["train", "--config", bad_yaml, "--out", tmp_path / "t"], "not valid YAML"),
             (["evaluate", "--policy", "rule:baseline", "--episodes", 0, "--out", tmp_path],
              "--episodes 0"),
             (["evaluate", "--policy", "rule:baseline", "--out", some_file], "is a file")]
    for args, message in cases:
        result = ebus(*args)
        assert result.exit_code == 2, result.output
        text = " ".join(result.output.split())  # rich wraps long lines
        assert message in text and "Traceback" not in text
    assert not (tmp_path / "t").exists() and some_file.read_text() == "{}"


def test_evaluate_writes_a_folder_of_its_own_by_default(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = ebus("evaluate", "--policy", "rule:baseline", "--episodes", 1, "--set",
                  "service_h=0.3")
    assert result.exit_code == 0, result.output
    assert (tmp_path / "runs" / "evaluate" / "scores.json").exists()
    assert not (tmp_path / "report").exists()  # the demo's report folder stays the demo's


def test_ppo_without_the_rl_extra_names_the_extra(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "stable_baselines3", None)  # as if not installed
    result = ebus("evaluate", "--policy", "ppo:default", "--episodes", 1)
    assert result.exit_code == 2 and "pip install 'ebus-env[rl]'" in " ".join(result.output.split())


def fleet_peak(rule_name):
    import gymnasium as gym

    import ebus_env  # noqa: F401
    from agents.rules import FleetChargingRule

    env = gym.make("EBusFleet-v0", config="fleet_sort2",
                   lines=[{"config": "sort2_day", "buses": 4, "service_h": 3.0}])
    policy = FleetChargingRule.for_env(env, rule_name)
    obs, _ = env.reset(seed=0)
    grid = 0.0
    while True:
        obs, _, terminated, truncated, info = env.step(policy.predict(obs)[0])
        grid += info["grid_kwh"]
        if terminated or truncated:
            return info["site_peak_kw"], grid, policy, obs


def test_fleet_charging_rules_order_the_site_peak_and_share_by_need():
    greedy, balanced, shaving = (fleet_peak(n) for n in ("greedy", "balanced", "peak_shaving"))
    assert shaving[0] < 0.6 * greedy[0]  # peak shaving: a much lower site peak
    assert balanced[0] <= greedy[0]
    assert shaving[1] < greedy[1]  # ... bought with less charge in the same layovers
    policy, obs = balanced[2], balanced[3].copy()
    obs[0], obs[len(OBSERVATIONS)] = 0.5, 0.9  # bus 0 emptier than bus 1
    action = policy.predict(obs)[0].reshape(-1, 5)
    assert action[0, 3] > action[1, 3]


def test_the_agent_commands_plug_into_ebus_through_an_entry_point():
    import tomllib
    from pathlib import Path

    import typer

    from agents.cli import register

    pyproject = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())
    assert pyproject["project"]["entry-points"]["ebus_env.commands"] == {
        "agents": "agents.cli:register"}
    app = typer.Typer()
    register(app)
    assert {c.callback.__name__ for c in app.registered_commands} == {"train", "evaluate"}
