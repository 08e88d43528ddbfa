"""The native vector env (equal to single envs, both autoreset modes, stable-baselines3) and
EBusFleet-v0 (conformance, the shared chargers and the site's grid limit)."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import ebus_env  # noqa: F401  (registers the environments)
from ebus_env.envs.vector import EBusVectorEnv

SHORT = {"service_h": 0.3}  # 18 decisions: episodes end and restart within a test


def single_rollouts(n, seed, actions, autoreset, **config):
    """What n single envs seeded seed + i give for the same actions, restarted as a vector
    env restarts them."""
    envs = [gym.make("EBus-v0", **config) for _ in range(n)]
    first = np.array([e.reset(seed=seed + i)[0] for i, e in enumerate(envs)])
    ended = np.zeros(n, bool)
    steps = []
    for a in actions:
        rows = []
        for i, env in enumerate(envs):
            if autoreset == AutoresetMode.NEXT_STEP and ended[i]:
                rows.append((env.reset()[0], 0.0, False, False, None))
                ended[i] = False
                continue
            obs, reward, terminated, truncated, _ = env.step(a[i])
            final = None
            if terminated or truncated:
                ended[i] = True
                if autoreset == AutoresetMode.SAME_STEP:
                    final, obs = obs, env.reset()[0]
            rows.append((obs, reward, terminated, truncated, final))
        steps.append(rows)
    return first, steps


@pytest.mark.parametrize("mode, config", [
    (AutoresetMode.NEXT_STEP, SHORT), (AutoresetMode.SAME_STEP, SHORT),
    # stop-to-stop decisions: the sub-envs' decisions differ in length within one call
    (AutoresetMode.SAME_STEP, {"service_h": 0.12, "decide_at_stops": True, "laps_per_trip": 1})])
def test_vector_env_equals_single_envs_step_for_step(mode, config):
    n = 17  # more than THREADS_FROM: the batch is split over threads
    venv = gym.make_vec("EBus-v0", num_envs=n, autoreset_mode=mode, **config)
    assert isinstance(venv, EBusVectorEnv) and venv.metadata["autoreset_mode"] == mode
    venv.action_space.seed(4)
    actions = [venv.action_space.sample() for _ in range(40)]
    obs, _ = venv.reset(seed=11)
    first, steps = single_rollouts(n, 11, actions, mode, **config)
    np.testing.assert_array_equal(obs, first)
    restarts, lengths = 0, set()
    for a, rows in zip(actions, steps, strict=True):
        obs, reward, terminated, truncated, info = venv.step(a)
        lengths |= set(info["duration_s"].round(1).tolist())
        np.testing.assert_array_equal(obs, np.array([r[0] for r in rows]))
        np.testing.assert_array_equal(reward, np.array([r[1] for r in rows]))
        np.testing.assert_array_equal(terminated, np.array([r[2] for r in rows]))
        np.testing.assert_array_equal(truncated, np.array([r[3] for r in rows]))
        for i, r in enumerate(rows):
            if r[4] is not None:
                np.testing.assert_array_equal(info["final_obs"][i], r[4])
                restarts += 1
        if mode == AutoresetMode.NEXT_STEP and "_battery_kwh" in info:
            restarts += int((~info["_battery_kwh"]).sum())
    assert restarts >= n  # every sub-env ended and restarted at least once
    assert len(lengths) > 5 if config.get("decide_at_stops") else lengths == {60.0}


def test_vector_env_flags_observations_at_their_bound_as_the_single_env_does():
    config = {"layover_min": 2.5, "decision_s": 600}
    vec = EBusVectorEnv(num_envs=2, **config)
    vec.reset(seed=0)
    single = gym.make("EBus-v0", **config)
    single.reset(seed=0)
    slow, fast = -np.ones(5, np.float32), np.zeros(5, np.float32)
    with pytest.warns(UserWarning) as warned:
        for _ in range(200):  # sub-env 0 drives as slowly as it may, sub-env 1 normally
            obs, _, terminated, truncated, info = vec.step(np.stack([slow, fast]))
            one = single.step(slow)[4]
            flags = info["clipped_observations"]
            assert [n for n, b in flags.items() if b[0]] == one["clipped_observations"]
            if flags["schedule_delay_min"][0] or terminated.any() or truncated.any():
                break
    assert flags["schedule_delay_min"].tolist() == [True, False]
    said = [str(w.message) for w in warned]  # the vector env's, and the single env's
    assert sum("(schedule_delay_min) holds its bound in sub-env 0: the true value" in s
               for s in said) == 1
    assert info["schedule_delay_min"][0] > 60.0 and obs[0, 7] == pytest.approx(60.0)


def test_vector_env_checks_actions_and_seeds():
    venv = gym.make_vec("EBus-v0", num_envs=3, **SHORT)
    venv.reset(seed=0)
    bad = np.zeros((3, 5), np.float32)
    bad[2, 1] = 2.0
    with pytest.raises(ValueError, match=r"\[2, 1\] \(accel_cap_mps2\)"):
        venv.step(bad)
    with pytest.raises(ValueError, match="shape"):
        venv.step(np.zeros(5, np.float32))
    with pytest.raises(ValueError, match="3 seeds"):
        venv.reset(seed=[1, 2])


def test_stable_baselines3_ppo_runs_on_the_adapter_and_reloads(tmp_path, monkeypatch):
    monkeypatch.setenv("SB3_LOGDIR", str(tmp_path))  # not a stray SB3-<time> folder in /tmp
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor

    from ebus_env.envs.sb3 import SB3VecEnv

    venv = VecMonitor(SB3VecEnv(num_envs=4, **SHORT))
    venv.seed(0)
    model = PPO("MlpPolicy", venv, n_steps=32, batch_size=64, n_epochs=2, seed=0,
                device="cpu")
    model.learn(256)
    assert len(model.ep_info_buffer) >= 4  # episodes ended, were reset and logged
    model.save(tmp_path / "ppo")
    again = PPO.load(tmp_path / "ppo", device="cpu")
    obs = venv.reset()
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0],
                                  again.predict(obs, deterministic=True)[0])


def fleet(**overrides):
    return gym.make("EBusFleet-v0", config="fleet_sort2", **overrides)


def test_fleet_passes_the_checkers_and_is_reproducible():
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = fleet(lines=[{"config": "sort2_day", "buses": 3, "service_h": 0.3}]).unwrapped
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env)
        sb3_check_env(env, warn=True)
    space = gym.spaces.Box(-1, 1, env.action_space.shape, np.float32, seed=1)
    actions = [space.sample() for _ in range(10)]
    runs = []
    for _ in range(2):
        obs, _ = env.reset(seed=5)
        runs.append([obs] + [env.step(a)[0] for a in actions])
    np.testing.assert_array_equal(np.array(runs[0]), np.array(runs[1]))


def run_fleet(env, charge_frac=1.0, decisions=None):
    """Full-power driving, charging at charge_frac; per decision: site kW, the 10 Hz charger
    rows of every bus (connected, rating) and the buses' own grid power."""
    env.reset(seed=0)
    u = env.unwrapped
    a = np.ones(env.action_space.shape, np.float32)
    a[3::5] = 2.0 * (charge_frac - 0.1) / 0.9 - 1.0
    out = []
    while True:
        _, _, terminated, truncated, info = env.step(a)
        rows = [tuple(r.copy() for r in line.charger_rows()) for line in u.lines]
        out.append((info["site_grid_kw"], rows, sum(b["grid_kw"] for b in info["buses"])))
        if terminated or truncated or (decisions and len(out) >= decisions):
            return out, info


