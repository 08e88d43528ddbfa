"""The step loop for many buses at once, in SIMD lanes: ``run_lanes`` and ``run_sample_lanes``,
``run`` and ``run_sample`` (:mod:`.generate`) for buses that share their input rows, generated in
a module of their own for each set of parameters that differ between the buses."""

from __future__ import annotations

import ast
from collections.abc import Iterable

from ebus_env.model.generate import Layout, param_local

LANES_MAX = 64
LANES_MIN = 12
"""``run_lanes`` advances its buses in groups of at most ``LANES_MAX`` lanes, of equal width and a
multiple of 4 (AVX2: four float64 per instruction); below ``LANES_MIN`` buses it is not faster
than ``run`` by much. Measured on a 12 m bus, one thread, against ``run`` (two runs, before
the battery's ``pack`` call made the lanes about 15 % faster; not measured again): 12 buses
-16 and -27 %, 16 to 275 buses -28 to -33 %, 8 and 11 buses (8 and 12 lanes) -7 and -6 %, and
11 lanes +21 % (presumably as the remainder of 3 runs scalar). The width is not known to the
compiler, on purpose: written as the literal 32 the same loop took 53.7 against 39.5 ns per
bus-step (its machine code is shorter, not longer; the cause was not found)."""


class _ToLanes(ast.NodeTransformer):
    """Rewrite a statement of the step for lane ``g``: variable ``x`` becomes ``W[row(x), g]``,
    parameter ``p`` becomes ``P[j, g]``; functions, tables and constants stay."""

    def __init__(self, rows: dict[str, int], params: dict[str, int]) -> None:
        self.at = {**{n: ("W", j) for n, j in rows.items()}, **{n: ("P", j) for n, j in params.items()}}

    def visit_Name(self, node: ast.Name) -> ast.expr:
        if node.id not in self.at:
            return node
        array, j = self.at[node.id]
        index = ast.Tuple([ast.Constant(j), ast.Name("g", ast.Load())], ast.Load())
        return ast.copy_location(ast.Subscript(ast.Name(array, ast.Load()), index, node.ctx), node)


def lane_source(layout: Layout, varying: Iterable[int]) -> str:
    """Source of the lane loops ``run_lanes`` and ``run_sample_lanes`` for buses whose
    parameters differ only in the columns ``varying`` (the others are read once, from the
    first bus)."""
    columns = sorted(set(varying))
    return "\n".join(
        layout.header + [f"# lane loops: parameters that differ between lanes: {columns}"]
        + _lane_loop("run_lanes", layout, "plain", columns)
        + _lane_loop("run_sample_lanes", layout, "sample", columns)) + "\n"


