"""The compiled loop: batch = single runs = plain Python; continuation from a saved state;
composition checks; a user's out-of-tree effect; the disk cache."""

from __future__ import annotations

import re
import subprocess
import sys
import textwrap
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from ebus_env.cycles import service_day
from ebus_env.errors import CompositionError, ConfigError
from ebus_env.model.lanes import lane_source
from ebus_env.model.model import build_model, differing_columns
from ebus_env.model.threads import run_chunks
from tests.conftest import DT, constant_profile

ROOT = Path(__file__).resolve().parent.parent
HEADWIND = f"{ROOT}/tests/user_effects/headwind.py:headwind"


@pytest.fixture(scope="module")
def mixed_profile(bus12):
    """20 minutes of SORT 2 with a layover on the charger, on a cold morning."""
    service = replace(bus12.service, layover_every_min=8.0, layover_min=2.0)
    return service_day("sort2", 20 / 60, DT, service, ambient_degc=2.0)


def candidate_rows(model, n=6, seed=1):
    rng = np.random.default_rng(seed)
    names = ["passenger_load.load_frac", "cabin_hvac.setpoint_degc", "static_rcd.rcd_frac",
             "cccv_taper.cv_soc_pct", "regen_cutoff.cutoff_speed_mps", "grid_charger.power_kw",
             "aero_drag.drag_coef"]
    rows = []
    for _ in range(n):
        row = {}
        for name in names:
            low, high = model.bounds[model.param_index(name)]
            row[name] = rng.uniform(low, high)
        rows.append(row)
    return rows


def test_batch_equals_each_member_alone(model12, mixed_profile):
    rows = candidate_rows(model12)
    batch = model12.simulate_batch(mixed_profile, rows, soc_start=0.85, record=["soc_frac"],
                                   record_every=10, threads=2)
    for i, row in enumerate(rows):
        single = model12.simulate(mixed_profile, row, soc_start=0.85)
        np.testing.assert_array_equal(batch.accumulators[i], single.accumulators)
        np.testing.assert_array_equal(batch.final_states[i], single.final_state)
        np.testing.assert_array_equal(batch.record("soc_frac")[i], single.trace("soc_frac")[::10])
    # the members really differ
    assert np.ptp(batch.final("soc_frac")) > 1e-3


def test_lane_loop_shares_what_does_not_vary(model12, mixed_profile):
    """The lane loop reads per bus only the parameters that differ between the buses, and runs
    each statement where its inputs change: with only the curb mass differing, the auxiliaries
    once per call, the vehicle body once per group, the passenger load once per step and the
    road load per lane and step. Still the scalar loop's bits."""
    i = model12.param_index("vehicle_body.curb_mass_kg")
    source = lane_source(model12.layout, {i})
    loop = source[source.index("def run_lanes("):source.index("def run_sample_lanes(")]
    assert re.search(r"\n {4}auxiliaries_w = fx__auxiliaries__main\(", loop)
    assert re.search(r"\n {12}W\[\d+, g\], .* = fx__vehicle_body__main\(P\[0, g\]", loop)
    assert re.search(r"\n {12}\w+ = fx__passenger_load__main\(passenger_count, ", loop)
    assert re.search(r"\n {16}W\[\d+, g\] = fx__aero_drag__main\(W\[", loop)
    assert loop.count("P[") == 2  # read in, read by the vehicle body

    short = mixed_profile.slice(0, 3000)
    params = np.repeat(model12.params[None], 24, axis=0)
    params[:, i] += np.linspace(0.0, 4000.0, 24)
    state0 = np.repeat(model12.initial_state(model12.params, {}, 0.85)[None], 24, axis=0)
    inputs = model12.input_array(short)
    results = []
    for kw in ({"lanes": True, "varying": {i}}, {"lanes": False}):
        states = state0.copy()
        results.append((model12.run(params, states, inputs, threads=2, **kw), states))
    np.testing.assert_array_equal(results[0][0], results[1][0])
    np.testing.assert_array_equal(results[0][1], results[1][1])
    assert np.ptp(results[0][1][:, model12.state_names.index("soc_frac")]) > 1e-4
    # a column left out that differs is an error, not a silent mix-up
    with pytest.raises(ValueError, match=rf"give at least \[{i}\]"):
        model12.run(params, state0.copy(), inputs, threads=2, lanes=True, varying=set())
    # columns differ bit for bit: -0.0 against 0.0 and NaN against a number count
    table = np.zeros((3, 4))
    table[1, 1], table[2, 3], table[:, 2] = -0.0, np.nan, np.nan
    assert differing_columns(table) == {1, 3}


