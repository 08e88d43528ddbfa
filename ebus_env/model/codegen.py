"""Generate, compile and cache the model's step loop.

The chosen effects are stitched into the skeleton of :mod:`ebus_env.model.template` as one flat
Python function that loops over buses and time steps. Effect functions are called by name with
their parameters unpacked into locals, so numba compiles (and inlines) everything into one
machine-code loop: a user's effect runs at the same speed as a built-in one. Five variants are
generated from the same step: ``run`` (no recording: nothing beyond the states and energy sums
stays live, which keeps the loop in registers), ``run_record`` (keeps a trace), ``run_sample``
(calibration: only the SoC at the rows a log has samples, no energy sums), and, in a module of
their own for each set of parameters that differ between the buses (:func:`lane_source`),
``run_lanes`` and ``run_sample_lanes``: ``run`` and ``run_sample`` for buses that share their
input rows, many at a time in SIMD lanes.

The source is written to ``$EBUS_CACHE_DIR`` (default ``~/.cache/ebus_env/kernels``) under a
name that hashes the source, the effects' source files and the library versions, and compiled
with numba's on-disk cache: a second process with the same model loads machine code instead
of compiling. The same source executed as plain Python (``python_kernel``) is the reference the
tests compare the compiled loop with.

``run[_record|_sample](params, states, inputs, input_set, step0, n_steps, dt_s, record_every,
record_sel, record_out, sample_mask, acc, bus_lo, bus_hi)`` advances buses ``bus_lo..bus_hi-1``,
each by ``n_steps[b]`` steps starting at input row ``step0[b]`` of input set ``input_set[b]``, in
place:

* ``params`` (n_bus, n_params): parameter values, one row per bus (or per candidate);
* ``states`` (n_bus, n_states): updated to the state after the last step;
* ``inputs`` (n_sets, n_inputs, n_rows): input channels, one contiguous row each;
* ``acc`` (n_bus, n_acc): energies [J] are added, extremes updated;
* ``record_out`` (n_bus, n_records, len(record_sel)): ``run_record`` writes the trace signals
  ``record_sel`` every ``record_every`` steps (float32); ``run_sample`` writes ``soc_frac`` in
  column 0 at each row where ``sample_mask[row]`` is set, in order (the energy sums stay 0).
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
import inspect
import os
import sys
import textwrap
import threading
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np

from ebus_env.effects.base import Effect
from ebus_env.errors import CompositionError, did_you_mean
from ebus_env.model import template
from ebus_env.model.signals import ALWAYS, CORE_STATES, INPUTS, SINKS, SLOTS


@dataclass
class Composition:
    """The effects of a model: one per slot (None: pass-through) and contributions per sink."""

    slots: dict[str, Effect | None]
    contributions: dict[str, list[Effect]]
    tables: dict[tuple[str, str], np.ndarray]

    @property
    def effects(self) -> list[Effect]:
        chosen = [e for e in self.slots.values() if e is not None]
        return chosen + [e for sink in SINKS for e in self.contributions.get(sink, [])]


@dataclass
class Layout:
    """What the generated kernel expects and produces, in column order."""

    source: str = ""
    params: list[tuple[str, str]] = field(default_factory=list)  # (effect, param)
    states: list[str] = field(default_factory=list)
    inputs: list[str] = field(default_factory=list)
    trace: list[str] = field(default_factory=list)
    accumulators: list[tuple[str, str]] = field(default_factory=list)  # (name, sum|max|min)
    calls: list[tuple[str, str]] = field(default_factory=list)  # (effect, call site)
    road_terms: list[str] = field(default_factory=list)
    load_terms: list[str] = field(default_factory=list)
    header: list[str] = field(default_factory=list)  # imports, bindings, tables
    body: list[str] = field(default_factory=list)  # one step, as Python statements
    sums: list[tuple[str, str]] = field(default_factory=list)  # (energy, power expression)
    extremes: list[tuple[str, str, str]] = field(default_factory=list)  # (name, expr, max|min)


def _param_local(effect: str, name: str) -> str:
    return f"p__{effect}__{name}"


def _table_global(effect: str, name: str) -> str:
    return f"T__{effect}__{name}"


def _function_global(effect: str, site: str) -> str:
    return f"fx__{effect}__{site}"


class _Writer:
    """Accumulates the step body and checks every name an effect reads."""

    def __init__(self, composition: Composition):
        self.comp = composition
        self.lines: list[str] = []
        self.available: set[str] = set(ALWAYS)
        self.read_inputs: list[str] = []
        self.trace: list[str] = []
        self.layout = Layout()
        self.channels = dict(INPUTS)
        for eff in composition.effects:
            for channel in eff.inputs:
                if channel.name in self.channels and self.channels[channel.name] != channel:
                    raise CompositionError(
                        f"Effect '{eff.name}' declares input '{channel.name}', which another "
                        "declaration already defines differently."
                    )
                self.channels[channel.name] = channel
        self.available |= set(self.channels)
        self.states = list(CORE_STATES)
        for eff in composition.effects:
            for state in eff.states:
                if state.name in self.available or state.name in self.states:
                    raise CompositionError(
                        f"State '{state.name}' of effect '{eff.name}' is already defined.")
                self.states.append(state.name)
        self.available |= set(self.states)

    def provide(self, names, who: str) -> None:
        for name in names:
            if name in self.available:
                raise CompositionError(
                    f"Signal '{name}' from {who} is already provided by another effect or the "
                    "model; every signal has exactly one provider."
                )
            self.available.add(name)
            if not name.endswith("_next") and name not in template.TEMPORARIES:
                self.trace.append(name)

    def arguments(self, eff: Effect, site: str, where: str) -> list[str]:
        params = {p.name for p in eff.params}
        tables = {t.name for t in eff.tables}
        args = []
        for arg in eff.calls[site].arguments:
            if arg in params:
                args.append(_param_local(eff.name, arg))
            elif arg in tables:
                args.append(_table_global(eff.name, arg))
            elif arg in self.available:
                args.append(arg)
                if arg in self.channels and arg not in self.read_inputs:
                    self.read_inputs.append(arg)
            else:
                known = sorted(params | tables | self.available)
                raise CompositionError(
                    f"Effect '{eff.name}' reads '{arg}', which is neither one of its parameters "
                    f"nor a signal available at {where}.{did_you_mean(arg, known)} Signals "
                    f"available there: {', '.join(sorted(self.available - set(ALWAYS)))}."
                )
        return args

    def call(self, eff: Effect, site: str, outputs: list[str], where: str) -> None:
        args = self.arguments(eff, site, where)
        fn = _function_global(eff.name, site)
        if (eff.name, site) not in self.layout.calls:
            self.layout.calls.append((eff.name, site))
        self.lines.append(f"{', '.join(outputs)} = {fn}({', '.join(args)})")
        self.provide(outputs, f"effect '{eff.name}'")

    def site(self, stage: template.Site) -> None:
        slot = SLOTS[stage.slot]
        eff = self.comp.slots.get(stage.slot)
        if eff is None:
            assert slot.none is not None, stage.slot
            names = slot.calls[stage.call]
            for name in names:
                self.lines.append(f"{name} = {float(slot.none[name])!r}")
            self.provide(names, f"the empty slot '{stage.slot}'")
            return
        outputs = list(eff.calls[stage.call].returns)
        if not stage.when:
            self.call(eff, stage.call, outputs, f"slot '{stage.slot}' ({stage.call})")
            return
        self.lines.append(f"if {stage.when}:")
        start = len(self.lines)
        self.call(eff, stage.call, outputs, f"slot '{stage.slot}' ({stage.call})")
        self.lines[start:] = ["    " + line for line in self.lines[start:]]
        self.lines.append("else:")
        for name in outputs:
            self.lines.append(f"    {name} = {float(slot.none[name])!r}")

    def sink(self, stage: template.SinkSum) -> None:
        sink = SINKS[stage.sink]
        terms = [sink.base] if sink.base else []
        for eff in self.comp.contributions.get(stage.sink, []):
            extra = list(eff.calls["main"].returns[1:])
            self.call(eff, "main", [eff.contribution_name] + extra, f"sink '{sink.name}'")
            terms.append(eff.contribution_name)
            if stage.sink == "road_force_n":
                self.layout.road_terms.append(eff.name)
            elif stage.sink == "dc_load_w":
                self.layout.load_terms.append(eff.name)
        self.lines.append(f"{sink.name} = {' + '.join(terms) if terms else '0.0'}")
        self.provide([sink.name], f"sink '{sink.name}'")

    def code(self, stage: template.Code) -> None:
        for line in textwrap.dedent(stage.text).strip("\n").splitlines():
            stripped = line.strip()
            if stripped.startswith("{") and stripped.endswith("}"):
                slot, site = stripped[1:-1].split(".")
                eff = self.comp.slots[slot]
                indent = line[: len(line) - len(line.lstrip())]
                outputs = list(eff.calls[site].returns)
                args = self.arguments(eff, site, f"slot '{slot}' ({site})")
                self.lines.append(f"{indent}{', '.join(outputs)} = "
                                  f"{_function_global(eff.name, site)}({', '.join(args)})")
            else:
                self.lines.append(line)
        self.provide(stage.provides, "the model skeleton")


def generate(comp: Composition) -> Layout:
    """Generate the kernel source for a composition; raise CompositionError if it is invalid."""
    w = _Writer(comp)
    for stage in template.STAGES:
        if isinstance(stage, template.Site):
            w.site(stage)
        elif isinstance(stage, template.SinkSum):
            w.sink(stage)
        else:
            w.code(stage)
    for term in w.layout.road_terms:
        w.lines.append(f"{term}_w = {term}_n * speed_mid_mps")
        w.provide([f"{term}_w"], "the model skeleton")
    for state in w.states:
        if state + "_next" not in w.available:
            raise CompositionError(f"No effect computes the next value of state '{state}'.")
    for name in ("speed_ref_mps", "accel_ref_mps2"):  # read by the skeleton
        if name not in w.read_inputs:
            w.read_inputs.append(name)

    layout = w.layout
    layout.states = w.states
    layout.inputs = [name for name in w.channels if name in w.read_inputs]
    layout.params = [(e.name, p.name) for e in comp.effects for p in e.params]
    layout.trace = layout.inputs + layout.states + [n for n in w.trace if n not in layout.inputs]

    # Energies the summary cannot derive from others (friction brakes, drivetrain loss, the
    # battery's terminal and chemical energy and the charger loss follow from these exactly).
    sums = [("traction", "max(motor_wheel_power_w, 0.0)"),
            ("regen_recovered", "max(-motor_wheel_power_w, 0.0)"),
            ("inertia", "inertia_w")]
    sums += [(term, f"{term}_w") for term in layout.road_terms]
    sums += [("motor", "motor_power_w")]
    sums += [(term, f"{term}_w") for term in layout.load_terms]
    sums += [("battery_ohmic_loss", "battery_loss_w"), ("coulombic_loss", "coulombic_loss_w"),
             ("battery_shortfall", "battery_shortfall_w"), ("charger", "charger_power_w"),
             ("grid", "grid_power_w")]
    extremes = [("peak_grid", "grid_power_w", "max"), ("soc_min", "soc_frac", "min"),
                ("max_behind", "distance_behind_m", "max")]
    layout.accumulators = [(n, "sum") for n, _ in sums] + [(n, m) for n, _, m in extremes]

    layout.body, layout.sums, layout.extremes = w.lines, sums, extremes
    layout.header = _header(comp, layout)
    layout.source = "\n".join(
        layout.header + _loop("run", layout, "plain") + _loop("run_record", layout, "record")
        + _loop("run_sample", layout, "sample")) + "\n"
    return layout


def _header(comp: Composition, layout: Layout) -> list[str]:
    out = [
        "# Generated by ebus_env.model.codegen: one model's compiled step loop. Do not edit.",
        "import math",
        "import numpy as np",
        "from ebus_env.model.codegen import bind as _bind",
        f"globals().update(_bind({layout.calls!r}, globals().get('_PYTHON_MODE', False)))",
        "",
    ]
    for (effect, name), encoded in comp.tables.items():
        values = ", ".join(repr(float(v)) for v in encoded)
        out.append(f"{_table_global(effect, name)} = np.array([{values}], dtype=np.float64)")
    return out


def _loop(name: str, layout: Layout, mode: str) -> list[str]:
    """The loop over buses and steps (``mode``: plain, record or sample). The recording variant
    keeps every signal live, which costs registers, so the others have no such code at all."""
    sums, extremes = layout.sums, layout.extremes
    out = [
        "",
        "",
        f"def {name}(params, states, inputs, input_set, step0, n_steps, dt_s, record_every, "
        "record_sel, record_out, sample_mask, acc, bus_lo, bus_hi):",
        f"    buf = np.empty({len(layout.trace)})",
        "    for b in range(bus_lo, bus_hi):",
        "        inp = inputs[input_set[b]]",
    ]
    ind3 = " " * 12
    if mode == "sample":
        out.append("        r = 0")
    for j, (effect, pname) in enumerate(layout.params):
        out.append(f"        {_param_local(effect, pname)} = params[b, {j}]")
    for j, state in enumerate(layout.states):
        out.append(f"        {state} = states[b, {j}]")
    energy_sums = [] if mode == "sample" else sums  # calibration needs no energies
    for j, _ in enumerate(energy_sums):
        out.append(f"        s{j} = 0.0")
    for j, _ in enumerate(extremes, start=len(sums)):
        out.append(f"        a{j} = acc[b, {j}]")
    out.append("        for k in range(n_steps[b]):")
    out.append(f"{ind3}row = step0[b] + k")
    out.append(f"{ind3}time_s = row * dt_s")
    for j, channel in enumerate(layout.inputs):
        out.append(f"{ind3}{channel} = inp[{j}, row]")
    out += [ind3 + line for line in layout.body]
    for j, (_, expr) in enumerate(energy_sums):
        out.append(f"{ind3}s{j} += {expr}")
    for j, (_, expr, how) in enumerate(extremes, start=len(sums)):
        out.append(f"{ind3}a{j} = {how}(a{j}, {expr})")
    if mode == "sample":
        out += [f"{ind3}if sample_mask[row]:",
                f"{ind3}    record_out[b, r, 0] = soc_frac",
                f"{ind3}    r += 1"]
    if mode == "record":
        out.append(f"{ind3}if k % record_every == 0:")
        for j, signal in enumerate(layout.trace):
            out.append(f"{ind3}    buf[{j}] = {signal}")
        out += [
            f"{ind3}    r = k // record_every",
            f"{ind3}    for j in range(record_sel.shape[0]):",
            f"{ind3}        record_out[b, r, j] = buf[record_sel[j]]",
        ]
    for state in layout.states:
        out.append(f"{ind3}{state} = {state}_next")
    for j, state in enumerate(layout.states):
        out.append(f"        states[b, {j}] = {state}")
    # sums of powers over steps become energies once, at the end: sum(P) dt
    for j, _ in enumerate(energy_sums):
        out.append(f"        acc[b, {j}] += s{j} * dt_s")
    for j, _ in enumerate(extremes, start=len(sums)):
        out.append(f"        acc[b, {j}] = a{j}")
    return out


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

    def __init__(self, rows: dict[str, int], params: dict[str, int]):
        self.at = {**{n: ("W", j) for n, j in rows.items()}, **{n: ("P", j) for n, j in params.items()}}

    def visit_Name(self, node: ast.Name):
        if node.id not in self.at:
            return node
        array, j = self.at[node.id]
        index = ast.Tuple([ast.Constant(j), ast.Name("g", ast.Load())], ast.Load())
        return ast.copy_location(ast.Subscript(ast.Name(array, ast.Load()), index, node.ctx), node)


def lane_source(layout: Layout, varying) -> str:
    """Source of the lane loops ``run_lanes`` and ``run_sample_lanes`` for buses whose
    parameters differ only in the columns ``varying`` (the others are read once, from the
    first bus)."""
    varying = sorted(set(varying))
    return "\n".join(
        layout.header + [f"# lane loops: parameters that differ between lanes: {varying}"]
        + _lane_loop("run_lanes", layout, "plain", varying)
        + _lane_loop("run_sample_lanes", layout, "sample", varying)) + "\n"


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
    locals_ = [_param_local(e, p) for e, p in layout.params]
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
    for st in placed["call"]:
        out += lane(st, "    ")
    out += [
        "    for c in range(bus_lo, bus_hi, lanes):",
        f"{i2}{g}",
        f"{i3}b = min(c + g, bus_hi - 1)",
    ]
    out += [f"{i3}P[{i}, g] = params[b, {j}]" for i, j in enumerate(varying)]
    out += [f"{i3}W[{rows[s]}, g] = states[b, {j}]" for j, s in enumerate(layout.states)]
    out += [f"{i3}S[{j}, g] = 0.0" for j in summed]
    out += [f"{i3}S[{j}, g] = acc[b, {j}]" for j in range(n_sum, n_acc)]
    for st in placed["group"]:
        out += [f"{i2}{g}"] + lane(st, i3)
    out += [f"{i2}r = 0"] if mode == "sample" else []
    out += [f"{i2}for k in range(n_steps[bus_lo]):",
            f"{i3}row = step0[bus_lo] + k",
            f"{i3}time_s = row * dt_s"]
    out += [f"{i3}{ch} = inp[{j}, row]" for j, ch in enumerate(layout.inputs)]
    for st in placed["step"]:
        out += lane(st, i3)
    for st in each:
        out += [f"{i3}{g}"] + lane(st, i4)
    if mode == "sample":
        out += [f"{i3}if sample_mask[row]:",
                f"{i4}for g in range(min(lanes, bus_hi - c)):",
                f"{i5}record_out[c + g, r, 0] = W[{rows['soc_frac']}, g]",
                f"{i4}r += 1"]
    for st in advance:
        out += [f"{i3}{g}"] + lane(st, i4)
    out += [f"{i2}for g in range(min(lanes, bus_hi - c)):", f"{i3}b = c + g"]
    out += [f"{i3}states[b, {j}] = W[{rows[s]}, g]" for j, s in enumerate(layout.states)]
    out += [f"{i3}acc[b, {j}] += S[{j}, g] * dt_s" for j in summed]
    out += [f"{i3}acc[b, {j}] = S[{j}, g]" for j in range(n_sum, n_acc)]
    return out


# -- binding and compilation --------------------------------------------------------------
_EFFECTS_BY_NAME: dict[str, Effect] = {}
_LOCK = threading.Lock()


def bind(calls, python: bool) -> dict:
    """Globals of a generated module: effect functions (compiled or plain) and helpers."""
    names = {}
    for effect_name, site in calls:
        eff = _EFFECTS_BY_NAME[effect_name]
        fn = eff.calls[site].function if python else eff.jitted(site)
        names[_function_global(effect_name, site)] = fn
    names["_move"] = template.move.py_func if python else template.move
    return names


def _library_fingerprint() -> str:
    """Hash of the library code a kernel depends on (effects, tables, template)."""
    root = Path(__file__).resolve().parent.parent
    h = hashlib.sha256()
    for path in sorted(list((root / "effects").glob("*.py")) + list((root / "model").glob("*.py"))):
        h.update(path.read_bytes())
    h.update(f"{numba.__version__} {np.__version__} {sys.version}".encode())
    return h.hexdigest()


_FINGERPRINT: str | None = None


def kernel_key(comp: Composition, source: str) -> str:
    """Cache key: the source, every effect's source file and the library fingerprint."""
    global _FINGERPRINT
    if _FINGERPRINT is None:
        _FINGERPRINT = _library_fingerprint()
    h = hashlib.sha256(source.encode())
    h.update(_FINGERPRINT.encode())
    for eff in comp.effects:
        for path in sorted(eff.source_files):
            h.update(Path(path).read_bytes())
        for call in eff.calls.values():
            h.update(inspect.getsource(call.function).encode())
    return h.hexdigest()[:20]


