"""Speed and memory of the compiled core (issue 2 targets). Prints a table; no assertions.

    python -m benchmarks.bench_core            # full run (about a minute)
    python -m benchmarks.bench_core --smoke    # CI: small sizes, same code paths

Figures are medians of repeated runs on this machine; ratios are taken within one run.
The reference figure for FASTSim 3 (about 8 s for the same 486,000-step day, 17 us per step)
comes from the issue text; FASTSim is not installed here.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

from ebus_env.config import load_bus
from ebus_env.cycles import service_day
from ebus_env.model.lanes import LANES_MIN

ROOT = Path(__file__).resolve().parent.parent

FASTSIM_DAY_S = 8.0
rows: list[tuple[str, str, str]] = []


def row(what: str, value: str, note: str = "") -> None:
    rows.append((what, value, note))
    print(f"  {what:58s} {value:>14s}  {note}", flush=True)


def median_time(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def compile_times() -> None:
    script = ("import time; t=time.perf_counter(); from ebus_env.config import load_bus; "
              "m=load_bus('12m').build(); m.compile(); print(time.perf_counter()-t)")
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "EBUS_CACHE_DIR": cache}
        cold = float(subprocess.run([sys.executable, "-c", script], env=env, cwd=ROOT,
                                    capture_output=True, text=True, check=True).stdout)
        warm = float(subprocess.run([sys.executable, "-c", script], env=env, cwd=ROOT,
                                    capture_output=True, text=True, check=True).stdout)
    row("build + JIT compile, empty cache (12 m model)", f"{cold:.1f} s")
    row("build + load from the disk cache (second process)", f"{warm:.2f} s",
        "includes importing numba")


def cli_time() -> None:
    cmd = [sys.executable, "-m", "ebus_env.cli", "simulate", "--bus", "12m", "--cycle", "sort2",
           "--hours", "13.5"]
    subprocess.run(cmd, cwd=ROOT, capture_output=True, check=True)  # warm the cache
    wall = median_time(lambda: subprocess.run(cmd, cwd=ROOT, capture_output=True, check=True), 3)
    row("`ebus simulate --bus 12m --cycle sort2 --hours 13.5` (process)", f"{wall:.2f} s",
        "interpreter start, imports, cached kernel, table")


def single_bus(hours: float, repeat: int) -> float:
    bus = load_bus("12m")
    model = bus.build()
    model.compile()
    day = service_day("sort2", hours, model.dt_s, bus.service)
    steps = day.n_steps
    loops: list[float] = []
    total = median_time(lambda: loops.append(
        model.simulate(day, soc_start=0.95, record=False).wall_time_s), repeat)
    loop = statistics.median(loops)
    row(f"single bus, {hours:g} h SORT 2 day ({steps:,} steps): compiled loop", f"{1e3 * loop:.1f} ms",
        f"{1e9 * loop / steps:.0f} ns/step; FASTSim 3 day / this = "
        f"{FASTSIM_DAY_S / (loop * 486_000 / steps):.0f}x")
    row("  the same through model.simulate() (inputs cached after 1st)", f"{1e3 * total:.1f} ms")
    model.compile(record=True)
    rec = median_time(lambda: model.simulate(day, soc_start=0.95, record=True), max(1, repeat // 2))
    row("  with the full 10 Hz trace recorded", f"{1e3 * rec:.1f} ms",
        f"{len(model.trace_names)} signals, float32")
    no_hvac = bus.without_effect("cabin_hvac").build()
    no_hvac.compile()
    loops.clear()
    median_time(lambda: loops.append(
        no_hvac.simulate(day, soc_start=0.95, record=False).wall_time_s), repeat)
    t = statistics.median(loops)
    row("  without the cabin HVAC effect: compiled loop", f"{1e3 * t:.1f} ms",
        f"{1e9 * t / steps:.0f} ns/step")
    return loop


def batch(hours: float, sizes, repeat: int) -> None:
    bus = load_bus("12m")
    model = bus.build()
    model.compile()
    day = service_day("sort2", hours, model.dt_s, bus.service)
    rng = np.random.default_rng(0)
    for n in sizes:
        params = np.tile(model.params, (n, 1))
        for name in ("passenger_load.load_frac", "cabin_hvac.setpoint_degc", "static_rcd.rcd_frac",
                     "cccv_taper.cv_soc_pct", "regen_cutoff.cutoff_speed_mps"):
            low, high = model.bounds[model.param_index(name)]
            params[:, model.param_index(name)] = rng.uniform(low, high, n)
        for threads in (1, 2):
            lanes_and_scalar(f"batch of {n} parameter sets, {threads} thread(s)", n, day.n_steps,
                             threads, repeat, lambda lanes, p=params, th=threads: model.simulate_batch(
                                 day, p, soc_start=0.95, threads=th, lanes=lanes).wall_time_s)
        calibration_pass(model, day, params, repeat)


def calibration_pass(model, day, params: np.ndarray, repeat: int) -> None:
    """The batch as calibration runs it: SoC kept at a 1 Hz log's rows, no energy sums."""
    n = params.shape[0]
    # timed runs exclude the JIT
    model.compile(sample=True, lanes=n >= 2 * LANES_MIN, params=params)
    inputs = model.input_array(day)
    states = np.repeat(model.initial_state(model.params, {"speed_ref_mps": 0.0}, 0.95)[None],
                       n, axis=0)
    mask = np.zeros(day.n_steps, bool)
    mask[::round(1.0 / model.dt_s)] = True
    soc = np.zeros((n, int(mask.sum()), 1), np.float32)

    def one(lanes: bool) -> float:
        t0 = time.perf_counter()
        model.run(params, states.copy(), inputs, sample_mask=mask, record_out=soc, threads=2,
                  lanes=lanes)
        return time.perf_counter() - t0

    lanes_and_scalar("  as calibration (SoC at 1 Hz only), 2 threads", n, day.n_steps, 2, repeat, one)


