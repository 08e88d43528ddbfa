"""A built model: chosen effects, parameter values and the compiled step loop.

Build one with :func:`build_model` (or from a bus config, :func:`ebus_env.config.load_bus`), then::

    result = model.simulate(profile, soc_start=0.95)        # one bus, with a 10 Hz trace
    batch = model.simulate_batch(profile, params_matrix)    # N parameter sets at once
    model.run(params, states, inputs, ...)                  # N buses, k steps, from a saved state

All three go through the same compiled kernel (:mod:`ebus_env.model.generate`,
:mod:`~ebus_env.model.lanes`, :mod:`~ebus_env.model.kernels`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Collection, Mapping, Sequence
from numbers import Integral
from types import ModuleType
from typing import TYPE_CHECKING, SupportsFloat

import numpy as np

from ebus_env.effects.base import Effect, Param, get_effect
from ebus_env.effects.compile_errors import explain
from ebus_env.effects.tables import TableValue
from ebus_env.errors import CompositionError, ConfigError, EbusError, unknown_name
from ebus_env.model.generate import Composition, generate
from ebus_env.model.kernels import compile_kernel, compile_lanes, lanes_compiled, python_kernel
from ebus_env.model.lanes import LANES_MIN
from ebus_env.model.threads import default_threads, run_chunks
from ebus_env.profile import Profile
from ebus_env.signals import HANDLES, SINKS, SLOTS

if TYPE_CHECKING:
    from ebus_env.model.results import BatchResult, SimulationResult


def _resolve(item: str | Effect) -> Effect:
    return item if isinstance(item, Effect) else get_effect(item)


class Model:
    """A compiled Lo-Fi bus model (use :func:`build_model` to make one)."""

    def __init__(self, composition: Composition, values: Mapping[str, float],
                 bounds: Mapping[str, tuple[float, float]], dt_s: float, name: str = ""):
        self.composition = composition
        self.layout = generate(composition)
        self.dt_s = float(dt_s)
        self.name = name
        self._effects = {e.name: e for e in composition.effects}
        self.param_names = [f"{e}.{p}" for e, p in self.layout.params]
        self._param_index = {n: i for i, n in enumerate(self.param_names)}
        self._declared: dict[str, Param] = {
            f"{e}.{p}": self._effects[e].param(p) for e, p in self.layout.params}
        self.bounds = np.array([bounds.get(n, self._declared[n].bounds) for n in self.param_names],
                               dtype=float).reshape(-1, 2)
        self.params = np.array([values.get(n, self._declared[n].default) for n in self.param_names],
                               dtype=float)
        self._counts = np.array([i for i, n in enumerate(self.param_names)
                                 if self._declared[n].whole], dtype=int)  # Param.whole
        self._check_in_bounds(self.params, "the model's configured value")
        self._kernel: ModuleType | None = None
        # varying parameter columns -> module of the lane loops
        self._lane_kernels: dict[frozenset[int], ModuleType] = {}
        # varying parameter columns -> compiled in an earlier process
        self._lanes_cached: dict[frozenset[int], bool] = {}
        self._python_kernel: dict[str, Callable] | None = None

    # -- description ------------------------------------------------------------------------
    @property
    def effects(self) -> list[Effect]:
        return self.composition.effects

    @property
    def input_names(self) -> list[str]:
        return self.layout.inputs

    @property
    def state_names(self) -> list[str]:
        return self.layout.states

    @property
    def trace_names(self) -> list[str]:
        return self.layout.trace

    @property
    def accumulator_names(self) -> list[str]:
        return [n for n, _ in self.layout.accumulators]

    def has_effect(self, name: str) -> bool:
        return name in self._effects

    def equivalent(self, name: str) -> str | None:
        """This model's parameter that plays the role of ``name`` (``effect.param``): the
        same one, or the same-named parameter of the effect that fills the slot of ``name``'s
        effect (``regen_soc_limit.cutoff_speed_mps`` for ``regen_cutoff.cutoff_speed_mps``)."""
        if name in self._param_index:
            return name
        effect_name, _, short = name.partition(".")
        try:
            original = get_effect(effect_name)
        except EbusError:
            return None
        current = self.composition.slots.get(original.slot) if original.slot else None
        same = f"{current.name}.{short}" if current is not None else ""
        return same if same in self._param_index else None

    def carry_over(self, values: Mapping[str, float]) -> dict[str, float]:
        """``values`` by qualified name, renamed to this model's equivalents (see
        :meth:`equivalent`); those without one are dropped."""
        out = {}
        for name, value in values.items():
            mine = self.equivalent(name)
            if mine is not None:
                out[mine] = value
        return out

    def param_info(self, name: str) -> Param:
        """Declaration of a parameter by qualified name (``effect.param``)."""
        if name not in self._declared:
            raise unknown_name("parameter", name, self.param_names)
        return self._declared[name]

    def param_index(self, name: str) -> int:
        if name not in self._param_index:
            raise unknown_name("parameter", name, self.param_names,
                               listed_by="`ebus effects --bus NAME`")
        return self._param_index[name]

    def handle(self, name: str) -> int:
        """Column of ``params`` of the parameter this model's effects offer as handle ``name``
        (:data:`ebus_env.signals.HANDLES`, e.g. ``charge_pulse_duty``); a clear error when no
        effect, or more than one, offers it."""
        if name not in HANDLES:
            raise unknown_name("handle", name, HANDLES)
        offers = [f"{e.name}.{e.handles[name]}" for e in self.effects if name in e.handles]
        if len(offers) != 1:
            h = HANDLES[name]
            raise CompositionError(
                f"Model '{self.name}': {len(offers) or 'no'} effects offer the {h.description} "
                f"(handle '{name}'{': ' + ', '.join(offers) if offers else ''}); exactly one "
                f"must, e.g. {h.provider}, or an effect of yours declaring handles={{'{name}': "
                "'<its parameter>'}.")
        return self._param_index[offers[0]]

    # -- parameters -------------------------------------------------------------------------
    def _check_in_bounds(self, values: np.ndarray, what: str) -> None:
        """Every value inside its bounds, and a count (``Param.whole``) a whole number."""
        low, high = self.bounds[:, 0], self.bounds[:, 1]
        bad = np.flatnonzero(~((values >= low) & (values <= high)))
        if bad.size:
            i = bad[0]
            raise ConfigError(
                f"Parameter '{self.param_names[i]}' = {values[i]} ({what}) lies outside its "
                f"bounds [{low[i]}, {high[i]}] {self._declared[self.param_names[i]].unit}."
            )
        for i in self._counts[values[self._counts] != np.round(values[self._counts])]:
            raise ConfigError(f"Parameter '{self.param_names[i]}' = {values[i]} ({what}) is a "
                              "count: give a whole number.")

    def checked_vector(self, params: Mapping[str, float] | np.ndarray | None) -> np.ndarray:
        """A full parameter vector from overrides by name (:meth:`param_vector`) or a vector
        given whole: one value per ``param_names``, each finite and inside its bounds."""
        if params is None or isinstance(params, Mapping):
            return self.param_vector(params)
        if not isinstance(params, np.ndarray):
            raise ConfigError(f"params: give a mapping of qualified names to values "
                              f"({{'aero_drag.drag_coef': 0.6}}) or a numpy vector of "
                              f"{len(self.param_names)} values in model.param_names' order, not "
                              f"a {type(params).__name__}.")
        vec = np.asarray(params, dtype=float)
        if vec.shape != (len(self.param_names),):
            raise ConfigError(f"params: a vector of shape {vec.shape}; the model has "
                              f"{len(self.param_names)} parameters (model.param_names).")
        self._check_in_bounds(vec, "params vector")
        return vec

    def param_vector(self, overrides: Mapping[str, float] | None = None) -> np.ndarray:
        """The model's parameter values with ``overrides`` (qualified names) applied."""
        vec = self.params.copy()
        for name, value in (overrides or {}).items():
            vec[self.param_index(name)] = float(value)
        self._check_in_bounds(vec, "override")
        return vec

    def param_matrix(self, rows: Sequence[Mapping[str, float]] | np.ndarray) -> np.ndarray:
        """(N, n_params) matrix from a list of override mappings, or a checked copy of one."""
        if len(rows) == 0:
            raise ConfigError("params: no parameter sets; give one mapping (or matrix row) per "
                              "bus to run.")
        if isinstance(rows, np.ndarray):
            matrix = np.array(rows, dtype=float, ndmin=2)
            if matrix.ndim != 2 or matrix.shape[1] != len(self.param_names):
                raise ConfigError(
                    f"Parameter matrix of shape {matrix.shape}; the model has "
                    f"{len(self.param_names)} parameters (see model.param_names).")
            for row in matrix:
                self._check_in_bounds(row, "batch row")
            return matrix
        return np.array([self.param_vector(r) for r in rows], dtype=float)

    # -- inputs and states ------------------------------------------------------------------
    def input_array(self, profile: Profile) -> np.ndarray:
        """(n_inputs, n_steps) input array of a profile, channels in ``input_names`` order."""
        if not isinstance(profile, Profile):
            raise ConfigError(f"A run needs a Profile (service_day(...), or load_log(...).profile "
                              f"/ .profiles), not a {type(profile).__name__}.")
        if abs(profile.dt_s - self.dt_s) > 1e-12:
            raise ConfigError(
                f"Profile '{profile.name}' is on a {profile.dt_s} s grid but the model steps "
                f"{self.dt_s} s; build the profile with dt_s={self.dt_s}.")
        if not np.all(np.isfinite(profile.channels["speed_ref_mps"])):
            raise ConfigError(f"Profile '{profile.name}': reference speed has NaN values.")
        return profile.stacked(tuple(self.input_names))

    def initial_state(self, params: np.ndarray, first_inputs: Mapping[str, float],
                      soc_start: float | None = None, **overrides: float) -> np.ndarray:
        """State vector at the start of a run.

        Speed starts at the reference speed, distances at 0, effect states at their declared
        initial values (e.g. the cabin preconditioned to its setpoint); ``soc_start`` [0-1] and
        any ``state_name=value`` override them.
        """
        own: dict[str, dict[str, float]] = {}
        for (effect, name), value in zip(self.layout.params, params, strict=True):
            own.setdefault(effect, {})[name] = float(value)
        values = {"speed_mps": float(first_inputs.get("speed_ref_mps", 0.0)),
                  "distance_m": 0.0, "distance_ref_m": 0.0}
        for eff in self.effects:
            for state in eff.states:
                values[state.name] = float(state.initial(own.get(eff.name, {}), first_inputs))
        if soc_start is not None:
            overrides["soc_frac"] = checked_soc(soc_start)
        for name, value in overrides.items():
            if name not in values:
                raise unknown_name("state", name, values)
            values[name] = float(value)
        return np.array([values[n] for n in self.state_names], dtype=float)

    def measured_states(self, profile: Profile) -> dict[str, float]:
        """Initial states the log measured (``cabin_temp_degc``...): each state other than SoC
        that the profile has as a measured signal, at its first finite value."""
        out = {}
        for name in self.state_names:
            values = profile.measured.get(name)
            if name != "soc_frac" and values is not None and np.isfinite(values).any():
                out[name] = float(values[np.flatnonzero(np.isfinite(values))[0]])
        return out

    def new_accumulators(self, n_bus: int) -> np.ndarray:
        """Zeroed accumulators (sums 0, maxima -inf, minima +inf) for ``n_bus`` buses."""
        start = {"sum": 0.0, "max": -math.inf, "min": math.inf}
        row = [start[mode] for _, mode in self.layout.accumulators]
        return np.tile(np.array(row, dtype=float), (n_bus, 1))

    # -- running ----------------------------------------------------------------------------
    def kernel(self, variant: str = "run", varying: Collection[int] | None = None
               ) -> Callable[..., None]:
        """A compiled loop: ``run``, ``run_record``, ``run_sample``, ``run_lanes`` or
        ``run_sample_lanes`` (compiled, or loaded from the disk cache, on first call). The lane
        loops are made for the parameter columns ``varying`` that differ between the buses (the
        others are taken from the first bus; default: all columns differ)."""
        if variant.endswith("_lanes"):
            columns = frozenset(range(len(self.params)) if varying is None else varying)
            if columns not in self._lane_kernels:
                self._lane_kernels[columns] = compile_lanes(self.composition, self.layout,
                                                                    columns)
            return getattr(self._lane_kernels[columns], variant + "_compiled")
        if self._kernel is None:
            self._kernel = compile_kernel(self.composition, self.layout)
        return getattr(self._kernel, variant + "_compiled")

    def varying_columns(self, params: np.ndarray) -> frozenset[int]:
        """The parameter columns a lane loop for ``params`` reads per bus: those where any row
        differs from the first, or the smallest set of a lane loop already compiled that holds
        them (saves a compile)."""
        columns = differing_columns(params)
        ready = [c for c in self._lane_kernels if columns <= c]
        return min(ready, key=len) if ready else columns

    def lanes_ready(self, params: np.ndarray) -> bool:
        """Whether the lane loop a batch of ``params`` would run in is compiled already (in
        this process, or in the disk cache by an earlier one): then lanes cost nothing to
        start."""
        columns = self.varying_columns(params)
        if columns in self._lane_kernels:
            return True
        if columns not in self._lanes_cached:
            self._lanes_cached[columns] = lanes_compiled(self.composition, self.layout, columns)
        return self._lanes_cached[columns]

    def compile(self, record: bool = False, sample: bool = False, lanes: bool = False,
                params: np.ndarray | None = None) -> float:
        """Compile now (or load from the disk cache) the loop a run with these options uses;
        returns the seconds it took. ``lanes``: the SIMD lane loop (about 12 s per model and
        set of differing parameters on an empty cache) for the parameter sets ``params``
        (default: all the model's own)."""
        t0 = time.perf_counter()
        n_bus = LANES_MIN if lanes else 1  # enough buses for run() to choose lanes
        matrix = self.params[None, :] if params is None else params
        varying = self.varying_columns(matrix) if lanes else None
        args = (np.repeat(self.params[None, :], n_bus, axis=0),
                np.repeat(self.initial_state(self.params, {})[None, :], n_bus, axis=0),
                np.zeros((1, len(self.input_names), 2)))
        trace = np.zeros((n_bus, 1, len(self.trace_names)), np.float32) if record else None
        self.run(*args, n_steps=1, record_every=1 if record else 0, record_out=trace, threads=1,
                 lanes=lanes, varying=varying)
        if sample:
            self.run(*args, n_steps=1, sample_mask=np.ones(2, bool),
                     record_out=np.zeros((n_bus, 1, 1), np.float32), threads=1, lanes=lanes,
                     varying=varying)
        return time.perf_counter() - t0

    def run(self, params: np.ndarray, states: np.ndarray, inputs: np.ndarray,
            input_set: np.ndarray | None = None, step0: np.ndarray | None = None,
            n_steps: int | np.ndarray | None = None, record_every: int = 0,
            record_sel: np.ndarray | None = None, record_out: np.ndarray | None = None,
            acc: np.ndarray | None = None, sample_mask: np.ndarray | None = None,
            threads: int | None = None, python: bool = False, lanes: bool = False,
            varying: Collection[int] | None = None) -> np.ndarray:
        """Advance N buses by ``n_steps`` from ``states`` (updated in place).

        Parameters
        ----------
        params : (N, n_params)
        states : (N, n_states)
        inputs : (n_inputs, n_rows) shared by all buses, or (n_sets, n_inputs, n_rows)
        input_set : (N,) which input set each bus reads (default: 0)
        step0 : (N,) first input row of each bus (default: 0)
        n_steps : steps to advance, one count for all buses or (N,) per bus (default: all
            rows after ``step0``)
        record_every, record_sel, record_out : trace recording (see :mod:`ebus_env.model.generate`)
        acc : (N, n_acc) accumulators to add to (default: new ones)
        sample_mask : (n_rows,) bool: record only ``soc_frac`` at these rows, into
            ``record_out[:, :, 0]``, and skip the energy sums (calibration)
        threads : split the buses over this many threads (default: all CPUs, when the run has
            at least 50,000 bus-steps)
        python : run the uncompiled Python version of the same code
        lanes : when all buses read the same input rows (a batch of parameter sets) and each
            thread has at least ``LANES_MIN`` of them, advance them in groups with the
            SIMD lane kernel (``run_lanes``, ``run_sample_lanes``: the same results to the last
            bit, about half the time with 64 to 550 buses when a few parameters differ). Off by
            default: it compiles on first use (about 12 s per model and set of differing
            parameters, then cached on disk), which pays for repeated or large runs only
        varying : the parameter columns the lane loop reads per bus (default:
            :meth:`varying_columns` of ``params``); the others it reads from the first bus

        Returns
        -------
        acc : (N, n_acc)
        """
        n_bus = params.shape[0]
        inputs = inputs[None] if inputs.ndim == 2 else inputs
        input_set = np.zeros(n_bus, np.int64) if input_set is None else np.asarray(input_set, np.int64)
        step0 = np.zeros(n_bus, np.int64) if step0 is None else np.asarray(step0, np.int64)
        if n_steps is None:
            n_steps = int(inputs.shape[2] - step0.max())
        steps = np.broadcast_to(np.asarray(n_steps, np.int64), (n_bus,)).copy()
        bad = (steps < 0) | (step0 < 0) | (step0 + steps > inputs.shape[2])
        if bad.any():
            b = int(np.flatnonzero(bad)[0])
            raise ValueError(f"Bus {b}: rows {step0[b]}..{step0[b] + steps[b]} (step0 + n_steps) lie "
                             f"outside the {inputs.shape[2]} input rows.")
        n_steps = int(steps.max()) if n_bus else 0
        if states.shape != (n_bus, len(self.state_names)):
            raise ValueError(f"states must have shape ({n_bus}, {len(self.state_names)}).")
        if inputs.shape[1] != len(self.input_names):
            raise ValueError(f"inputs must have {len(self.input_names)} channels: {self.input_names}.")
        if acc is None:
            acc = self.new_accumulators(n_bus)
        if record_sel is None:
            record_sel = np.arange(len(self.trace_names), dtype=np.int64)
        if record_out is None:
            record_out = np.zeros((n_bus, 0, len(record_sel)), np.float32)
        if record_every > 0 and record_out.shape[1] < -(-n_steps // record_every):
            raise ValueError("record_out has too few rows for n_steps / record_every.")
        variant = "run_record" if record_every > 0 else "run"
        if sample_mask is None:
            sample_mask = np.zeros(1, np.bool_)
        else:
            variant = "run_sample"
            sample_mask = np.asarray(sample_mask, np.bool_)
            rows = int(sample_mask[int(step0.min()):int(step0.max()) + n_steps].sum())
            if sample_mask.shape[0] < inputs.shape[2] or record_out.shape[1] < rows:
                raise ValueError("sample_mask needs one flag per input row and record_out one "
                                 "row per flagged row in the run.")
        params = np.ascontiguousarray(params, dtype=float)
        args = (params, states, inputs, input_set, step0, steps, self.dt_s,
                int(record_every), np.asarray(record_sel, np.int64), record_out, sample_mask, acc)
        if python:
            if self._python_kernel is None:
                self._python_kernel = python_kernel(self.composition, self.layout)
            self._python_kernel[variant](*args, 0, n_bus)
            return acc
        kernel = self.kernel(variant)
        threads = default_threads() if threads is None else max(1, threads)
        # split the buses over threads when there is enough work to pay for the hand-off
        threads = min(threads, n_bus) if steps.sum() >= 50_000 else 1
        edges = np.linspace(0, n_bus, threads + 1).astype(int).tolist()
        if lanes and variant != "run_record" and self._shared_rows(input_set, step0, steps, edges):
            # groups of buses in SIMD lanes
            if varying is None:
                varying = self.varying_columns(params)
            elif not differing_columns(params) <= set(varying):
                raise ValueError(f"varying = {sorted(varying)} misses parameter columns that "
                                 f"differ between the buses: give at least "
                                 f"{sorted(differing_columns(params))}, or leave it out.")
            kernel = self.kernel(variant + "_lanes", varying)
        try:
            run_chunks(lambda lo, hi: kernel(*args, lo, hi), edges)
        except Exception as exc:  # a user's effect numba cannot compile: say which and why
            explained = explain(exc, self.effects)
            if explained is None:
                raise
            raise explained from exc
        return acc

    @staticmethod
    def _shared_rows(input_set: np.ndarray, step0: np.ndarray, steps: np.ndarray,
                     edges: list[int]) -> bool:
        """Whether the lane kernel applies: every bus reads the same input rows and each
        thread has at least ``LANES_MIN`` buses."""
        return bool(min(np.diff(edges)) >= LANES_MIN and (input_set == input_set[0]).all()
                    and (step0 == step0[0]).all() and (steps == steps[0]).all())

    def _first_inputs(self, inputs: np.ndarray) -> dict[str, float]:
        return dict(zip(self.input_names, inputs[:, 0], strict=True))

    def simulate(self, profile: Profile, params: Mapping[str, float] | np.ndarray | None = None,
                 soc_start: float | None = None, record: bool = True, record_every: int = 1,
                 python: bool = False, **initial: float) -> SimulationResult:
        """Run one bus through a profile.

        Parameters
        ----------
        profile
            The inputs, on this model's time step.
        params
            Overrides by qualified name, or a full parameter vector.
        soc_start
            Initial SoC [0-1]; default: the first measured SoC of the profile, else 0.9.
        record
            Keep the trace of every signal (every ``record_every`` steps).
        initial
            Other initial states by name (``cabin_temp_degc=5.0``); default: those the profile
            measured (:meth:`measured_states`), else the effects' own.
        """
        from ebus_env.model.results import SimulationResult

        vec = self.checked_vector(params)
        if record:
            _check_record_every(record_every)
        inputs = self.input_array(profile)
        if soc_start is None:
            soc_start = _first_measured_soc(profile)
        initial = {**self.measured_states(profile), **initial}
        state = self.initial_state(vec, self._first_inputs(inputs), soc_start, **initial)
        states = state[None, :].copy()
        n = inputs.shape[1]
        record_out = None
        if record:
            record_out = np.zeros((1, -(-n // record_every), len(self.trace_names)), np.float32)
        if not python:
            self.compile(record=record)  # the wall time is the run's, not the JIT's
        t0 = time.perf_counter()
        acc = self.run(vec[None, :], states, inputs, record_every=record_every if record else 0,
                       record_out=record_out, python=python)
        wall = time.perf_counter() - t0
        self._check_finite(acc[0], profile)
        trace = record_out[0] if record_out is not None else None
        return SimulationResult(self, profile, vec, state, states[0], acc[0], trace,
                                record_every, wall)

    def _check_finite(self, acc: np.ndarray, profile: Profile) -> None:
        """A run whose energies are NaN or infinite is no result: say where it went wrong
        (an effect's power, named by its term, or the pack's)."""
        # extremes start at +-inf and stay there when nothing set them (never stranded)
        bad = [name for (name, how), value in zip(self.layout.accumulators, acc, strict=True)
               if math.isnan(value) or (how == "sum" and math.isinf(value))]
        if bad:
            raise EbusError(
                f"The run through '{profile.name}' produced NaN or infinite values in: "
                f"{', '.join(bad)}. An effect returned NaN or inf for this run's inputs (a "
                "division by zero, the square root or log of a negative number...). Fix: "
                "guard that effect's arithmetic, or check its parameters.")

    def simulate_batch(self, profile: Profile, params: Sequence[Mapping[str, float]] | np.ndarray,
                       soc_start: float | None = None, record: Sequence[str] = (),
                       record_every: int = 10, threads: int | None = None,
                       lanes: bool = False) -> BatchResult:
        """Run N parameter sets through the same profile in one batched call.

        ``params`` is an (N, n_params) matrix or a list of override mappings. ``record`` names
        trace signals to keep (every ``record_every`` steps), e.g. ``["soc_frac"]``. ``lanes``:
        see :meth:`run`.
        """
        from ebus_env.model.results import BatchResult

        matrix = self.param_matrix(params)
        inputs = self.input_array(profile)
        if soc_start is None:
            soc_start = _first_measured_soc(profile)
        first = self._first_inputs(inputs)
        measured = self.measured_states(profile)
        states0 = np.array([self.initial_state(row, first, soc_start, **measured)
                            for row in matrix])
        states = states0.copy()
        for name in record:
            if name not in self.trace_names:
                raise unknown_name("trace signal", name, self.trace_names, "model.trace_names")
        if len(record):
            _check_record_every(record_every)
        sel = np.array([self.trace_names.index(n) for n in record], dtype=np.int64)
        n = inputs.shape[1]
        out = np.zeros((len(matrix), -(-n // record_every) if len(sel) else 0, len(sel)), np.float32)
        # the wall time is the run's, not the JIT's
        self.compile(record=len(sel) > 0, lanes=lanes and len(matrix) >= LANES_MIN,
                     params=matrix)
        t0 = time.perf_counter()
        acc = self.run(matrix, states, inputs, record_every=record_every if len(sel) else 0,
                       record_sel=sel, record_out=out, threads=threads, lanes=lanes)
        wall = time.perf_counter() - t0
        return BatchResult(self, profile, matrix, states0, states, acc, list(record), out,
                           record_every, wall)


def differing_columns(params: np.ndarray) -> frozenset[int]:
    """Columns where any row differs from the first, bit for bit (-0.0 and NaN differ too)."""
    bits = np.ascontiguousarray(params, dtype=float).view(np.int64)
    return frozenset(np.flatnonzero((bits != bits[:1]).any(axis=0)).tolist())


def checked_soc(soc_start: SupportsFloat | str) -> float:
    """A starting SoC as a fraction in [0, 1], or an error that says so (95 is 0.95)."""
    try:
        value = float(soc_start)
    except (TypeError, ValueError):
        raise ConfigError(f"soc_start = {soc_start!r}: give the SoC as a fraction in [0, 1]."
                          ) from None
    if isinstance(soc_start, bool) or not 0.0 <= value <= 1.0:  # NaN fails too
        hint = f" Did you mean {value / 100:g} ({value:g} %)?" if 1.0 < value <= 100.0 else ""
        raise ConfigError(f"soc_start = {soc_start!r}: give the SoC as a fraction in [0, 1]."
                          f"{hint}")
    return value


def _check_record_every(record_every: object) -> None:
    if isinstance(record_every, bool) or not isinstance(record_every, Integral) \
            or record_every < 1:
        raise ConfigError(f"record_every = {record_every!r}: keep every k-th step, a whole "
                          "number >= 1.")


def _first_measured_soc(profile: Profile) -> float | None:
    soc = profile.measured.get("soc_frac")
    if soc is None:
        return None
    finite = np.flatnonzero(np.isfinite(soc))
    return float(soc[finite[0]]) if finite.size else None


def build_model(slots: Mapping[str, str | Effect | None] | None = None,
                contributions: Sequence[str | Effect] = (),
                params: Mapping[str, Mapping[str, float]] | None = None,
                tables: Mapping[str, Mapping[str, TableValue]] | None = None,
                bounds: Mapping[str, Mapping[str, Sequence[float]]] | None = None,
                dt_s: float = 0.1, name: str = "") -> Model:
    """Compose effects into a model.

    Parameters
    ----------
    slots
        Implementation per slot by name (or Effect); ``None`` or ``"none"`` leaves a slot that
        allows it empty; unnamed slots take their default implementation.
    contributions
        Contribution effects, by name or Effect, summed into their sinks in this order.
    params, tables, bounds
        ``{effect: {param: value}}``, ``{effect: {table: preset name or points}}`` and
        ``{effect: {param: [low, high]}}`` (bounds may only narrow the declared ones). Entries
        for effects that are registered but not in this model are ignored.
    dt_s
        Time step [s].
    """
    slots = dict(slots or {})
    for given in slots:
        if given not in SLOTS:
            raise unknown_name("slot", given, SLOTS)
    chosen: dict[str, Effect | None] = {}
    for slot_name, slot in SLOTS.items():
        choice = slots.get(slot_name, slot.default)
        if choice is None or choice == "none":
            if slot.none is None:
                raise CompositionError(f"Slot '{slot_name}' cannot be empty ({slot.description}).")
            chosen[slot_name] = None
            continue
        eff = _resolve(choice)
        if eff.slot != slot_name:
            raise CompositionError(
                f"Effect '{eff.name}' is a {eff.role}, it cannot fill slot '{slot_name}'.")
        chosen[slot_name] = eff
    sinks: dict[str, list[Effect]] = {s: [] for s in SINKS}
    seen = set()
    for item in contributions:
        eff = _resolve(item)
        if eff.sink is None:
            raise CompositionError(
                f"Effect '{eff.name}' fills slot '{eff.slot}'; choose it as that slot's "
                "implementation, not as a contribution.")
        if eff.name in seen:
            raise CompositionError(f"Effect '{eff.name}' is listed twice.")
        seen.add(eff.name)
        sinks[eff.sink].append(eff)

    in_model = {e.name: e for e in list(chosen.values()) + [e for v in sinks.values() for e in v]
                if e is not None}
    values: dict[str, float] = {}
    for effect_name, entries in (params or {}).items():
        eff = in_model.get(effect_name) or get_effect(effect_name)
        for pname, value in (entries or {}).items():
            eff.param(pname)
            if effect_name in in_model:
                values[f"{effect_name}.{pname}"] = float(value)
    box: dict[str, tuple[float, float]] = {}
    for effect_name, limits in (bounds or {}).items():
        eff = in_model.get(effect_name) or get_effect(effect_name)
        for pname, pair in (limits or {}).items():
            declared = eff.param(pname).bounds
            low, high = (float(v) for v in pair)
            if not declared[0] <= low <= high <= declared[1]:
                raise ConfigError(
                    f"Bounds [{low}, {high}] for '{effect_name}.{pname}' must narrow its declared "
                    f"bounds [{declared[0]}, {declared[1]}], not widen them.")
            box[f"{effect_name}.{pname}"] = (low, high)
    encoded: dict[tuple[str, str], np.ndarray] = {}
    table_values = tables or {}
    for effect_name in table_values:
        eff = in_model.get(effect_name) or get_effect(effect_name)
        for tname in table_values[effect_name] or {}:
            eff.table(tname)
    for eff in in_model.values():
        for table in eff.tables:
            chosen_points = (table_values.get(eff.name) or {}).get(table.name)
            try:
                points = table.resolve(chosen_points)
                encoded[(eff.name, table.name)] = points.encode(table.name)
            except ValueError as exc:
                raise ConfigError(f"Effect '{eff.name}': {exc}") from exc
            for pname, default in points.param_defaults:  # e.g. a cell's voltage window
                values.setdefault(f"{eff.name}.{eff.param(pname).name}", float(default))
    comp = Composition(chosen, sinks, encoded)
    return Model(comp, values, box, dt_s, name)
