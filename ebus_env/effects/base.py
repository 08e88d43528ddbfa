"""Effects: one physical effect, one small unit.

An effect is a plain Python function (or, for slots with several call sites, a few) whose
argument names say what it reads: its own parameters and tables, signals of the step
(``speed_mps``, ``mass_kg``, ...) and ``dt_s``/``time_s``. It declares its parameters once, with
default, unit, admissible bounds and meaning; the calibrator's search box is those bounds.

Two kinds:

* a **contribution** returns one value that is summed into a sink
  (``road_force_n``, ``dc_load_w``, ``mass_kg``, ``cabin_heat_w``), optionally followed by extra
  signals it provides (``returns``);
* a **slot** implementation returns the signals its slot's call site requires
  (see :data:`ebus_env.signals.SLOTS`), optionally followed by extras.

An effect that owns a state (``State``) reads its current value by name and returns
``<state>_next``. The model compiles all chosen effects into one step function, so effect
functions must be numba-compilable: scalar float arithmetic, ``math``, and the table lookups of
:mod:`ebus_env.effects.tables`.

Example, a user's own effect in their own file::

    from ebus_env import Param, effect

    @effect("headwind", sink="road_force_n", drivers=("speed_mps",), params=[
        Param("wind_speed_mps", 3.0, "m/s", (0.0, 15.0), "Mean headwind speed w"),
        Param("cda_m2", 5.0, "m^2", (3.0, 8.0), "Drag area c_d A"),
    ])
    def headwind(speed_mps, wind_speed_mps, cda_m2):
        # extra drag of a headwind: F = 1/2 rho c_d A ((v + w)^2 - v^2) [N]
        return 0.5 * 1.2 * cda_m2 * ((speed_mps + wind_speed_mps) ** 2 - speed_mps**2)
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numba
from numba.core.dispatcher import Dispatcher

from ebus_env.effects.tables import Table
from ebus_env.errors import ConfigError, unknown_name
from ebus_env.signals import HANDLES, SINKS, SLOTS, Input


@dataclass(frozen=True)
class Param:
    """A declared, calibratable parameter of an effect.

    Parameters
    ----------
    name
        Name with its unit suffix (``drag_coef``, ``curb_mass_kg``), unique within its effect.
    default
        Default value, in ``unit``.
    unit
        Unit, ``"1"`` for dimensionless.
    bounds
        Admissible range ``(low, high)``: the calibrator's search box.
    description
        Meaning, with the symbol used in the effect's equation.
    source
        Where the default comes from.
    whole
        A count (cells, passengers): only whole numbers are values of it.
    """

    name: str
    default: float
    unit: str
    bounds: tuple[float, float]
    description: str
    source: str = ""
    whole: bool = False

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise ValueError(f"Param name '{self.name}' must be a Python identifier.")
        low, high = self.bounds
        if not (math.isfinite(low) and math.isfinite(high) and low <= high):
            raise ValueError(f"Param '{self.name}': bounds {self.bounds} must be finite, low <= high.")
        if not low <= self.default <= high:
            raise ValueError(
                f"Param '{self.name}': default {self.default} lies outside its bounds {self.bounds}."
            )


@dataclass(frozen=True)
class State:
    """A state variable owned by an effect.

    ``initial(params, first_inputs)`` gives its value at the start of a run from the effect's
    own parameter values and the first row of inputs (both mappings by name).
    """

    name: str
    unit: str
    description: str
    initial: Callable[[Mapping[str, float], Mapping[str, float]], float]


@dataclass(frozen=True)
class Call:
    """One function of an effect and the signals it returns, in order."""

    function: Callable
    returns: tuple[str, ...]

    @property
    def arguments(self) -> tuple[str, ...]:
        return tuple(inspect.signature(self.function).parameters)


@dataclass(eq=False)
class Effect:
    """A named physical effect: a contribution to a sink or the implementation of a slot.

    Use the :func:`effect` decorator for single-function effects; build an ``Effect`` directly
    for slots with several call sites (battery, drivetrain).
    """

    name: str
    calls: dict[str, Call]
    sink: str | None = None
    slot: str | None = None
    params: tuple[Param, ...] = ()
    tables: tuple[Table, ...] = ()
    states: tuple[State, ...] = ()
    inputs: tuple[Input, ...] = ()
    drivers: tuple[str, ...] = ()
    key_params: tuple[str, ...] = ()
    shape_params: dict[str, tuple[float, ...]] = field(default_factory=dict)
    refines: str | None = None
    label: str = ""
    doc: str = ""
    handles: dict[str, str] = field(default_factory=dict)
    _jitted: dict[str, Dispatcher] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise ValueError(f"Effect name '{self.name}' must be a Python identifier.")
        if (self.sink is None) == (self.slot is None):
            raise ValueError(f"Effect '{self.name}': give exactly one of sink= or slot=.")
        if self.sink is not None:
            if self.sink not in SINKS:
                raise unknown_name("sink", self.sink, SINKS)
            if set(self.calls) != {"main"}:
                raise ValueError(f"Contribution '{self.name}' has exactly one function.")
        elif self.slot is not None:  # (exactly one of the two, checked above)
            if self.slot not in SLOTS:
                raise unknown_name("slot", self.slot, SLOTS)
            slot = SLOTS[self.slot]
            required = slot.calls
            if not set(required) - set(slot.optional) <= set(self.calls) <= set(required):
                optional = f" ({', '.join(slot.optional)} optional)" if slot.optional else ""
                raise ValueError(
                    f"Effect '{self.name}' fills slot '{self.slot}', whose call sites are "
                    f"{sorted(required)}{optional}; it gives {sorted(self.calls)}."
                )
            for site, outputs in required.items():
                if site not in self.calls:
                    continue
                got = self.calls[site].returns
                if tuple(got[: len(outputs)]) != outputs:
                    raise ValueError(
                        f"Effect '{self.name}', call '{site}' of slot '{self.slot}' must return "
                        f"{outputs} first; it declares {got}."
                    )
        names = [p.name for p in self.params] + [t.name for t in self.tables]
        if len(set(names)) != len(names):
            raise ValueError(f"Effect '{self.name}': parameter/table names repeat: {names}.")
        for call in self.calls.values():
            for arg in call.arguments:
                if "__" in arg:
                    raise ValueError(
                        f"Effect '{self.name}': argument '{arg}' may not contain '__' (reserved "
                        "for generated names)."
                    )
        for name in (*self.key_params, *self.shape_params):
            self.param(name)
        for handle, name in self.handles.items():
            if handle not in HANDLES:
                raise unknown_name(f"handle of effect '{self.name}'", handle, HANDLES)
            if self.param(name).unit != HANDLES[handle].unit:
                raise ValueError(f"Effect '{self.name}': handle '{handle}' is in "
                                 f"{HANDLES[handle].unit}; parameter '{name}' in "
                                 f"{self.param(name).unit}.")
        for state in self.states:
            if not any(state.name + "_next" in c.returns for c in self.calls.values()):
                raise ValueError(
                    f"Effect '{self.name}' owns state '{state.name}' but no call returns "
                    f"'{state.name}_next'."
                )

    # -- parameters -------------------------------------------------------------------------
    def param(self, name: str) -> Param:
        for p in self.params:
            if p.name == name:
                return p
        raise unknown_name(f"parameter of effect '{self.name}'", name, [p.name for p in self.params])

    def table(self, name: str) -> Table:
        for t in self.tables:
            if t.name == name:
                return t
        raise unknown_name(f"table of effect '{self.name}'", name, [t.name for t in self.tables])

    @property
    def strength_params(self) -> tuple[str, ...]:
        """Parameters that set how strong the effect is (diagnosis estimates them, the error
        ladder frees them): ``key_params``, else the first parameter."""
        return self.key_params or tuple(p.name for p in self.params[:1])

    @property
    def builtin(self) -> bool:
        """Whether the effect ships with ebus-env (not a user's file)."""
        return all(c.function.__module__.startswith("ebus_env.effects")
                   for c in self.calls.values())

    @property
    def title(self) -> str:
        """The physics in words, for reports."""
        return self.label or self.name.replace("_", " ")

    @property
    def role(self) -> str:
        return f"sink {self.sink}" if self.sink else f"slot {self.slot}"

    @property
    def contribution_name(self) -> str:
        """Name of a contribution's value in traces: effect name + its sink's unit suffix."""
        if self.sink is None:
            raise ValueError(f"Effect '{self.name}' fills slot '{self.slot}': only a "
                             "contribution to a sink has a contribution name.")
        return self.name + SINKS[self.sink].suffix

    def jitted(self, site: str) -> Dispatcher:
        """The numba-compiled function of a call site (compiled lazily, inside the kernel)."""
        if site not in self._jitted:
            self._jitted[site] = numba.njit(error_model="numpy", inline="always")(self.calls[site].function)
        return self._jitted[site]

    @property
    def source_files(self) -> set[str]:
        files = set()
        for call in self.calls.values():
            path = inspect.getsourcefile(call.function)
            if path:
                files.add(path)
        return files


def effect(
    name: str,
    *,
    sink: str | None = None,
    slot: str | None = None,
    params: Sequence[Param] = (),
    tables: Sequence[Table] = (),
    states: Sequence[State] = (),
    inputs: Sequence[Input] = (),
    returns: Sequence[str] = (),
    drivers: Sequence[str] = (),
    key_params: Sequence[str] = (),
    shape_params: dict[str, Sequence[float]] | None = None,
    refines: str | None = None,
    label: str = "",
    handles: dict[str, str] | None = None,
    register_effect: bool = True,
) -> Callable[[Callable], Effect]:
    """Decorator that turns a function into a registered single-call effect.

    For a contribution, the function returns the contribution followed by ``returns`` (extra
    signals); for a slot, it returns the slot's required outputs followed by ``returns``.
    ``key_params`` name the parameters that set the effect's strength (diagnosis estimates
    them; default: the first). ``shape_params`` name parameters that change the form of what
    the effect does, not its size, with values a diagnosis tries beside its strength (a
    pack's thermal time constant). A slot effect that ``refines`` another adds physics to it (the
    same slot, more detail): diagnosis offers it as a missing effect where the simpler one
    fills the slot. ``label`` names the physics in words for reports ("cabin heating and
    cooling"; default: the name). ``handles`` offer parameters to controllers by the names of
    :data:`ebus_env.signals.HANDLES` (``{"charge_pulse_duty": "pulse_duty"}``: an env's
    ECO-charging action sets it). The decorated name is the :class:`Effect` itself; its function
    stays reachable as ``effect.calls["main"].function`` for the uncompiled run.
    """

    def wrap(function: Callable) -> Effect:
        if sink is not None:
            outputs = ("__contribution__",) + tuple(returns)
        else:
            if slot not in SLOTS:
                raise unknown_name("slot", str(slot), SLOTS)
            outputs = SLOTS[slot].calls["main"] + tuple(returns)
        eff = Effect(
            name=name,
            calls={"main": Call(function, outputs)},
            sink=sink,
            slot=slot,
            params=tuple(params),
            tables=tuple(tables),
            states=tuple(states),
            inputs=tuple(inputs),
            drivers=tuple(drivers),
            key_params=tuple(key_params),
            shape_params={k: tuple(float(x) for x in v) for k, v in (shape_params or {}).items()},
            refines=refines,
            label=label,
            doc=inspect.getdoc(function) or "",
            handles=dict(handles or {}),
        )
        if register_effect:
            register(eff)
        return eff

    return wrap


def helper(function: Callable) -> Callable:
    """Decorator for a plain function that effects call (compiled with them into the kernel)."""
    return numba.njit(error_model="numpy", inline="always")(function)


# -- registry -------------------------------------------------------------------------------
_REGISTRY: dict[str, Effect] = {}


def _origin(eff: Effect) -> tuple:
    fn = next(iter(eff.calls.values())).function
    return (inspect.getsourcefile(fn), fn.__qualname__)


def register(eff: Effect) -> Effect:
    """Add an effect to the registry (re-registering from the same file replaces it)."""
    old = _REGISTRY.get(eff.name)
    if old is not None and _origin(old) != _origin(eff):
        raise ConfigError(
            f"Effect name '{eff.name}' is already registered (from {_origin(old)[0]}); "
            "choose another name."
        )
    _REGISTRY[eff.name] = eff
    return eff


def get_effect(name: str) -> Effect:
    """Registered effect by name, with a close-match suggestion when unknown."""
    import ebus_env.effects  # noqa: F401  (registers the built-in effects)

    if name not in _REGISTRY:
        raise unknown_name("effect", name, _REGISTRY)
    return _REGISTRY[name]


def registered_effects() -> dict[str, Effect]:
    """All registered effects by name (built-in and loaded user files)."""
    import ebus_env.effects  # noqa: F401

    return dict(_REGISTRY)