def test_fleet_site_limit_and_chargers_hold_at_every_step():
    limit_kw, chargers = 300.0, 2
    env = fleet(site_limit_kw=limit_kw, chargers=chargers)
    eff = env.unwrapped.efficiency
    steps, info = run_fleet(env, decisions=300)
    bound_kw, most_plugged = 0.0, 0
    for site_kw, rows, buses_kw in steps:
        assert site_kw == pytest.approx(buses_kw, rel=1e-12)  # the site is its buses
        assert site_kw <= limit_kw + 1e-6
        connected = np.concatenate([c for c, _ in rows])
        rating = np.concatenate([r for _, r in rows])
        most_plugged = max(most_plugged, int((connected > 0.5).sum(axis=0).max()))
        draw_kw = np.nansum(np.where(connected > 0.5, rating, 0.0) / eff[:, None], axis=0) / 1e3
        bound_kw = max(bound_kw, draw_kw.max())
    assert most_plugged == chargers  # the plugs were all taken at times, never more
    assert bound_kw == pytest.approx(limit_kw, rel=1e-9)  # the limit bit, exactly
    assert info["site_peak_kw"] == pytest.approx(max(s[0] for s in steps))
    assert len(info["site_load_kw"]) == len(steps)


def test_fleet_lower_site_limit_lowers_the_peak_and_the_charge_in_the_same_layovers():
    out = {}
    for limit_kw in (1000.0, 250.0):
        steps, info = run_fleet(fleet(site_limit_kw=limit_kw), decisions=240)
        kw = np.array([s[0] for s in steps])
        out[limit_kw] = (kw.max(), kw.sum() / 60.0)
    assert out[250.0][0] <= 250.0 + 1e-6 < out[1000.0][0]
    assert out[250.0][1] < 0.95 * out[1000.0][1]  # less energy through the connection


