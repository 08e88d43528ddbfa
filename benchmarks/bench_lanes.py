"""SIMD across buses: the step as loops over lanes, one loop per statement. Prints a table.

    python benchmarks/bench_lanes.py             # 64 buses, 4 h SORT 2 day, 16 and 64 lanes
    python benchmarks/bench_lanes.py --smoke     # CI: tiny sizes, checks the results only

An experiment, not (yet) a kernel the model uses. The scalar kernel advances one bus through
all its steps; here a group of G buses advances together, and every statement of the step is
its own loop over the G lanes, each variable a row of one scratch array ``W[variable, lane]``
(parameters ``P[param, lane]``). A loop that simple is one the compiler turns into 4-wide AVX2
code (the whole step as one lane loop is not: too many branches). Statements that read only
parameters run once per group, not per step. Lanes share the input rows (as a batch of
parameter sets does), the results must equal the scalar kernel's to the last bit, and the time
is compared with the scalar kernel on the same buses in the same run.

The source is derived from the generated scalar loop (``Model.layout.source``), so it follows
whatever effects the bus has. Set ``NUMBA_DEBUGINFO`` off when looking at vectorisation: with
debug info numba's LLVM does not vectorise these loops at all.
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from pathlib import Path

import numba
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from ebus_env.config import load_bus  # noqa: E402
from ebus_env.cycles import service_day  # noqa: E402
from ebus_env.model import codegen  # noqa: E402

_ASSIGN = re.compile(r"\s*([a-z_][\w, ]*?)\s*(?:\*=|\+=|=)\s")


def _step_parts(layout):
    """The scalar loop's step body (statements with their blocks), energy sums and extremes."""
    lines = layout.source[:layout.source.index("def run_record")].splitlines()
    start = next(i for i, line in enumerate(lines) if line.strip().startswith("time_s = row"))
    end = next(i for i, line in enumerate(lines) if re.match(r"\s+s0 \+= ", line))
    body = [line for line in lines[start + 1:end]
            if line.strip() and not line.strip().startswith("#") and " = inp[" not in line]
    indent = min(len(line) - len(line.lstrip()) for line in body)
    statements: list[list[str]] = []
    for line in (line[indent:] for line in body):
        if statements and line.startswith((" ", "else", "elif")):
            statements[-1].append(line)
        else:
            statements.append([line])
    sums = [line.split("+=", 1)[1].strip() for line in lines if re.match(r"\s+s\d+ \+= ", line)]
    extremes = [re.match(r"\s+a\d+ = (max|min)\(a\d+, (.*)\)$", line).groups()
                for line in lines if re.match(r"\s+a\d+ = (max|min)\(a\d+", line)]
    return statements, sums, extremes


def lane_source(layout, lanes: int) -> str:
    """Source of ``run_lanes(params, states, inputs, step0, n_steps, dt_s, acc, bus_lo,
    bus_hi)``: buses in groups of ``lanes``, all reading input set 0 from the same rows."""
    statements, sums, extremes = _step_parts(layout)
    scalars = set(layout.inputs) | {"dt_s", "time_s", "row"}
    names = list(layout.states)
    for st in statements:
        for line in st:
            m = _ASSIGN.match(line)
            names += [n.strip() for n in m.group(1).split(",")] if m else []
    row_of = {n: j for j, n in enumerate(dict.fromkeys(n for n in names if n not in scalars))}
    param_of = {f"p__{e}__{p}": j for j, (e, p) in enumerate(layout.params)}

    def lane(line: str) -> str:
        def sub(m):
            name = m.group(0)
            if name in row_of:
                return f"W[{row_of[name]}, g]"
            return f"P[{param_of[name]}, g]" if name in param_of else name
        return re.sub(r"\b[A-Za-z_]\w*\b", sub, line)

    # statements that read only parameters (or earlier such results), and whose results no
    # other statement changes, run once per group
    fixed: set[str] = set()
    once, each_step = [], []
    for st in statements:
        m = _ASSIGN.match(st[0])
        outs = {n.strip() for n in m.group(1).split(",")} if m and len(st) == 1 else set()
        reads = set(re.findall(r"\b[a-z_]\w*\b", st[0])) & (set(row_of) | scalars)
        if outs and reads - outs <= fixed and all(names.count(o) == 1 for o in outs):
            fixed |= outs
            once.append(st)
        else:
            each_step.append(st)
    n_acc = len(sums) + len(extremes)
    end = [f"S[{j}, g] += {e}" for j, e in enumerate(sums)]
    end += [f"S[{len(sums) + j}, g] = {how}(S[{len(sums) + j}, g], {e})"
            for j, (how, e) in enumerate(extremes)]
    end += [f"{s} = {s}_next" for s in layout.states]
    g = f"for g in range({lanes}):"
    out = [layout.source[:layout.source.index("\n\ndef run(")], "",
           "def run_lanes(params, states, inputs, step0, n_steps, dt_s, acc, bus_lo, bus_hi):",
           f"    W = np.zeros(({len(row_of)}, {lanes}))",
           f"    P = np.empty(({len(param_of)}, {lanes}))",
           f"    S = np.empty(({n_acc}, {lanes}))",
           "    inp = inputs[0]",
           f"    for c in range(bus_lo, bus_hi, {lanes}):",
           f"        {g}",
           "            b = min(c + g, bus_hi - 1)  # spare lanes repeat the last bus",
           f"            for j in range({len(param_of)}):",
           "                P[j, g] = params[b, j]"]
    out += [f"            W[{row_of[s]}, g] = states[b, {j}]" for j, s in enumerate(layout.states)]
    out += [f"            S[{j}, g] = 0.0" for j in range(len(sums))]
    out += [f"            S[{j}, g] = acc[b, {j}]" for j in range(len(sums), n_acc)]
    for st in once:
        out += [f"        {g}"] + ["            " + lane(line) for line in st]
    out += ["        for k in range(n_steps):", "            row = step0 + k",
            "            time_s = row * dt_s"]
    out += [f"            {ch} = inp[{j}, row]" for j, ch in enumerate(layout.inputs)]
    for st in each_step + [end]:
        out += [f"            {g}"] + ["                " + lane(line) for line in st]
    out += [f"        {g}", "            b = c + g", "            if b < bus_hi:"]
    out += [f"                states[b, {j}] = W[{row_of[s]}, g]" for j, s in enumerate(layout.states)]
    out += [f"                acc[b, {j}] += S[{j}, g] * dt_s" for j in range(len(sums))]
    out += [f"                acc[b, {j}] = S[{j}, g]" for j in range(len(sums), n_acc)]
    return "\n".join(out) + "\n"