def test_lane_kernel_equals_the_scalar_loop(model12, mixed_profile):
    """Buses on the same input rows run in SIMD lanes (``run_lanes``): the same results to the
    last bit, through ``simulate_batch`` on two threads and called directly, with spare lanes
    in the last group."""
    short = mixed_profile.slice(0, 3000)  # 5 minutes, the layover on the charger included
    rows = candidate_rows(model12, 150, seed=3)
    lanes = model12.simulate_batch(short, rows, soc_start=0.85, threads=2, lanes=True)
    scalar = model12.simulate_batch(short, rows, soc_start=0.85, threads=2)
    np.testing.assert_array_equal(lanes.final_states, scalar.final_states)
    np.testing.assert_array_equal(lanes.accumulators, scalar.accumulators)
    assert np.ptp(lanes.final("soc_frac")) > 1e-3 and np.ptp(lanes.final("cabin_temp_degc")) > 1.0

    n = 70  # two groups of 36 lanes, the second with 2 spare
    params = model12.param_matrix(rows[:n])
    inputs = model12.input_array(short)[None]
    state0 = lanes.initial_states[:n]
    results = {}
    for variant in ("run", "run_lanes"):
        states, acc = state0.copy(), model12.new_accumulators(n)
        kernel = model12.kernel(variant, model12.varying_columns(params))
        kernel(params, states, inputs, np.zeros(n, np.int64), np.full(n, 100), np.full(n, 2500),
               model12.dt_s, 0, np.zeros(0, np.int64), np.zeros((n, 0, 0), np.float32),
               np.zeros(1, np.bool_), acc, 0, n)
        results[variant] = states, acc
    np.testing.assert_array_equal(results["run_lanes"][0], results["run"][0])
    np.testing.assert_array_equal(results["run_lanes"][1], results["run"][1])
    # as calibration runs them: SoC at 1 Hz rows only, 15 buses a thread (16 lanes, 1 spare)
    mask = np.zeros(inputs.shape[2], np.bool_)
    mask[::10] = True
    soc = {}
    for lanes_on in (True, False):
        soc[lanes_on] = np.zeros((30, 250, 1), np.float32)
        model12.run(params[:30], state0[:30].copy(), inputs, step0=np.full(30, 500), n_steps=2500,
                    sample_mask=mask, record_out=soc[lanes_on], threads=2, lanes=lanes_on)
    np.testing.assert_array_equal(soc[True], soc[False])
    assert np.ptp(soc[True][:, -1, 0]) > 1e-3
    # lanes only where every bus reads the same rows and each thread has enough buses
    same = (np.zeros(n, np.int64), np.zeros(n, np.int64), np.full(n, 9))
    assert model12._shared_rows(*same, [0, 35, n])
    assert not model12._shared_rows(*same, [0, 5, n])
    assert not model12._shared_rows(same[0], same[1], np.r_[np.full(n - 1, 9), 8], [0, n])
    assert not model12._shared_rows(np.r_[np.zeros(n - 1, np.int64), 1], same[1], same[2], [0, n])


def test_run_chunks_runs_every_chunk_and_reraises():
    done = np.zeros(9, int)

    def mark(lo, hi):
        done[lo:hi] += 1

    run_chunks(mark, [0, 3, 6, 9])
    np.testing.assert_array_equal(done, 1)  # each bus exactly once

    def fail_in(chunk_lo):
        def fn(lo, hi):
            if lo == chunk_lo:
                raise RuntimeError(f"chunk {lo}")
            done[lo:hi] += 1
        return fn

    for lo in (0, 4):  # the chunk on this thread, then one on the pool
        done[:] = 0
        with pytest.raises(RuntimeError, match=f"chunk {lo}"):
            run_chunks(fail_in(lo), [0, 4, 8])
        # the other chunk was not abandoned: it finished before the error reached the caller
        np.testing.assert_array_equal(done[4:8] if lo == 0 else done[0:4], 1)


