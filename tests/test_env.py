"""EBus-v0: Gymnasium conformance, reproducibility, clear errors, and the physics of its ECO
actions (speed cap, cabin setpoint, pulsed charging)."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest

import ebus_env  # noqa: F401  (registers the environments)
from ebus_env.envs import reference_vehicle as reference
from ebus_env.envs.common import ACTION_NAMES, ACTIONS, CONFIG_DIR, checked_actions, physical
from ebus_env.envs.course import course_from_cycle
from ebus_env.errors import ConfigError, LogError
from ebus_env.profile import Profile


def action(**values) -> np.ndarray:
    """An action from physical values (others at +1: no cap, 28 degC, full power, no pulses)."""
    a = np.ones(len(ACTIONS), np.float32)
    for i, r in enumerate(ACTIONS):
        if r.name in values:
            a[i] = 2.0 * (values[r.name] - r.low) / (r.high - r.low) - 1.0
    return a


def rollout(env, actions, seed=0):
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        out.append(np.concatenate([obs, [reward]]))
        if terminated or truncated:
            break
    return out


def test_gymnasium_and_sb3_checkers_pass_without_warnings():
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make("EBus-v0", service_h=0.3).unwrapped
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env)
        sb3_check_env(env, warn=True)


def test_same_seed_same_rollout_and_reset_is_reproducible():
    space = gym.spaces.Box(-1, 1, (len(ACTIONS),), np.float32, seed=3)
    actions = [space.sample() for _ in range(40)]
    a = gym.make("EBus-v0", service_h=0.5)
    b = gym.make("EBus-v0", service_h=0.5)
    first = rollout(a, actions, seed=7)
    assert all(np.array_equal(x, y) for x, y in zip(first, rollout(b, actions, seed=7),
                                                     strict=True))
    assert all(np.array_equal(x, y) for x, y in zip(first, rollout(a, actions, seed=7),
                                                     strict=True))
    other = rollout(a, actions, seed=8)  # another day: another ambient and passenger load
    assert not np.array_equal(first[0], other[0])


@pytest.mark.parametrize("bad, words", [
    (np.full(len(ACTIONS), np.nan, np.float32), "finite"),
    (np.full(len(ACTIONS), 1.5, np.float32), "[-1, 1]"),
    (np.zeros(3, np.float32), "shape"),
])
def test_invalid_actions_raise_clear_errors(bad, words):
    env = gym.make("EBus-v0", service_h=0.2, disable_env_checker=True)
    env.reset(seed=0)
    with pytest.raises(ValueError) as info:
        env.step(bad)
    assert words in str(info.value) and "speed_cap_kmh" in str(info.value)


@pytest.mark.parametrize("n_bus", [1, 4])  # 5 actions (checked in Python), 20 (with numpy)
def test_one_bad_action_among_good_ones_is_named(n_bus):
    shape = (n_bus, len(ACTIONS)) if n_bus > 1 else (len(ACTIONS),)
    names = list(ACTION_NAMES)
    good = np.linspace(-1.0, 1.0, np.prod(shape)).reshape(shape).astype(np.float32)
    np.testing.assert_array_equal(checked_actions(good, shape, names, "test"), good)
    for value, words in ((np.nan, "finite"), (-1.01, "[-1, 1]"), (np.inf, "finite")):
        bad = good.copy()
        bad[(-1, 2) if n_bus > 1 else 2] = value
        with pytest.raises(ValueError, match="setpoint_degc") as info:
            checked_actions(bad, shape, names, "test")
        assert words in str(info.value)


def test_actions_map_linearly_onto_their_ranges():
    """-1 and 1 give the ends exactly: a pulse duty of exactly 1 is continuous charging."""
    ends = physical(np.array([[-1.0] * len(ACTIONS), [1.0] * len(ACTIONS), [0.0] * len(ACTIONS)]))
    np.testing.assert_array_equal(ends[0], [a.low for a in ACTIONS])
    np.testing.assert_array_equal(ends[1], [a.high for a in ACTIONS])
    np.testing.assert_allclose(ends[2], [(a.low + a.high) / 2 for a in ACTIONS], rtol=1e-15)


@pytest.mark.parametrize("at_stops", [False, True])
def test_episode_energy_equals_one_continuous_run_of_the_model(at_stops):
    """Decision by decision with states carried is the same physics as one run of the
    recorded inputs: battery and grid energy and the final SoC agree (decisions of 60 s, or
    stop to stop)."""
    env = gym.make("EBus-v0", service_h=1.5, layover_min=10.0, laps_per_trip=10,
                   decide_at_stops=at_stops).unwrapped
    env.reset(seed=1)
    model = env.model
    start_states = env.buses.states.copy()
    rows, battery, grid = [], 0.0, 0.0
    a = action(setpoint_degc=22.0, charge_power_frac=0.6)
    terminated = False
    while not terminated:
        params = env.buses.params.copy()
        _, _, terminated, _, info = env.step(a)
        rows.append(env.buses.inputs[0, :, :env.buses.rows[0]].copy())
        battery += info["battery_kwh"]
        grid += info["grid_kwh"]
    inputs = np.concatenate(rows, axis=1)
    profile = Profile(dict(zip(model.input_names, inputs, strict=True)), model.dt_s)
    initial = dict(zip(model.state_names, start_states[0], strict=True))
    initial.pop("soc_frac")
    run = model.simulate(profile, params[0], soc_start=float(start_states[0, 3]),
                         record=False, **initial)
    s = run.summary()
    assert grid > 1.0 and s["grid_energy_kwh"] == pytest.approx(grid, rel=1e-9)
    assert s["battery_energy_kwh"] == pytest.approx(battery, rel=1e-9, abs=1e-9)
    assert s["soc_end_pct"] == pytest.approx(100 * env.buses.states[0, 3], abs=1e-9)


def test_stop_to_stop_decisions_end_at_departures_and_layovers():
    """With ``decide_at_stops`` a decision runs from one departure to the next (or into a
    layover), never longer than ``decision_s``; the day still ends after ``service_h``."""
    env = gym.make("EBus-v0", service_h=1.2, layover_min=6.0, decide_at_stops=True).unwrapped
    env.reset(seed=0)
    course, ref = env.course, env.buses.ref[0]
    durations, kinds = [], []
    terminated, mode = False, ref[reference.MODE]
    while not terminated:
        _, _, terminated, truncated, info = env.step(action(speed_cap_kmh=40.0))
        assert not truncated
        durations.append(info["duration_s"])
        mode, before = ref[reference.MODE], mode
        if mode == reference.LAYOVER and before != reference.LAYOVER:
            kinds.append("layover")  # just arrived: the whole layover is ahead
            assert ref[reference.TIMER] >= 60.0 * env.config.min_layover_min - 0.1
        elif mode == reference.DRIVE and ref[reference.V] == 0.0:
            kinds.append("departure")  # standing at a stop (or the terminal), doors shut
            k = int(ref[reference.STOP])
            assert ref[reference.S] == pytest.approx(0.0 if k == 0 else course.stop_m[k - 1])
        else:
            kinds.append("cut")  # a long stretch or layover split at decision_s
            assert info["duration_s"] == pytest.approx(env.config.decision_s)
    durations = np.array(durations)
    assert np.all(durations <= env.config.decision_s + 1e-9)
    assert durations.sum() == pytest.approx(3600.0 * 1.2, abs=env.config.decision_s)
    trips = int(ref[reference.LAP])  # trips completed (each ends in a layover)
    assert trips >= 1
    assert kinds.count("departure") >= trips * (len(course.stop_m) - 1)  # at every stop
    assert kinds.count("layover") in (trips, trips + 1)
    assert len(set(durations.round(1))) > 10  # segments differ in length


def test_speed_cap_keeps_the_stops_and_the_distance_and_takes_longer():
    course = course_from_cycle("manhattan")
    laps = {}
    for cap_kmh in (80.0, 25.0):
        state = reference.new_state()[None, :]
        n = 30000
        rows = np.zeros((1, 6, n))
        reference.advance(state, course.speed_mps, course.grade_frac, course.step_m,
                          course.stop_m, course.dwell_s, np.array([cap_kmh / 3.6]),
                          np.array([1.5]), 1.0, 1.0, course.lap_time_s + 600, 60.0, 1.0,
                          np.array([1e5]), 0.1, n, rows, np.arange(6))
        speed, door, plugged = rows[0, 0], rows[0, 5], rows[0, 3]
        arrive = int(np.argmax(plugged > 0))
        position = np.cumsum(speed) * 0.1
        opened = np.flatnonzero(np.diff(door[:arrive]) > 0) + 1
        laps[cap_kmh] = (arrive * 0.1, position[arrive], position[opened], speed.max())
    free, capped = laps[80.0], laps[25.0]
    assert free[0] == pytest.approx(course.lap_time_s, rel=0.03)  # the cycle's own timing
    assert capped[0] > free[0] + 20.0  # slower
    assert capped[1] == pytest.approx(course.length_m, abs=1.0)  # same lap distance
    assert free[1] == pytest.approx(course.length_m, abs=1.0)
    np.testing.assert_allclose(capped[2], free[2], atol=1.0)  # the same stops
    np.testing.assert_allclose(free[2], course.stop_m, atol=1.0)  # the terminal too
    assert capped[3] <= 25.0 / 3.6 + 1e-9


def test_speed_cap_lowers_traction_energy_and_delays_the_bus():
    out = {}
    for cap in (80.0, 30.0):
        env = gym.make("EBus-v0", cycle="sort3", service_h=1.0, ambient_random_k=0.0).unwrapped
        env.reset(seed=0)
        traction = distance = 0.0
        for _ in range(45):
            _, _, _, _, info = env.step(action(speed_cap_kmh=cap))
            traction += info["breakdown_kwh"]["traction"]
            distance += info["distance_km"]
        out[cap] = (traction / distance, info["schedule_delay_min"], distance)
    assert out[30.0][0] < 0.9 * out[80.0][0]
    assert out[30.0][1] > out[80.0][1] + 1.0
    assert out[30.0][2] < out[80.0][2]  # in the same time it got less far


def test_higher_setpoint_in_winter_raises_hvac_energy():
    hvac = {}
    for setpoint in (16.0, 24.0):
        env = gym.make("EBus-v0", service_h=1.0, ambient_mean_degc=-5.0).unwrapped
        env.reset(seed=0)
        total = 0.0
        for _ in range(60):
            _, _, _, _, info = env.step(action(setpoint_degc=setpoint))
            total += info["breakdown_kwh"]["cabin_hvac"]
        hvac[setpoint] = total
    assert hvac[24.0] > 1.2 * hvac[16.0] > 0


def test_pulsed_charging_lowers_peak_grid_power_at_equal_energy():
    """A long layover on the charger: pulses at half duty halve the grid power over each
    decision; over the layover both fill the battery to the same SoC."""
    result = {}
    for duty in (1.0, 0.5):
        env = gym.make("EBus-v0", cycle="sort1", laps_per_trip=1, service_h=5.0,
                       layover_min=290.0, soc_start_pct=50.0, charger_kw=150.0).unwrapped
        env.reset(seed=0)
        grid, terminated = 0.0, False
        while not terminated:
            _, _, terminated, _, info = env.step(action(pulse_duty=duty))
            grid += info["grid_kwh"]
        result[duty] = (info["peak_grid_kw"], grid, env.buses.states[0, 3])
    assert result[0.5][0] < 0.6 * result[1.0][0]
    assert result[0.5][1] == pytest.approx(result[1.0][1], rel=0.02)
    assert result[0.5][2] == pytest.approx(result[1.0][2], abs=0.005)


def test_rgb_render_shows_the_day_so_far():
    env = gym.make("EBus-v0", service_h=0.2, render_mode="rgb_array")
    env.reset(seed=0)
    env.step(action())
    image = env.render()
    assert image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3
    assert image.std() > 10  # not blank


def test_an_empty_battery_ends_the_day_and_charges_the_service_lost():
    """Without charging, a bus starting at 12 % SoC reaches the pack's floor within the day:
    the episode ends there and the reward charges every service hour left."""
    env = gym.make("EBus-v0", soc_start_pct=12.0, charge_at_terminal=False).unwrapped
    env.reset(seed=0)
    floor = env.model.params[env.model.param_names.index("rint_battery.soc_min_frac")]
    terminated, steps, km = False, 0, 0.0
    while not terminated:
        obs, reward, terminated, _, info = env.step(action())
        steps += 1
        km += info["distance_km"]
    hours_left = env.config.service_h - steps * env.config.decision_s / 3600.0
    assert info["depleted"] and hours_left > 1.0
    assert obs[env.observation_names.index("soc")] <= floor + 1e-9
    # the reason, with when and where
    clock_h = env.config.start_time_h + steps * env.config.decision_s / 3600.0
    assert info["ended_by"].startswith(f"battery empty at {int(clock_h):02d}:")
    assert f", {km:.1f} km into the day: the BMS opened the pack at its SoC floor" in \
        info["ended_by"]
    assert info["service_lost_h"] == pytest.approx(hours_left)
    weight = env.reward_fn.lost_service_per_hour
    assert info["reward_terms"]["lost_service"] == pytest.approx(weight * hours_left)
    assert reward <= -weight * hours_left


def test_observations_hold_the_peak_so_far_and_the_layover_left():
    env = gym.make("EBus-v0", service_h=3.0).unwrapped
    obs, _ = env.reset(seed=0)
    names = env.observation_names
    peak, left, plugged = (names.index(n) for n in ("peak_grid_kw", "layover_left_min",
                                                     "charger_connected"))
    seen_peak, lefts = 0.0, []
    for _ in range(180):
        obs, _, terminated, _, info = env.step(action())
        seen_peak = max(seen_peak, info["grid_kw"])
        assert obs[peak] == pytest.approx(seen_peak, rel=1e-5)
        lefts.append(obs[left] if obs[plugged] else None)
        assert obs[plugged] or obs[left] == 0.0
        if terminated:
            break
    on = [x for x in lefts if x is not None]
    assert on and max(on) <= env.config.layover_min + 1e-6
    # counts down by one decision per step on a layover
    runs = [(a, b) for a, b in zip(lefts, lefts[1:], strict=False) if a is not None and b is not None]
    assert runs and all(a - b == pytest.approx(1.0, abs=1e-6) for a, b in runs)


@pytest.mark.parametrize("name", sorted(p.stem for p in CONFIG_DIR.glob("*.yaml")
                                        if not p.stem.startswith("fleet")))
def test_every_shipped_env_config_runs_with_its_climate(name):
    """Each configs/env file builds EBus-v0; the ambient spans mean -+ amplitude over the day."""
    env = gym.make("EBus-v0", config=name, ambient_random_k=0.0).unwrapped
    cfg = env.config
    obs, _ = env.reset(seed=0)
    ambient = env.observation_names.index("ambient_degc")
    seen = [obs[ambient]]
    for _ in range(int(cfg.service_h * 60)):
        obs, _, terminated, _, _ = env.step(action())
        seen.append(obs[ambient])
        if terminated:
            break
    assert min(seen) >= cfg.ambient_mean_degc - cfg.ambient_amplitude_k - 1e-4
    assert max(seen) <= cfg.ambient_mean_degc + cfg.ambient_amplitude_k + 1e-4
    assert max(seen) - min(seen) > cfg.ambient_amplitude_k  # a day's swing, not a constant


def test_climate_normals_set_the_day_heat_in_winter_and_cool_in_summer():
    """A climate and a month set the day's ambient from monthly normals (mean of the daily
    minimum and maximum, half their difference). January in Gothenburg costs more HVAC
    energy than May; in July in Barcelona the HVAC cools: a lower setpoint costs more."""
    from ebus_env.envs.common import EnvConfig

    cfg = EnvConfig(climate="barcelona", month=7)
    assert (cfg.ambient_mean_degc, cfg.ambient_amplitude_k) == (26.0, 3.0)
    cfg = EnvConfig.load("gothenburg_jan")
    assert (cfg.ambient_mean_degc, cfg.ambient_amplitude_k) == (-1.0, 2.0)
    own = EnvConfig(climate={"name": "here", "min_degc": [0] * 12, "max_degc": [10] * 12},
                    month=3)
    assert (own.ambient_mean_degc, own.ambient_amplitude_k) == (5.0, 5.0)

    def hvac_kwh(name, setpoint_degc):
        env = gym.make("EBus-v0", config=name, ambient_random_k=0.0, service_h=3.0).unwrapped
        env.reset(seed=0)
        total, terminated = 0.0, False
        while not terminated:
            _, _, terminated, _, info = env.step(action(setpoint_degc=setpoint_degc))
            total += info["breakdown_kwh"]["cabin_hvac"]
        return total

    assert hvac_kwh("gothenburg_jan", 21.0) > 1.5 * hvac_kwh("gothenburg_may", 21.0)
    assert hvac_kwh("barcelona_jul", 19.0) > 1.3 * hvac_kwh("barcelona_jul", 24.0)


@pytest.mark.parametrize("keys, words", [
    ({"climate": "barcelna", "month": 7}, "Did you mean 'barcelona'"),
    ({"climate": "barcelona", "month": 13}, "1-12"),
    ({"climate": "barcelona"}, "climate and month go together"),
    ({"climate": "barcelona", "month": 7, "ambient_mean_degc": 20.0}, "not both"),
    ({"climate": {"min_degc": [0] * 11, "max_degc": [9] * 12}, "month": 1}, "12 monthly values"),
    ({"climate": {"min_degc": [5] * 12, "max_degc": [0] * 12}, "month": 1}, "must not exceed"),
])
def test_bad_climate_keys_raise_clear_errors(keys, words):
    from ebus_env.envs.common import EnvConfig

    with pytest.raises(ConfigError, match=words):
        EnvConfig.load("sort2_day" if "ambient_mean_degc" not in keys else None,
                       **{"ambient_mean_degc": None, "ambient_amplitude_k": None, **keys})


def test_a_measured_logs_speed_profile_is_a_line(tmp_path):
    """A log's speed profile becomes the line: its stand-stills are the stops (with their
    dwell), its grade the grade, its distance one trip; the day runs on it."""
    t = np.arange(0.0, 400.0, 1.0)
    speed_kmh = np.zeros_like(t)
    for start in (10.0, 140.0, 270.0):  # three runs of 100 s at 36 km/h, stand-stills between
        speed_kmh[(t >= start) & (t < start + 100.0)] = 36.0
    path = tmp_path / "day.csv"
    path.write_text("time_s,speed_kmh,grade_pct\n" + "".join(
        f"{a},{b},2.0\n" for a, b in zip(t, speed_kmh, strict=True)))
    env = gym.make("EBus-v0", log=str(path), service_h=0.5, layover_min=3.0).unwrapped
    course = env.course
    assert course.length_m == pytest.approx(3000.0, abs=15.0)
    np.testing.assert_allclose(course.stop_m, [1000.0, 2000.0, 3000.0], atol=15.0)
    np.testing.assert_allclose(course.dwell_s[:2], [30.0, 30.0], atol=1.5)
    assert np.median(course.grade_frac) == pytest.approx(0.02)
    env.reset(seed=0)
    terminated = False
    distance = 0.0
    while not terminated:
        _, _, terminated, _, info = env.step(action())
        distance += info["distance_km"]
    assert distance > 4.0  # more than one trip in half an hour
    with pytest.raises(ConfigError, match="give one line"):
        gym.make("EBus-v0", log=str(path), route="kc45")
    (tmp_path / "bad.csv").write_text("time_s,velocity\n0,1\n1,2\n")
    with pytest.raises(LogError, match="No speed column.*bad.csv.*Fix"):
        gym.make("EBus-v0", log=str(tmp_path / "bad.csv"))


def test_a_bus_without_a_charger_effect_is_refused_by_name(tmp_path):
    import yaml

    from ebus_env.errors import ConfigError

    data = yaml.safe_load((CONFIG_DIR.parent / "bus" / "12m.yaml").read_text())
    data["slots"] = {**data.get("slots", {}), "charger": "none"}
    data["params"].pop("grid_charger")
    bus = tmp_path / "no_charger.yaml"
    bus.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match="no effects offer the pulse duty cycle.*grid_charger"):
        gym.make("EBus-v0", config="sort2_day", bus=str(bus), service_h=0.5)


def test_the_structs_of_the_compiled_passes_declare_the_same_fields_twice():
    """The typed structs the compiled passes take (``BatchArrays``, ``Track``, ``Driving``)
    declare each field for readers and type checkers (the proxy class) and for numba (its
    struct type): the same names in the same order, of matching kinds."""
    from numba.core import types

    from ebus_env.envs import batch

    kinds = {"float": types.Float, "int": types.Integer, "bool": types.Boolean,
             "np.ndarray": types.Array, "reference.Track": reference.TrackType,
             "reference.Driving": reference.DrivingType}
    for proxy, struct in ((batch.BatchArrays, batch.BATCH_ARRAYS),
                          (reference.Track, reference.TRACK),
                          (reference.Driving, reference.DRIVING)):
        declared = proxy.__annotations__
        assert list(declared) == list(struct.field_dict), proxy.__name__
        for name, numba_type in struct.field_dict.items():
            assert isinstance(numba_type, kinds[declared[name]]), (proxy.__name__, name)
