"""What each statement of the SIMD lane loop costs (``run_lanes``, docs/performance.md).

    python -m benchmarks.lane_costs              # every statement (about 15 min)
    python -m benchmarks.lane_costs 10 25        # statements 10 and 25 only

For statement i, the loop over the lanes that computes it is written twice in a copy of the
generated kernel, and that copy is timed against the unchanged kernel (64 buses, a 1 h SORT 2
day, five calibrated parameters differing between the buses, one thread, best of 5 each, the
unchanged one timed before and after). The difference is that statement's cost per bus-step.
Doubled, most statements compute the same values again; sums count twice and a few statements
that update a variable in place apply twice, which changes the figures but hardly the work,
and the figures are not used. Each copy compiles in about 10 s. Not run in CI.
"""

from __future__ import annotations

import argparse
import importlib.util
import time
from pathlib import Path

import numba
import numpy as np

from ebus_env.config import load_bus
from ebus_env.cycles import service_day
from ebus_env.model import kernels, lanes

ROOT = Path(__file__).resolve().parent.parent

N_BUS = 64
VARYING = ("passenger_load.load_frac", "cabin_hvac.setpoint_degc", "static_rcd.rcd_frac",
           "cccv_taper.cv_soc_pct", "regen_cutoff.cutoff_speed_mps")
STATEMENT = " " * 12 + "for g in range(lanes):"  # one lane loop inside the time loop


def statements(lines: list[str]) -> list[tuple[int, int]]:
    """(first, end) line of each lane loop inside the time loop."""
    spans = []
    for i, line in enumerate(lines):
        if line.startswith(STATEMENT):
            j = i + 1
            while j < len(lines) and lines[j].startswith(" " * 16):
                j += 1
            spans.append((i, j))
    return spans


def compiled(model, source: str, tag: str):
    """``run_lanes`` of a (modified) kernel source, compiled without the disk cache."""
    path = kernels.cache_dir() / f"lane_costs_{tag}.py"
    path.write_text(source)
    try:
        spec = importlib.util.spec_from_file_location(f"lane_costs_{tag}", path)
        module = importlib.util.module_from_spec(spec)
        vars(module).update(kernels.bindings(model.composition, model.layout.calls, python=False))
        spec.loader.exec_module(module)
        return numba.njit(cache=False, nogil=True, error_model="numpy")(module.run_lanes)
    finally:
        path.unlink()


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("which", nargs="*", type=int, help="statement numbers (default: all)")
    parser.add_argument("--bus", default="12m")
    args = parser.parse_args()
    bus = load_bus(args.bus)
    model = bus.build()
    day = service_day("sort2", 1.0, model.dt_s, bus.service)
    params = np.tile(model.params, (N_BUS, 1))
    rng = np.random.default_rng(0)
    for name in VARYING:  # as bench_core's batches: the other parameters are shared
        low, high = model.bounds[model.param_index(name)]
        params[:, model.param_index(name)] = rng.uniform(low, high, N_BUS)
    states = np.repeat(model.initial_state(model.params, {"speed_ref_mps": 0.0}, 0.95)[None],
                       N_BUS, axis=0)
    inputs = model.input_array(day)[None]
    zeros = np.zeros(N_BUS, np.int64)

    def ns_per_bus_step(kernel, repeat: int = 5) -> float:
        best = np.inf
        for _ in range(repeat):
            run_args = (params, states.copy(), inputs, zeros, zeros, np.full(N_BUS, day.n_steps),
                        model.dt_s, 0, np.zeros(1, np.int64), np.zeros((N_BUS, 0, 1), np.float32),
                        np.zeros(1, np.bool_), model.new_accumulators(N_BUS), 0, N_BUS)
            t0 = time.perf_counter()
            kernel(*run_args)
            best = min(best, time.perf_counter() - t0)
        return 1e9 * best / (N_BUS * day.n_steps)

    source = lanes.lane_source(model.layout, model.varying_columns(params))
    start = source.index("def run_lanes(")
    end = source.index("\ndef run_sample_lanes(")
    lines = source[start:end].split("\n")
    spans = statements(lines)
    base = compiled(model, source, "base")
    ns_per_bus_step(base, 1)  # the first call binds the arguments' types
    print(f"{len(spans)} statements in the lane loop of '{args.bus}'; cost per bus-step:")
    for i in args.which or range(len(spans)):
        a, b = spans[i]
        doubled = "\n".join(lines[:b] + lines[a:b] + lines[b:])
        kernel = compiled(model, source[:start] + doubled + source[end:], str(i))
        ns_per_bus_step(kernel, 1)
        before, cost, after = ns_per_bus_step(base), ns_per_bus_step(kernel), ns_per_bus_step(base)
        print(f"{i:4d} {cost - min(before, after):+6.2f} ns  (loop {min(before, after):.1f})  "
              f"{lines[a + 1].strip()[:80]}", flush=True)


if __name__ == "__main__":
    main()