def test_compiled_equals_plain_python(model12, mixed_profile):
    short = mixed_profile.slice(0, 3000)  # 5 minutes, layover included
    short = short.with_channels(charger_connected=np.r_[np.zeros(1500), np.ones(1500)])
    params = model12.param_vector(candidate_rows(model12, 1)[0])
    compiled = model12.simulate(short, params, soc_start=0.86)
    plain = model12.simulate(short, params, soc_start=0.86, python=True)
    np.testing.assert_allclose(plain.accumulators, compiled.accumulators, rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(plain.final_state, compiled.final_state, rtol=1e-10)
    np.testing.assert_allclose(plain.trace_array, compiled.trace_array, rtol=1e-5, atol=1e-5)


def test_advancing_in_chunks_equals_one_run(model12, mixed_profile):
    """What the vector env does: N buses, k steps at a time, from their saved state."""
    inputs = model12.input_array(mixed_profile)
    params = model12.param_matrix(candidate_rows(model12, 3))
    first = {n: inputs[i, 0] for i, n in enumerate(model12.input_names)}
    state0 = np.array([model12.initial_state(p, first, 0.85) for p in params])
    whole = state0.copy()
    n = inputs.shape[1]
    acc_whole = model12.run(params, whole, inputs, n_steps=n)
    chunked = state0.copy()
    acc = model12.new_accumulators(3)
    step = 0
    for k in (600, 1, 3000, n - 3601):
        model12.run(params, chunked, inputs, step0=np.full(3, step), n_steps=k, acc=acc)
        step += k
    np.testing.assert_array_equal(chunked, whole)
    np.testing.assert_allclose(acc, acc_whole, rtol=1e-12, atol=1e-6)  # J; sums regrouped


def test_buses_on_different_profiles_in_one_call(model12, bus12):
    days = [service_day(c, 0.2, DT, bus12.service) for c in ("sort1", "sort2", "manhattan")]
    n = min(d.n_steps for d in days)
    inputs = np.stack([model12.input_array(d)[:, :n] for d in days])
    params = np.tile(model12.params, (3, 1))
    states = np.array([model12.initial_state(model12.params, {"speed_ref_mps": 0.0}, 0.9)
                       for _ in days])
    acc = model12.run(params, states, inputs, input_set=[0, 1, 2], n_steps=n)
    for i, day in enumerate(days):
        alone = model12.simulate(day.slice(0, n), soc_start=0.9, record=False)
        np.testing.assert_array_equal(acc[i], alone.accumulators)


def test_unknown_effect_suggests_the_close_name(bus12):
    with pytest.raises(ConfigError, match="Unknown effect 'aero_drg'. Did you mean 'aero_drag'"):
        bus12.with_effect("aero_drg")


def test_effect_reading_a_missing_signal_is_refused():
    from ebus_env.effects.base import Param, effect

    @effect("needs_cabin", sink="dc_load_w", register_effect=False,
            params=[Param("gain_w_per_k", 1.0, "W/K", (0.0, 10.0), "gain")])
    def needs_cabin(cabin_temp_degc, gain_w_per_k):
        return gain_w_per_k * cabin_temp_degc

    with pytest.raises(CompositionError, match="reads 'cabin_temp_degc'"):
        build_model(contributions=["aero_drag", needs_cabin])
    # with the cabin model present it composes
    build_model(contributions=["aero_drag", "cabin_hvac", needs_cabin])


def test_signal_provided_twice_is_refused():
    from ebus_env.effects.base import effect

    @effect("second_hvac_heat", sink="dc_load_w", returns=("hvac_heat_w",),
            register_effect=False)
    def second(speed_mps):
        return 0.0, 0.0

    with pytest.raises(CompositionError, match="'hvac_heat_w'.*already provided"):
        build_model(contributions=["cabin_hvac", second])


def test_slot_and_contribution_roles_are_checked():
    with pytest.raises(CompositionError, match="fills slot 'drivetrain'"):
        build_model(contributions=["constant_efficiency"])
    with pytest.raises(CompositionError, match="cannot fill slot 'battery'"):
        build_model(slots={"battery": "efficiency_map"})
    with pytest.raises(CompositionError, match="Slot 'battery' cannot be empty"):
        build_model(slots={"battery": "none"})


def test_bounds_and_values_are_checked(bus12):
    with pytest.raises(ConfigError, match="narrow its declared bounds"):
        build_model(bounds={"aero_drag": {"drag_coef": [0.1, 0.8]}},
                    contributions=["aero_drag"])
    model = bus12.build()
    with pytest.raises(ConfigError, match="outside its bounds"):
        model.param_vector({"aero_drag.drag_coef": 3.0})
    with pytest.raises(ConfigError, match="Unknown parameter 'aero_drag.drag_cof'"):
        model.param_vector({"aero_drag.drag_cof": 0.5})


@pytest.mark.parametrize(("kwargs", "words"), [
    ({"soc_start": 95}, "give the SoC as a fraction in [0, 1]. Did you mean 0.95 (95 %)?"),
    ({"soc_start": -0.1}, "soc_start = -0.1: give the SoC as a fraction"),
    ({"soc_start": float("nan")}, "soc_start = nan"),
    ({"params": "vector"}, "params vector"),
    ({"params": "x100"}, "'vehicle_body.curb_mass_kg' = 1300000.0 (params vector) lies outside"),
    ({"params": np.ones(3)}, "a vector of shape (3,); the model has"),
    ({"params": [0.6]}, "not a list"),
    ({"record_every": 0}, "record_every = 0: keep every k-th step"),
])
def test_a_run_refuses_a_start_or_parameters_it_cannot_mean(model12, kwargs, words):
    """A SoC of 95 is not 9500 %, and a parameter vector is checked like overrides are."""
    day = constant_profile(10.0, 600.0)
    given = kwargs.get("params")
    if isinstance(given, str):  # vectors of the model's length: one NaN, or all 100 times
        bad = model12.params * 100 if given == "x100" else model12.params.copy()
        bad[0] = np.nan if given == "vector" else bad[0]
        kwargs = {"params": bad}
    with pytest.raises(ConfigError) as info:
        model12.simulate(day, **kwargs)
    assert words in str(info.value)
    with pytest.raises(ConfigError, match="Did you mean 0.95"):
        model12.simulate_batch(day, [{}], soc_start=95)
    with pytest.raises(ConfigError, match="no parameter sets"):
        model12.simulate_batch(day, [])
    with pytest.raises(ConfigError, match="Unknown trace signal 'soc'"):
        model12.simulate_batch(day, [{}], record=["soc"])
    with pytest.raises(ConfigError, match="needs a Profile"):
        model12.simulate(None)
    assert model12.simulate(day, model12.params, soc_start=0.95).summary()["soc_start_pct"] \
        == pytest.approx(95.0)


def test_a_count_is_a_whole_number_and_no_search_fits_it(bus12, tmp_path):
    from ebus_env.calibration import CalibrationProblem
    from ebus_env.config import load_bus

    model = bus12.build()
    with pytest.raises(ConfigError, match="'rint_battery.cells_series' = 204.5 .* is a count"):
        model.param_vector({"rint_battery.cells_series": 204.5})
    overlay = tmp_path / "o.yaml"
    overlay.write_text("params: {passenger_load: {max_passengers: 85.5}}\n")
    with pytest.raises(ConfigError, match="'passenger_load.max_passengers' = 85.5 .* is a count"):
        load_bus("12m", overlays=[overlay]).build()
    day = constant_profile(10.0, 600.0)
    day.measured["soc_frac"] = np.linspace(0.9, 0.89, day.n_steps)
    with pytest.raises(ConfigError, match="'rint_battery.cells_parallel' is a count"):
        CalibrationProblem(model, [day], free=["rint_battery.cells_parallel"])


def test_user_effect_from_its_own_file_runs_in_the_compiled_core(bus12):
    bus = bus12.without_effect("cabin_hvac").with_effect(HEADWIND)
    model = bus.build()
    assert "headwind.wind_speed_mps" in model.param_names
    v = 12.0
    result = model.simulate(constant_profile(v, 300.0), soc_start=0.9)
    force = result.trace("headwind_n")
    speed = result.trace("speed_mps")
    assert force == pytest.approx(np.where(speed > 0, 0.5 * 1.2 * 5.25 * ((speed + 4) ** 2 - speed**2),
                                           0.0), rel=1e-5)
    assert force[-1] == pytest.approx(0.5 * 1.2 * 5.25 * ((v + 4.0) ** 2 - v**2), rel=1e-4)
    calm = model.simulate(constant_profile(v, 300.0), {"headwind.wind_speed_mps": 0.0},
                          soc_start=0.9, record=False)
    s = result.summary()
    assert s["breakdown_kwh"]["headwind"] > 0
    assert calm.summary()["breakdown_kwh"]["headwind"] == 0.0
    assert s["consumed_energy_kwh"] > calm.summary()["consumed_energy_kwh"]


def test_second_process_loads_the_kernel_from_the_disk_cache(model12, tmp_path):
    script = textwrap.dedent("""
        from ebus_env.config import load_bus
        model = load_bus("12m").build()
        model.compile()
        stats = model.kernel("run").stats
        print(sum(stats.cache_hits.values()), sum(stats.cache_misses.values()))
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         check=True, cwd=ROOT)
    hits, misses = map(int, out.stdout.split())
    assert (hits, misses) == (1, 0)


def test_memory_does_not_grow_with_steps_when_not_recording(model12, bus12):
    import tracemalloc

    def peak_extra(hours):
        profile = service_day("sort2", hours, DT, bus12.service)
        inputs = model12.input_array(profile)
        params = model12.params[None, :]
        states = model12.initial_state(model12.params, {"speed_ref_mps": 0.0}, 0.9)[None, :]
        tracemalloc.start()
        model12.run(params, states, inputs)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return peak

    short, long = peak_extra(0.5), peak_extra(5.0)
    assert long < short + 10_000  # bytes: nothing per step