def _lane_loop(name: str, layout: Layout, mode: str, varying: list[int]) -> list[str]:
    """``run_lanes`` (``mode`` plain) or ``run_sample_lanes`` (sample): the loop for buses that
    share their input rows (``input_set``, ``step0`` and ``n_steps`` of ``bus_lo`` hold for
    all), in groups (``LANES_MAX``), with one loop over the lanes per statement of the step.
    Same arguments and results as ``run`` or ``run_sample``, to the last bit.

    Every variable of the step that differs between lanes is a row of the scratch array
    ``W[variable, lane]``, every parameter in ``varying`` a row of ``P``: loops that simple
    compile to SIMD code (4 lanes per AVX2 instruction), which the whole step as one loop does
    not (too many branches). Each statement runs where its inputs change: once per call (only
    shared parameters), once per group (parameters), once per step (shared parameters and the
    input rows) or once per lane and step; the shared values stay plain locals, so the compiler
    can hoist what depends on shared parameters alone out of both loops, as in ``run``. Spare lanes
    of the last group repeat its last bus and are not written back.
    """
    sums, extremes = layout.sums, layout.extremes
    tree = ast.parse("\n".join(layout.body))
    stored = [n.id for n in ast.walk(tree) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store)]
    variables = list(dict.fromkeys([*layout.states, *stored]))
    locals_ = [param_local(e, p) for e, p in layout.params]
    shared_params = [p for j, p in enumerate(locals_) if j not in set(varying)]
    steady = set(locals_)  # names that keep their value over the steps
    scalar = set(shared_params) | set(layout.inputs) | {"time_s"}  # the same in every lane
    known = set(variables) | steady | scalar
    placed: dict[str, list[str]] = {"call": [], "group": [], "step": [], "lane": []}
    for st in tree.body:
        reads = {n.id for n in ast.walk(st) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Load)}
        reads &= known
        outs = [n.id for n in ast.walk(st) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store)]
        single = isinstance(st, ast.Assign) and all(stored.count(o) == 1 for o in outs)
        is_steady, is_scalar = single and reads <= steady, single and reads <= scalar
        steady |= set(outs) if is_steady else set()
        scalar |= set(outs) if is_scalar else set()
        where = ("call" if is_steady and is_scalar else "group" if is_steady
                 else "step" if is_scalar else "lane")
        placed[where].append(ast.unparse(st))
    rows = {n: j for j, n in enumerate(v for v in variables if v not in scalar)}
    to_lanes = _ToLanes(rows, {locals_[j]: i for i, j in enumerate(varying)})

    def lane(code: str, indent: str) -> list[str]:
        return [indent + line for line in ast.unparse(to_lanes.visit(ast.parse(code))).splitlines()]

    n_sum, n_acc = len(sums), len(sums) + len(extremes)
    summed = range(n_sum if mode == "plain" else 0)  # calibration needs no energies
    each = placed["lane"] + [f"S[{j}, g] += {sums[j][1]}" for j in summed]
    each += [f"S[{j}, g] = {how}(S[{j}, g], {expr})"
             for j, (_, expr, how) in enumerate(extremes, start=n_sum)]
    advance = [f"{s} = {s}_next" for s in layout.states]

    g = "for g in range(lanes):"
    i2, i3, i4, i5 = (" " * n for n in (8, 12, 16, 20))
    out = [
        "",
        "",
        f"def {name}(params, states, inputs, input_set, step0, n_steps, dt_s, record_every, "
        "record_sel, record_out, sample_mask, acc, bus_lo, bus_hi):",
        "    if bus_hi <= bus_lo:",
        "        return",
        f"    groups = -(-(bus_hi - bus_lo) // {LANES_MAX})",
        "    lanes = -(-(bus_hi - bus_lo) // (4 * groups)) * 4  # equal groups, 4 lanes a vector",
        f"    W = np.zeros(({len(rows)}, lanes))",
        f"    P = np.empty(({len(varying)}, lanes))",
        f"    S = np.empty(({n_acc}, lanes))",
        "    inp = inputs[input_set[bus_lo]]",
    ]
    out += [f"    {p} = params[bus_lo, {locals_.index(p)}]" for p in shared_params]
    for code in placed["call"]:
        out += lane(code, "    ")
    out += [
        "    for c in range(bus_lo, bus_hi, lanes):",
        f"{i2}{g}",
        f"{i3}b = min(c + g, bus_hi - 1)",
    ]
    out += [f"{i3}P[{i}, g] = params[b, {j}]" for i, j in enumerate(varying)]
    out += [f"{i3}W[{rows[s]}, g] = states[b, {j}]" for j, s in enumerate(layout.states)]
    out += [f"{i3}S[{j}, g] = 0.0" for j in summed]
    out += [f"{i3}S[{j}, g] = acc[b, {j}]" for j in range(n_sum, n_acc)]
    for code in placed["group"]:
        out += [f"{i2}{g}"] + lane(code, i3)
    out += [f"{i2}r = 0"] if mode == "sample" else []
    out += [f"{i2}for k in range(n_steps[bus_lo]):",
            f"{i3}row = step0[bus_lo] + k",
            f"{i3}time_s = row * dt_s"]
    out += [f"{i3}{ch} = inp[{j}, row]" for j, ch in enumerate(layout.inputs)]
    for code in placed["step"]:
        out += lane(code, i3)
    for code in each:
        out += [f"{i3}{g}"] + lane(code, i4)
    if mode == "sample":
        out += [f"{i3}if sample_mask[row]:",
                f"{i4}for g in range(min(lanes, bus_hi - c)):",
                f"{i5}record_out[c + g, r, 0] = W[{rows['soc_frac']}, g]",
                f"{i4}r += 1"]
    for code in advance:
        out += [f"{i3}{g}"] + lane(code, i4)
    out += [f"{i2}for g in range(min(lanes, bus_hi - c)):", f"{i3}b = c + g"]
    out += [f"{i3}states[b, {j}] = W[{rows[s]}, g]" for j, s in enumerate(layout.states)]
    out += [f"{i3}acc[b, {j}] += S[{j}, g] * dt_s" for j in summed]
    out += [f"{i3}acc[b, {j}] = S[{j}, g]" for j in range(n_sum, n_acc)]
    return out