def cache_dir() -> Path:
    """Directory of generated kernels (``$EBUS_CACHE_DIR`` or ``~/.cache/ebus_env/kernels``)."""
    default = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "ebus_env"
    path = Path(os.environ.get("EBUS_CACHE_DIR", default)) / "kernels"
    path.mkdir(parents=True, exist_ok=True)
    return path


def _register_effects(comp: Composition) -> None:
    # a generated module binds its effect functions by name when it is imported
    for eff in comp.effects:
        _EFFECTS_BY_NAME[eff.name] = eff


def compile_kernel(comp: Composition, layout: Layout):
    """Import the generated module with its loops jitted (``run_compiled``,
    ``run_record_compiled``, ``run_sample_compiled``); each compiles, or loads from the disk
    cache, on first call."""
    return _compile(comp, layout.source, ("run", "run_record", "run_sample"))


def compile_lanes(comp: Composition, layout: Layout, varying):
    """The lane loops for parameters that differ in the columns ``varying`` (:func:`lane_source`),
    jitted as ``run_lanes_compiled`` and ``run_sample_lanes_compiled``."""
    return _compile(comp, lane_source(layout, varying), ("run_lanes", "run_sample_lanes"))


def _compile(comp: Composition, source: str, names):
    key = kernel_key(comp, source)
    with _LOCK:
        _register_effects(comp)
        module_name = f"ebus_kernel_{key}"
        if module_name in sys.modules:
            return sys.modules[module_name]
        path = cache_dir() / f"{module_name}.py"
        if not path.exists() or path.read_text() != source:
            tmp = path.with_suffix(f".{os.getpid()}.tmp")
            tmp.write_text(source)
            os.replace(tmp, path)
        spec = importlib.util.spec_from_file_location(module_name, path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        for name in names:
            jitted = numba.njit(cache=True, nogil=True, error_model="numpy")(getattr(module, name))
            setattr(module, name + "_compiled", jitted)
        sys.modules[module_name] = module
        return module


def python_kernel(comp: Composition, layout: Layout):
    """The same loops as plain Python (effects uncompiled): slow, for tests and debugging."""
    _register_effects(comp)
    namespace = {"_PYTHON_MODE": True, "__name__": "ebus_kernel_python"}
    exec(compile(layout.source, "<ebus kernel (python)>", "exec"), namespace)
    return {name: namespace[name] for name in ("run", "run_record", "run_sample")}
