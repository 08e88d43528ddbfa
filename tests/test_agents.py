"""Policies and the evaluator: each ECO rule moves its metric the expected way, the score
sheet is deterministic, PPO trains, saves and loads, the command writes its files."""

from __future__ import annotations

import dataclasses
import json
import tempfile
import warnings
from pathlib import Path

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
    cfg = PPOConfig.load(total_steps=1_024_000, num_envs=4, n_steps=32, batch_size=64,
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


@pytest.mark.parametrize("key, value", [
    ("total_steps", 0), ("num_envs", 0), ("torch_threads", 0), ("time_limit_min", -1.0),
    ("gamma", 1.5), ("gamma", "0.99"), ("gae_lambda", -0.1), ("learning_rate", "3e-4"),
    ("learning_rate", float("nan")), ("ent_coef", "lots"), ("ent_coef", -0.01),
    ("log_std_init", float("inf")), ("net_arch", [-4]), ("net_arch", [64, 0]),
    ("net_arch", 64), ("net_arch", [64.5]), ("seed", -3), ("seed", 2**32), ("seed", 1.5),
    ("normalize", "yes"), ("env_overrides", [1]), ("env_overrides", {1: 2}), ("env", 3), ("n_epochs", True),
    ("batch_size", 64.0), ("time_limit_min", "soon"), ("checkpoint_every", "1e5")])
def test_a_ppo_config_of_the_wrong_type_or_range_is_one_clear_error(key, value):
    with pytest.raises(ConfigError, match=f"PPO config {key}=") as error:
        PPOConfig.load(**{key: value})
    assert "\n" not in str(error.value) and "needs" in str(error.value)


def test_a_valid_ppo_config_is_normalized_to_the_types_training_uses():
    cfg = PPOConfig.load(net_arch=[32, np.int64(16)], seed=np.int64(7), learning_rate=1,
                         gae_lambda=0, env_overrides={"service_h": 0.3})
    assert cfg.net_arch == (32, 16) and type(cfg.seed) is int and cfg.seed == 7
    assert type(cfg.learning_rate) is float and cfg.gae_lambda == 0.0
    json.dumps(dataclasses.asdict(cfg))  # config.json can be written


@pytest.mark.parametrize("num_envs, n_steps, batch_size, message", [
    (1, 1, 1, "batch_size=1: needs at least 2"),
    (1, 1, 2, "larger than one rollout, num_envs x n_steps = 1 x 1 = 1"),
    (4, 64, 512, "at most 256")])
def test_a_rollout_stable_baselines3_refuses_is_a_config_error(num_envs, n_steps, batch_size,
                                                               message):
    with pytest.raises(ConfigError, match=message):
        PPOConfig.load(num_envs=num_envs, n_steps=n_steps, batch_size=batch_size)


@pytest.mark.parametrize("num_envs, n_steps, batch_size", [(1, 2, 2), (2, 1, 2), (4, 16, 64),
                                                           (3, 5, 4)])
def test_a_rollout_the_config_accepts_builds_a_ppo_model(num_envs, n_steps, batch_size):
    from agents.ppo import build

    cfg = PPOConfig.load(num_envs=num_envs, n_steps=n_steps, batch_size=batch_size,
                         net_arch=[8], env_overrides={"service_h": 0.3})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = build(cfg)  # stable-baselines3's own assertions pass
    lines = [str(w.message) for w in caught if issubclass(w.category, UserWarning)]
    if (num_envs * n_steps) % batch_size:  # one line of ours instead of SB3's three
        assert lines == [f"PPO config batch_size={batch_size} does not divide a rollout of "
                         f"num_envs x n_steps = {num_envs * n_steps} steps: each epoch ends "
                         f"with a mini-batch of {(num_envs * n_steps) % batch_size}. Fix: a "
                         f"batch_size that divides {num_envs * n_steps}."]
    else:
        assert lines == []
    assert model.n_steps == n_steps and model.batch_size == batch_size
    assert model.get_env().num_envs == num_envs
    model.get_env().close()


def test_total_steps_round_up_to_whole_rollouts():
    cfg = PPOConfig.load(total_steps=2000, num_envs=64, n_steps=256, batch_size=4096)
    assert cfg.rollout == 16384 and cfg.planned_steps == 16384
    assert cfg.rounding_note().startswith(
        "2000 steps round up to 16384: whole rollouts of num_envs x n_steps = 64 x 256")
    exact = PPOConfig.load(total_steps=3 * 128, num_envs=4, n_steps=32, batch_size=64)
    assert exact.planned_steps == 384 and exact.rounding_note() is None


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


TINY = {"num_envs": 4, "n_steps": 16, "batch_size": 32, "n_epochs": 1, "total_steps": 128,
        "checkpoint_every": 64, "env_overrides": {"service_h": 0.3}}


def tiny_yaml(path, **changes):
    """A PPO config file (JSON is YAML: strings stay quoted strings)."""
    path.write_text(json.dumps({**TINY, **changes}))
    return path


@pytest.mark.parametrize("changes, message", [
    ({"num_envs": 1, "n_steps": 1, "batch_size": 1}, "PPO config batch_size=1: needs at least 2"),
    ({"num_envs": 1, "n_steps": 1}, "batch_size=32 is larger than one rollout"),
    ({"net_arch": [-4]}, "PPO config net_arch=[-4]: needs a list of layer widths"),
    ({"ent_coef": "lots"}, "PPO config ent_coef='lots': needs a number >= 0"),
    ({"seed": -3}, "PPO config seed=-3: needs a whole number from 0"),
    ({"learning_rate": "3e-4"}, "PPO config learning_rate='3e-4': needs a number in (0, 1]"),
    ({"env": "nope"}, "No env config 'nope'"),
    ({"env_overrides": {"service_hh": 1}}, "Unknown env config key(s) ['service_hh']"),
    ({"env_overrides": {"bus": "nope"}}, "Unknown bus config 'nope'")])
def test_train_refuses_a_bad_config_in_one_line_before_making_its_folder(tmp_path, changes,
                                                                        message):
    config = tiny_yaml(tmp_path / "tiny.yaml", **changes)
    result = ebus("train", "--config", config, "--out", tmp_path / "run")
    text = " ".join(result.output.split())
    assert result.exit_code == 2 and message in text and "Traceback" not in text, text
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("name", ["config.json", "training.json", "progress.csv"])
def test_train_refuses_an_out_folder_where_it_would_overwrite_its_config(tmp_path, name):
    config = tiny_yaml(tmp_path / name)  # a YAML file by another name: still the input
    before = config.read_text()
    result = ebus("train", "--config", config, "--out", tmp_path)
    text = " ".join(result.output.split())
    assert result.exit_code == 2 and f"writes {name} there" in text, text
    assert config.read_text() == before and not (tmp_path / "model.zip").exists()


def test_evaluate_refuses_an_out_folder_where_it_would_overwrite_its_env_config(tmp_path):
    env = tmp_path / "scores.json"
    env.write_text('{"service_h": 0.3}')  # JSON is YAML: a valid env config
    result = ebus("evaluate", "--policy", "rule:baseline", "--episodes", 1, "--env", env,
                  "--out", tmp_path)
    assert result.exit_code == 2 and "writes scores.json there" in " ".join(result.output.split())
    assert env.read_text() == '{"service_h": 0.3}'


def test_train_says_the_steps_round_up_to_whole_rollouts_and_records_them(tmp_path):
    config = tiny_yaml(tmp_path / "tiny.yaml", total_steps=100)
    result = ebus("train", "--config", config, "--out", tmp_path / "run")
    text = " ".join(result.output.split())
    assert result.exit_code == 0, text
    assert ("100 steps round up to 128: whole rollouts of num_envs x n_steps = 4 x 16 = 64 "
            "steps") in text
    done = json.loads((tmp_path / "run" / "training.json").read_text())
    assert done["steps"] == 128 and done["steps_asked"] == 100 and done["rollout"] == 64
    assert "128 steps" in text
    exact = ebus("train", "--config", tiny_yaml(tmp_path / "exact.yaml"), "--out",
                 tmp_path / "exact")
    assert exact.exit_code == 0 and "round up" not in exact.output


def test_training_writes_each_file_whole_under_its_own_name(tmp_path):
    out = train(PPOConfig.load(**TINY), tmp_path / "run")
    assert {p.name for p in out.iterdir() if p.is_file() and not p.name.startswith(
        "events.out.tfevents")} == {"config.json", "training.json", "model.zip",
                                    "vecnormalize.pkl", "progress.csv"}  # no model.zip.zip
    assert {p.name for p in (out / "checkpoints").iterdir()} == {
        f"ppo_{kind}{n}_steps.{ext}" for n in (64, 128)
        for kind, ext in (("", "zip"), ("vecnormalize_", "pkl"))}
    assert isinstance(load_policy(f"ppo:{out / 'checkpoints' / 'ppo_64_steps.zip'}"), PPOPolicy)
    assert json.loads((out / "config.json").read_text())["net_arch"] == [64, 64]


def test_a_save_that_fails_leaves_the_previous_agent_whole(tmp_path):
    from agents.ppo import _save_agent

    class DiskFull:
        def save(self, path):
            Path(path).write_bytes(b"half a model")
            raise OSError("No space left on device")

    (tmp_path / "model.zip").write_bytes(b"the previous model")
    with pytest.raises(OSError, match="No space"):
        _save_agent(DiskFull(), None, tmp_path / "model.zip", tmp_path / "vecnormalize.pkl")
    assert [p.name for p in tmp_path.iterdir()] == ["model.zip"]
    assert (tmp_path / "model.zip").read_bytes() == b"the previous model"


def strict_json(text):
    def refuse(constant):
        raise ValueError(f"{constant} is not JSON")

    return json.loads(text, parse_constant=refuse)


def test_evaluate_writes_null_where_a_score_is_not_a_number(tmp_path):
    result = ebus("evaluate", "--policy", "rule:baseline", "--policy", "rule:eco_comfort",
                  "--episodes", 1, "--set", "service_h=0.3", "--set",
                  "charge_at_terminal=false", "--out", tmp_path)
    assert result.exit_code == 0, result.output
    data = strict_json((tmp_path / "scores.json").read_text())
    base = data["policies"]["baseline"]
    assert base["load_factor"] == {"mean": None, "ci95": None}  # no grid energy
    assert base["reward"]["ci95"] is None and base["reward"]["mean"] < 0  # one day: no CI
    csv = pd.read_csv(tmp_path / "scores_per_day.csv", keep_default_na=False)
    row = csv[csv["policy"] == "baseline"].iloc[0]
    assert row["load_factor"] == "" and float(row["reward"]) == base["reward"]["mean"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["day.png", "scores.json",
                                                          "scores_per_day.csv"]


def test_a_score_sheet_that_fails_to_write_leaves_the_previous_files_whole(tmp_path,
                                                                          monkeypatch):
    import agents.evaluate

    s = evaluate([rule("baseline")], "sort2_day", episodes=1, service_h=0.3)
    s.write(tmp_path)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}

    def broken_plot(sheet, path):
        Path(path).write_bytes(b"half a png")
        raise OSError("No space left on device")

    monkeypatch.setattr(agents.evaluate, "plot_days", broken_plot)
    with pytest.raises(OSError, match="No space"):
        s.write(tmp_path)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_finite_or_null_turns_every_non_finite_number_into_null():
    from agents.evaluate import finite_or_null

    value = {"a": float("nan"), "b": [np.float64(np.inf), 1.5, (np.float32(2.0), -np.inf)],
             "c": "text", "d": np.int64(3), "e": None}
    assert finite_or_null(value) == {"a": None, "b": [None, 1.5, [2.0, None]], "c": "text",
                                     "d": 3, "e": None}
    assert json.dumps(finite_or_null(value), allow_nan=False)


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

    from agents.commands import register

    pyproject = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())
    assert pyproject["project"]["entry-points"]["ebus_env.commands"] == {
        "agents": "agents.commands:register"}
    app = typer.Typer()
    register(app)
    assert {c.callback.__name__ for c in app.registered_commands} == {"train", "evaluate"}