def test_fleet_actions_are_checked_per_bus():
    env = fleet(lines=[{"config": "sort2_day", "buses": 2}])
    env.reset(seed=0)
    bad = np.zeros(env.action_space.shape, np.float32)
    bad[8] = np.nan
    with pytest.raises(ValueError, match=r"bus1\.charge_power_frac"):
        env.step(bad)


def test_fleet_refuses_stop_to_stop_decisions():
    """The fleet's central agent decides for every bus at once: decisions at each bus's own
    stops would desynchronise the site's clock, so a clear error says so."""
    from ebus_env.errors import ConfigError

    with pytest.raises(ConfigError, match="decide_at_stops"):
        gym.make("EBusFleet-v0", lines=[{"config": "sort2_day", "buses": 2,
                                         "decide_at_stops": True}])


def test_fleet_refuses_to_step_before_reset_and_after_the_episode_ended():
    """As EBus-v0: a step before reset() or after the day ended is an EnvError, not a silent
    simulation past the service day; reset() starts a new day."""
    from ebus_env.errors import EnvError

    env = fleet(lines=[{"config": "sort2_day", "buses": 3, "service_h": 0.3}], chargers=1)
    a = np.zeros(env.action_space.shape, np.float32)
    with pytest.raises(EnvError, match=r"Call reset\(\) before step\(\)"):
        env.unwrapped.step(a)
    env.reset(seed=0)
    for _ in range(100):
        _, _, terminated, truncated, _ = env.step(a)
        if terminated or truncated:
            break
    assert terminated and not truncated
    u = env.unwrapped
    decisions = [line.decisions().copy() for line in u.lines]
    for _ in range(3):  # every further step is refused and simulates nothing
        with pytest.raises(EnvError, match=r"after the episode ended.*call reset\(\)"):
            env.step(a)
    for line, before in zip(u.lines, decisions, strict=True):
        np.testing.assert_array_equal(line.decisions(), before)
    first, _ = env.reset(seed=0)
    obs, _, terminated, _, _ = env.step(a)  # a new day runs again
    assert not terminated and not np.array_equal(obs, first)