def compile_lanes(model, lanes: int):
    codegen._register_effects(model.composition)  # the effect globals the source binds
    namespace = {"__name__": f"ebus_lanes_{lanes}"}
    exec(compile(lane_source(model.layout, lanes), f"<lanes {lanes}>", "exec"), namespace)
    return numba.njit(nogil=True, error_model="numpy")(namespace["run_lanes"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--buses", type=int, default=64)
    parser.add_argument("--hours", type=float, default=4.0)
    parser.add_argument("--lanes", type=int, nargs="+", default=[16, 64])
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--smoke", action="store_true")
    args = parser.parse_args()
    if args.smoke:
        args.buses, args.hours, args.lanes, args.repeat = 10, 0.1, [8], 1
    bus = load_bus("12m")
    model = bus.build()
    day = service_day("sort2", args.hours, model.dt_s, bus.service)
    inputs = model.input_array(day)[None]
    n, steps = args.buses, inputs.shape[2]
    rng = np.random.default_rng(0)
    params = np.tile(model.params, (n, 1))
    for name in ("passenger_load.load_frac", "cabin_hvac.setpoint_degc", "static_rcd.rcd_frac"):
        low, high = model.bounds[model.param_index(name)]
        params[:, model.param_index(name)] = rng.uniform(low, high, n)
    states0 = np.repeat(model.initial_state(model.params, {"speed_ref_mps": 0.0}, 0.95)[None],
                        n, axis=0)

    def scalar():
        states = states0.copy()
        return states, model.run(params, states, inputs, threads=1)

    print(f"{n} buses x {steps:,} steps (12 m bus, SORT 2), one thread; ns per bus-step, "
          f"best of {args.repeat}")
    for lanes in args.lanes:
        t0 = time.perf_counter()
        kernel = compile_lanes(model, lanes)

        def lane_run(k=kernel):
            states, acc = states0.copy(), model.new_accumulators(n)
            k(params, states, inputs, 0, steps, model.dt_s, acc, 0, n)
            return states, acc
        s_lanes, acc_lanes = lane_run()
        compile_s = time.perf_counter() - t0
        s_scalar, acc_scalar = scalar()
        if not (np.array_equal(s_lanes, s_scalar) and np.array_equal(acc_lanes, acc_scalar)):
            raise SystemExit(f"{lanes} lanes: results differ from the scalar kernel")
        best = {"scalar": np.inf, "lanes": np.inf}
        for _ in range(args.repeat):  # alternate, so both see the same machine
            for what, fn in (("scalar", scalar), ("lanes", lane_run)):
                t = time.perf_counter()
                fn()
                best[what] = min(best[what], time.perf_counter() - t)
        per = {k: 1e9 * v / (n * steps) for k, v in best.items()}
        print(f"  {lanes:3d} lanes: {per['lanes']:5.1f} against scalar {per['scalar']:5.1f} "
              f"({per['lanes'] / per['scalar'] - 1:+.0%}), results identical, "
              f"compiled in {compile_s:.0f} s")


if __name__ == "__main__":
    main()
