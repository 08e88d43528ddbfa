"""The error ladder: NRMSE before and after each added effect, on calibration and held-out data.

The log is cut into blocks of an hour (a quarter of the log when it is shorter than four
hours); even blocks calibrate, odd blocks are held out. The model runs through the whole log
(a pack's temperature, a cabin's, carry on), but its SoC restarts from the measured one at
each block, so a held-out block tests the model, not the error it carried in. Rung 0 is the
model as given, calibrated; each further rung adds one effect and calibrates again, with the
paper's parameters, the bus-to-bus parameters (:data:`NUISANCE`; :data:`RESOLVED_BY_CURRENT`
too on logs of the pack's current) and the new effects' strength parameters free together,
starting from the rung before (and the diagnosis's estimate of the effect's strength, when it
has one). A :class:`Freedom` changes that choice as a calibration config does: other free
parameters in place of the paper's, narrower or wider search ranges, known values held.
After each rung the rung before is searched again from where the new one ended
(:func:`revisit`): the fall an effect is credited with is the fall beyond the bus without it
at its best.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from ebus_env.calibration.calibrate import CalibrationResult, calibrate, evaluate_fit
from ebus_env.calibration.isopt import ISOPTSettings
from ebus_env.calibration.problem import Blocks, CalibrationProblem, logs_current, paper_params
from ebus_env.config import BusConfig, resolve_effect
from ebus_env.effects.base import Effect
from ebus_env.errors import ConfigError

NUISANCE = {
    "vehicle_body.curb_mass_kg": (0.75, 1.25),
    "rolling_resistance.rolling_coef": (0.5, 1.5),
    "auxiliaries.base_power_w": (0.0, 3.0),
    "efficiency_map.gearbox_efficiency": (0.9, 1.04),
    "rint_battery.cell_capacity_ah": (0.6, 1.6),
    "rint_battery.cell_resistance_mohm": (0.3, 3.0),
    "regen_cutoff.max_decel_mps2": (0.06, 1.0),
}
"""The parameters that differ from bus to bus of one type (mass, rolling resistance,
auxiliary base load, drivetrain efficiency, pack capacity and resistance, the deceleration up
to which the motor brakes alone: each bus's brake blending), with the range a
calibration searches as factors of the configured value (within the declared bounds): wide
enough for a fleet's spread (the pack's, which the charging events pin down, also for another
pack than the configured one), narrow enough that they cannot stand in for a missing effect."""
RESOLVED_BY_CURRENT = {
    "regen_cutoff.max_share": (0.5, 1.0),
}
"""Bus-to-bus parameters that a log of the pack's current resolves and a SoC log does not,
freed with :data:`NUISANCE` when every profile has it: the share of the braking force the
motor takes (each bus's brake blending). The counted charge shows every braking window to a
few per cent, and a share left at its configured value leaves a braking-shaped residual
that the regen limit at high SoC takes for itself (it was named so on control days of the
independent truth simulator, docs/validation.md); on a SoC log the share and such a limit
cannot be told apart, and the share keeps its configured value."""


@dataclass(frozen=True)
class Freedom:
    """What the diagnosis's calibrations fit, where a user knows better than the defaults (the
    ``params``, ``ranges`` and ``fixed`` of a calibration config, ``ebus diagnose --set``):
    ``params`` in place of the paper's parameters (the bus-to-bus ones stay free), search
    ``ranges`` in place of the bus-to-bus ones' (within the declared bounds), and ``fixed``
    values, known and held: left out of every calibration and of the parameters that move
    back in an attribution."""

    params: tuple[str, ...] | None = None
    ranges: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    fixed: Mapping[str, float] = field(default_factory=dict)
    categorical_load: bool = False

    @classmethod
    def of(cls, config, fixed: Mapping[str, float] | None = None) -> Freedom:
        """From a :class:`~ebus_env.calibration.settings.CalibrationConfig`, with ``fixed``
        (``--set``) added to its known values."""
        return cls(tuple(config.params) if config.params else None, dict(config.ranges),
                   {**config.fixed, **(fixed or {})}, config.categorical_load)

    def on(self, model) -> Freedom:
        """The names as ``model`` has them (a refinement in a slot keeps its parameters under
        its own name: ``regen_soc_limit.cutoff_speed_mps``). Known values of an effect the
        model does not have (one the ladder adds later) wait until a model has it."""
        def name(n):
            return model.equivalent(n) or n

        effects = {n.partition(".")[0] for n in model.param_names}
        fixed = {name(k): v for k, v in self.fixed.items()
                 if model.equivalent(k) or k.partition(".")[0] in effects}
        return Freedom(None if self.params is None else tuple(map(name, self.params)),
                       {name(k): v for k, v in self.ranges.items()}, fixed,
                       self.categorical_load)


BLOCK_S = 3600.0
MIN_BLOCKS = 4
SCAN = 11


def as_effect(item) -> Effect:
    """An Effect, a registry name or ``file.py:Name``, as an Effect."""
    return item if isinstance(item, Effect) else resolve_effect(str(item))


def check_known(bus: BusConfig, add: list[Effect], freedom: Freedom | None,
                dt_s: float = 0.1) -> None:
    """Every known value names a parameter of ``bus`` or of an effect in ``add`` (held from
    the effect's signatures on), inside its bounds: a clear error otherwise, before any
    calibration (:meth:`Freedom.on` leaves an added effect's values out until it is there).
    An effect to add that the bus has already is refused: its rung would test nothing."""
    present, added = set(bus.effect_names()), set()
    for eff in add:
        if eff.name in added:
            raise ConfigError(f"--add {eff.name} is given twice. Fix: give it once.")
        if eff.name in present:
            raise ConfigError(f"--add {eff.name}: the bus has it already. Fix: take it out of "
                              f"the bus (--without {eff.name}) to see what adding it does.")
        added.add(eff.name)
    fixed = (freedom or Freedom()).fixed
    if fixed:
        for eff in add:
            bus = bus.with_effect(eff)
        bus.build(dt_s).param_vector(fixed)


def block_steps(profile, block_s: float = BLOCK_S) -> int:
    """Steps per block of a profile: an hour, or a quarter of a shorter log."""
    return max(2, int(round(min(block_s, profile.duration_s / MIN_BLOCKS) / profile.dt_s)))


def split_blocks(profiles, block_s: float = BLOCK_S) -> tuple[Blocks, Blocks]:
    """(calibration, held-out): the same blocks of each profile, even ones scored in the
    first, odd ones in the second."""
    starts, even = [], []
    for p in profiles:
        per = block_steps(p, block_s)
        first = np.arange(0, max(p.n_steps - per // 2, 1), per)
        starts.append(first)
        even.append(np.arange(len(first)) % 2 == 0)
    if sum(len(s) for s in starts) < 2:
        raise ValueError("The log is too short to hold out blocks of it.")
    return Blocks(tuple(starts), tuple(even)), Blocks(tuple(starts), tuple(~e for e in even))


def in_blocks(blocks: Blocks, k: int, rows: np.ndarray) -> np.ndarray:
    """Whether rows of profile ``k`` lie in the blocks ``blocks`` scores."""
    which = np.searchsorted(blocks.starts[k], rows, side="right") - 1
    return np.asarray(blocks.scored[k])[which]


def windows_in(blocks: Blocks, windows) -> np.ndarray:
    """Whether each of a diagnosis's ``windows`` starts in a block ``blocks`` scores."""
    return np.array([in_blocks(blocks, k, np.array([s]))[0] for k, s in
                     zip(windows.profile_index, windows.start_step, strict=True)], bool)


@dataclass
class Rung:
    """One step of the ladder."""

    label: str  # "as given" or "+ effect"
    effects: list[str]  # effects added so far
    values: dict  # calibrated parameter values
    calibration: dict  # NRMSE, RMSE [%-points], ... on calibration blocks
    held_out: dict  # the same on held-out blocks
    calibration_result: CalibrationResult | None = field(default=None, repr=False)
    model: object = field(default=None, repr=False)  # the built model of this rung
    # the calibration NRMSE this rung's own search ended at, where a search from the next
    # rung's values fitted better (:func:`revisit`); None otherwise
    searched_nrmse: float | None = None

    @property
    def range_ends(self) -> dict[str, str]:
        """The parameters this rung's calibration pressed against an end of their range
        (:meth:`~ebus_env.calibration.calibrate.CalibrationResult.pressing`): an effect that
        was missing lets the parameters that stood in for it come back inside."""
        return self.calibration_result.pressing() if self.calibration_result else {}

    def to_json(self) -> dict:
        pick = ("nrmse", "rmse_pct", "max_abs_error_pct", "charge_nrmse", "cost")
        return {"label": self.label, "effects": self.effects,
                "values": {k: float(v) for k, v in self.values.items()},
                **({"searched_nrmse": self.searched_nrmse}
                   if self.searched_nrmse is not None else {}),
                "at_range_end": self.range_ends,
                "free": list(self.calibration_result.free) if self.calibration_result else [],
                **{name: {k: float(fit[k]) for k in pick if k in fit}
                   for name, fit in (("calibration", self.calibration),
                                     ("held_out", self.held_out))}}


def nuisance_ranges(model, profiles=()) -> dict[str, tuple[float, float]]:
    """The :data:`NUISANCE` parameters the model has, and :data:`RESOLVED_BY_CURRENT` when
    every one of ``profiles`` logs the pack's current, with their search ranges."""
    nuisance = dict(NUISANCE)
    if profiles and all(map(logs_current, profiles)):
        nuisance.update(RESOLVED_BY_CURRENT)
    out = {}
    for name, (low, high) in nuisance.items():
        name = model.equivalent(name)  # a refinement in the slot keeps the parameter
        if name is None:
            continue
        value = model.params[model.param_index(name)]
        lo, hi = model.bounds[model.param_index(name)]
        out[name] = (max(lo, low * value), min(hi, high * value))
    return out


def fit_on_blocks(model, values: dict, profiles, cal: Blocks, held: Blocks) -> tuple[dict, dict]:
    """Fit statistics of parameter ``values`` on calibration and held-out blocks (on logs of
    the pack's current, the counted charge's too, as the calibrations fit it)."""
    params = model.param_vector(model.carry_over(values))
    charge = all(map(logs_current, profiles))
    return (evaluate_fit(model, profiles, params, cal, charge)[0],
            evaluate_fit(model, profiles, params, held, charge)[0])


def block_errors(model, values: dict, profiles, blocks: Blocks) -> np.ndarray:
    """Sum of squared SoC errors [%-points^2] in each block that ``blocks`` scores, profile by
    profile in order (the SoC restarting at each block): what a paired comparison of two
    fits on the same blocks resamples."""
    params = model.param_vector(model.carry_over(values))
    problem = CalibrationProblem(model, profiles, [model.param_names[0]], chunks=1,
                                 blocks=blocks)
    out = []
    for k, d in enumerate(problem.data):
        error_pct = 100.0 * (problem.simulate(d, params[None, :])[0] - d.measured)
        block = np.searchsorted(blocks.starts[k], d.rows, side="right") - 1
        out.extend(np.bincount(block, error_pct**2)[np.unique(block)])
    return np.array(out)


def strength_scan(problem, model, effect: Effect, bases: list[dict]) -> list[dict]:
    """For each point of ``bases``, the best of ``SCAN`` values of the effect's first strength
    parameter across its range (one batched evaluation): where a global search should start,
    since an effect added at its default strength may sit in another valley than the data."""
    name = f"{effect.name}.{effect.strength_params[0]}"
    if name not in problem.free:
        return bases
    i = problem.free.index(name)
    out = []
    for base in bases:
        u = np.repeat(problem.points([base]), SCAN, axis=0)
        u[:, i] = np.linspace(0.0, 1.0, SCAN)
        best = u[int(np.argmin(problem.cost(u)))]
        out.append(problem.named(best))
    return out


def calibrate_rung(bus: BusConfig, added: list[Effect], profiles, cal: Blocks, held: Blocks,
                   dt_s: float,
                   settings=None, polish_starts: int | None = None, label: str = "as given",
                   free: list[str] | None = None, start: dict | None = None,
                   model=None, freedom: Freedom | None = None) -> Rung:
    """Calibrate ``bus`` (with ``added`` effects already in it) on the calibration blocks of
    ``profiles``: by default the paper's parameters, the bus-to-bus ones (:data:`NUISANCE`,
    and :data:`RESOLVED_BY_CURRENT` on logs of the pack's current, in their ranges) and the
    added effects' strength parameters are free together, as ``freedom`` changes them; on such
    a log the charge it counts is fitted beside the SoC
    (:class:`~ebus_env.calibration.problem.CalibrationProblem`). The search
    starts from ``start`` (values by name) and from the bus's configured values, each with the
    last added effect's strength scanned (:func:`strength_scan`). ``model`` is the bus's model
    when already built. The rung's values include the fixed ones."""
    model = model or bus.build(dt_s)
    known = (freedom or Freedom()).on(model)
    nuisance = nuisance_ranges(model, profiles)
    if free is None:
        strengths = [f"{eff.name}.{p}" for eff in added for p in eff.strength_params]
        # the paper's parameters as named: on a log with its charger's rating the charging
        # power moves nothing, and the share of the rating delivered keeps its configured
        # value (freed, on a 2.5-h BMS log of the truth simulator's grade day it let the CC/CV
        # taper move to another optimum, and the grade went unnamed)
        free = list(dict.fromkeys([*(known.params or paper_params(model)), *nuisance,
                                   *strengths]))
    free = [n for n in free if n not in known.fixed]
    # a user's range for a parameter left out fails in the calibration, by its name
    ranges = {**{k: v for k, v in nuisance.items() if k in free}, **known.ranges}
    starts = [model.carry_over(start or {}), {}]  # the rung before, the configured values
    charge = all(map(logs_current, profiles))  # a BMS log: its counted charge is fitted too
    if added and added[-1].strength_params:
        problem = CalibrationProblem(model, profiles, free, ranges, known.fixed, blocks=cal,
                                     charge=charge)
        starts = strength_scan(problem, model, added[-1], starts)
    result = calibrate(model, profiles, free=free, bounds=ranges, fixed=known.fixed,
                       settings=settings, validate=profiles, polish_starts=polish_starts,
                       start=starts, blocks=cal, validate_blocks=held,
                       categorical_load=known.categorical_load, charge=charge)
    return Rung(label, [e.name for e in added], {**known.fixed, **result.values}, result.fit,
                result.validation, result, model)


def error_ladder(bus: BusConfig, profiles, add, dt_s: float = 0.1, settings=None,
                 polish_starts: int | None = None, first: Rung | None = None,
                 blocks: tuple[Blocks, Blocks] | None = None, progress=None,
                 estimates: dict | None = None, freedom: Freedom | None = None) -> list[Rung]:
    """Rung 0 (``first`` when already calibrated) and one rung per effect in ``add`` (names,
    ``file.py:Name`` or Effect objects), each added to the ones before and calibrated (as
    ``freedom`` says); ``estimates`` maps an effect's name to starting values of its
    parameters."""
    cal, held = blocks or split_blocks(profiles)
    check_known(bus, [as_effect(a) for a in add], freedom, dt_s)
    rungs = [first] if first is not None else []
    if not rungs:
        if progress:
            progress("as given")
        rungs.append(calibrate_rung(bus, [], profiles, cal, held, dt_s, settings,
                                    polish_starts, freedom=freedom))
    added: list[Effect] = []
    for item in add:
        eff = as_effect(item)
        before_bus, before_added = bus, list(added)
        bus = bus.with_effect(eff)
        added.append(eff)
        if progress:
            progress(f"+ {eff.name}")
        start = {**rungs[-1].values, **(estimates or {}).get(eff.name, {})}
        rungs.append(calibrate_rung(bus, list(added), profiles, cal, held, dt_s, settings,
                                    polish_starts, label=f"+ {eff.name}", start=start,
                                    freedom=freedom))
        rungs[-2] = revisit(rungs[-2], rungs[-1], profiles, (cal, held), settings, freedom,
                            before_bus, before_added)
    return rungs


def local_rung(bus: BusConfig | None, added: list[Effect], profiles,
               blocks: tuple[Blocks, Blocks], settings, label: str, start: dict, model=None,
               freedom: Freedom | None = None) -> Rung:
    """:func:`calibrate_rung` as a local search from ``start``: no iSOPT iterations, one
    Levenberg-Marquardt polish (the last added effect's strength scanned first)."""
    local = replace(settings or ISOPTSettings(), iterations=0)
    return calibrate_rung(bus, added, profiles, *blocks, profiles[0].dt_s, local, 1, label,
                          start=start, model=model, freedom=freedom)


def revisit(before: Rung, after: Rung, profiles, blocks: tuple[Blocks, Blocks], settings=None,
            freedom: Freedom | None = None, bus: BusConfig | None = None,
            added: list[Effect] = ()) -> Rung:
    """``before`` searched again from where ``after`` ended (``after``: the same bus with one
    more effect; a local search from its values, that effect's own left out), kept where it
    fits the calibration blocks better, with the NRMSE its own search ended at
    (``searched_nrmse``). A calibration with an effect added searches the other parameters
    again too, and may end in a better valley of theirs than the first search did: the fall
    an effect is credited with is measured against the bus without it at its best, not
    against where one search happened to end. ``bus`` and ``added``: ``before``'s bus and
    its added effects (``bus`` only where ``before`` holds no model)."""
    if before.calibration_result is None or after.calibration_result is None:
        return before
    again = local_rung(bus, list(added), profiles, blocks, settings, before.label,
                       after.values, before.model, freedom)
    if again.calibration_result.cost >= before.calibration_result.cost:
        return before
    return replace(again, searched_nrmse=before.calibration["nrmse"])


def improvement(rungs: list[Rung], key: str = "nrmse") -> float:
    """Relative fall of held-out SoC NRMSE from the first rung to the last (on a log of the
    pack's current, the counted charge's, ``key="charge_nrmse"``, is reported beside it)."""
    before, after = rungs[0].held_out[key], rungs[-1].held_out[key]
    return float(1.0 - after / before) if before > 0 else float("nan")
