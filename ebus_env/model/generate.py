"""Generate the source of a model's step loop.

The chosen effects are stitched into the skeleton of :mod:`ebus_env.model.template` as one flat
Python function that loops over buses and time steps. Effect functions are called by name with
their parameters unpacked into locals, so numba compiles (and inlines) everything into one
machine-code loop: a user's effect runs at the same speed as a built-in one. Three variants are
generated from the same step: ``run`` (no recording: nothing beyond the states and energy sums
stays live, which keeps the loop in registers), ``run_record`` (keeps a trace) and ``run_sample``
(calibration: only the SoC at the rows a log has samples, no energy sums); :mod:`.lanes`
rewrites the step for many buses at a time in SIMD lanes, and :mod:`.kernels` binds the effect
functions, compiles and caches.

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

import math
import textwrap
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from ebus_env.effects.base import Effect
from ebus_env.errors import CompositionError, did_you_mean
from ebus_env.model import template
from ebus_env.signals import ALWAYS, CORE_STATES, INPUTS, SINKS, SLOTS


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


def param_local(effect: str, name: str) -> str:
    """The local variable holding parameter ``name`` of ``effect`` in the generated loop."""
    return f"p__{effect}__{name}"


def _literal(value: float) -> str:
    """A float as generated source: ``math.inf`` for "no limit", else its repr."""
    value = float(value)
    if value in (math.inf, -math.inf):
        return f"{'-' if value < 0 else ''}math.inf"
    return repr(value)


def _table_global(effect: str, name: str) -> str:
    return f"T__{effect}__{name}"


def function_global(effect: str, site: str) -> str:
    """The module global the generated loop calls for call ``site`` of ``effect``."""
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

    def provide(self, names: Iterable[str], who: str) -> None:
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
                args.append(param_local(eff.name, arg))
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
        fn = function_global(eff.name, site)
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
                self.lines.append(f"{name} = {_literal(slot.none[name])}")
            self.provide(names, f"the empty slot '{stage.slot}'")
            return
        if stage.call not in eff.calls:  # an optional call site this effect has no use for
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
        assert slot.none is not None, stage.slot  # a conditional call needs the pass-through
        for name in outputs:
            self.lines.append(f"    {name} = {_literal(slot.none[name])}")

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
                assert eff is not None, slot  # the skeleton re-calls only slots that cannot be empty
                indent = line[: len(line) - len(line.lstrip())]
                outputs = list(eff.calls[site].returns)
                args = self.arguments(eff, site, f"slot '{slot}' ({site})")
                self.lines.append(f"{indent}{', '.join(outputs)} = "
                                  f"{function_global(eff.name, site)}({', '.join(args)})")
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
    # what the pack could not deliver: beyond its maximum power, and the loads of an empty pack
    sums += [("battery_ohmic_loss", "battery_loss_w"), ("coulombic_loss", "coulombic_loss_w"),
             ("battery_shortfall", "battery_shortfall_w + unserved_load_w"),
             ("charger", "charger_power_w"), ("grid", "grid_power_w"),
             ("battery_limited", "battery_limited"), ("stranded", "stranded")]  # -> seconds
    # the first stranded step: its time [s] and distance [m] (distance never decreases)
    extremes = [("peak_grid", "grid_power_w", "max"), ("soc_min", "soc_frac", "min"),
                ("max_behind", "distance_behind_m", "max"),
                ("stranded_at", "time_s if stranded > 0.0 else math.inf", "min"),
                ("stranded_at_m", "distance_m if stranded > 0.0 else math.inf", "min")]
    layout.accumulators = [(n, "sum") for n, _ in sums] + [(n, m) for n, _, m in extremes]

    layout.body, layout.sums, layout.extremes = w.lines, sums, extremes
    layout.header = _header(comp, layout)
    layout.source = "\n".join(
        layout.header + _loop("run", layout, "plain") + _loop("run_record", layout, "record")
        + _loop("run_sample", layout, "sample")) + "\n"
    return layout


def _header(comp: Composition, layout: Layout) -> list[str]:
    out = [
        "# Generated by ebus_env.model.generate: one model's compiled step loop. Do not edit.",
        "# The loader (ebus_env.model.kernels) sets the effect functions fx__<effect>__<call>",
        f"# and _move before this module runs: {layout.calls!r}",
        "import math",
        "import numpy as np",
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
        out.append(f"        {param_local(effect, pname)} = params[b, {j}]")
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