def lanes_and_scalar(what: str, n: int, n_steps: int, threads: int, repeat: int, run) -> None:
    """Rows for ``run(lanes)`` (its wall time [s]) with SIMD lanes and one bus at a time, taken
    in turn; lanes apply from ``LANES_MIN`` buses per thread."""
    ways = (True, False) if n >= threads * LANES_MIN else (False,)
    walls: dict[bool, list[float]] = {lanes: [] for lanes in ways}
    for _ in range(repeat):
        for lanes in ways:
            walls[lanes].append(run(lanes))
    for lanes in ways:
        t = statistics.median(walls[lanes])
        how = "in SIMD lanes" if lanes else "one by one"
        row(f"{what}, {how}", f"{t:.2f} s", f"{1e9 * t / (n * n_steps):.1f} ns per bus-step")


def memory(model_hours=(1.35, 13.5)) -> None:
    bus = load_bus("12m")
    model = bus.build()
    model.compile()
    peaks = []
    for hours in model_hours:
        day = service_day("sort2", hours, model.dt_s, bus.service)
        inputs = model.input_array(day)
        params = model.params[None, :]
        states = model.initial_state(model.params, {"speed_ref_mps": 0.0}, 0.95)[None, :]
        tracemalloc.start()
        model.run(params, states, inputs)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        row(f"memory allocated by a {hours:g} h run, trace off", f"{peaks[-1] / 1024:.1f} KiB",
            f"inputs themselves: {inputs.nbytes / 2**20:.1f} MiB")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--smoke", action="store_true", help="small sizes (CI)")
    args = parser.parse_args()
    print(f"ebus-env core benchmark on {os.cpu_count()} CPUs ({'smoke' if args.smoke else 'full'})")
    if args.smoke:
        single_bus(1.0, 3)
        batch(0.2, (11, 128), 1)
        memory((0.2, 1.0))
        return
    compile_times()
    cli_time()
    single_bus(13.5, 9)
    batch(13.5, (11, 550), 3)
    memory()


if __name__ == "__main__":
    main()