@pytest.mark.parametrize("mode", ["rgb_array", "human"])
def test_fleet_refuses_a_render_mode_by_name(mode):
    """The fleet declares no render modes (metadata render_modes is empty): a render_mode
    is refused as such, not as an unknown fleet config key."""
    from ebus_env.errors import ConfigError

    assert fleet().metadata["render_modes"] == []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # gymnasium's own warning, before the env's error
        with pytest.raises(ConfigError) as info:
            fleet(render_mode=mode)
    said = str(info.value)
    assert f"render_mode '{mode}'" in said and "no render modes" in said
    assert "Unknown fleet config key" not in said
    env = fleet(render_mode=None)
    assert env.render_mode is None
    with pytest.warns(UserWarning, match="does not render"):
        assert env.unwrapped.render() is None


@pytest.mark.parametrize("num_envs", [0, -1, 2.5, 2.0, "4", True, None])
def test_vector_env_refuses_a_bad_num_envs_by_name(num_envs):
    from ebus_env.envs.sb3 import SB3VecEnv
    from ebus_env.errors import ConfigError

    with pytest.raises(ConfigError, match=r"num_envs = .*whole number >= 1"):
        gym.make_vec("EBus-v0", num_envs=num_envs, **SHORT)
    with pytest.raises(ConfigError, match=r"num_envs = .*whole number >= 1"):
        SB3VecEnv(num_envs=num_envs, **SHORT)


def test_vector_env_takes_a_numpy_integer_and_refuses_out_of_order_use():
    from ebus_env.errors import ConfigError, EnvError

    venv = EBusVectorEnv(num_envs=np.int64(2), **SHORT)
    assert venv.num_envs == 2 and type(venv.num_envs) is int
    with pytest.raises(EnvError, match=r"Call reset\(\) before step\(\)"):
        venv.step(np.zeros((2, 5), np.float32))
    obs, _ = venv.reset(seed=0)
    assert obs.shape == (2, 16)
    with pytest.raises(ConfigError, match="max_episode_steps = 0"):
        EBusVectorEnv(num_envs=2, max_episode_steps=0, **SHORT)
    with pytest.raises(ConfigError, match="autoreset_mode = 'Disabled'.*SAME_STEP"):
        EBusVectorEnv(num_envs=2, autoreset_mode="Disabled", **SHORT)
    with pytest.raises(ConfigError, match="autoreset_mode = 'sometimes'"):
        EBusVectorEnv(num_envs=2, autoreset_mode="sometimes", **SHORT)


def test_the_site_step_counts_plug_rows_and_shares_no_plug_it_lacks():
    """The one site step (fleet env and study): bus-rows on a plug never exceed the plugs,
    every layover row is either held or waited, and a site without a plug holds none."""
    from ebus_env.envs.batch import BusBatch
    from ebus_env.envs.charging_site import ChargingSite
    from ebus_env.envs.common import EnvConfig

    cfg = EnvConfig.load("sort2_day", service_h=2.0)
    counts = {}
    for chargers in (0, 1, 6):
        line = BusBatch(cfg, 6, offsets_s=np.arange(6) * 600.0)
        site = ChargingSite([line], chargers, 600.0)
        site.reset(np.random.default_rng(0))
        values = np.tile([80.0, 1.5, 21.0, 1.0, 1.0], (6, 1))
        held_max = 0
        for _ in range(120):
            site.step(values)
            connected, _ = line.charger_rows()
            held_max = max(held_max, int((connected > 0.5).sum(axis=0).max()))
            assert site.plugged.sum() <= chargers
        assert held_max <= chargers
        counts[chargers] = (site.held_rows, site.waited_rows)
    assert counts[0][0] == 0.0 and counts[0][1] > 0.0  # layovers asked, nobody plugged
    assert counts[1][0] > 0.0 and counts[1][1] > 0.0  # one plug: some waited
    assert counts[6][1] == 0.0  # a plug per bus: nobody waits
    # every layover row asked for a plug, held or not: one plug holds fewer, waits the rest
    assert counts[1][0] < counts[6][0]
