"""The calibration problem: which parameters are free, their box, and the cost of a candidate.

Cost of a candidate (paper section 4.2)::

    J = NRMSE(SoC_sim, SoC_meas) + sum_k penalty_k,    penalty_k = 1 + v_k / s_k  if v_k > 0

with the SoC compared only at the rows where the log has samples, and penalties (always greater
than 1, growing with the violation v_k) for: CV decay factor, regen cutoff speed and CC/CV
cutoff SoC not positive; cutoff SoC not below 100 %; RCD not below 25 %; charging power not
positive; simulated SoC below 10 %. Charging events shorter than one minute are a property of
the data, not of a candidate: they are reported as warnings (a constant penalty would only
shift every cost).

On a log of the pack's current (``charge=True``) the charge it counts is fitted too: a BMS
log resolves the charge moved to far below its SoC's 0.1 % steps, which pins what a SoC log
blurs (a drivetrain loss while driving against an auxiliary load all day). Both in SoC points
of the configured pack, counted from the start of each block (or of the log)::

    NRMSE_Q = rms( (SoC_sim(t) - SoC_0) Q / Q_0 + int_0^t eta(I) I dt / (3600 Q_0) ) / span,
    J = sqrt((NRMSE^2 + NRMSE_Q^2) / 2) + penalties

(Q: the candidate's capacity, Q_0 the starting one; the current counts > 0 discharging, and
charge goes in at the candidate's coulombic efficiency eta, as in the model's own count.)

A whole population runs in one batched call of the compiled core, in chunks of the day: after
each chunk the SoC error so far gives a lower bound on a candidate's final cost, and candidates
that can no longer beat the population's worst are dropped (the upper-bound strategy).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ebus_env.errors import ConfigError
from ebus_env.profile import Profile, as_profiles

if TYPE_CHECKING:
    from ebus_env.model.model import Model

PAPER_PARAMS = (
    "passenger_load.load_frac",
    "cabin_hvac.setpoint_degc",
    "static_rcd.rcd_frac",
    "cccv_taper.cv_soc_pct",
    "cccv_taper.decay_per_pct",
    "grid_charger.power_kw",
    "regen_cutoff.cutoff_speed_mps",
)
"""The seven uncertain parameters Hasan et al. 2023 tune, by qualified name."""
CHARGING_POWER = "grid_charger.power_kw"
CHARGER_SHARE = "grid_charger.delivered_frac"


def logs_rating(profile: Profile) -> bool:
    """Whether a log gives its charger's rating at every row the bus is on a charger (the
    model's charger then takes the log's rating, and its own power moves nothing)."""
    rating = profile.channels.get("charger_rating_w")
    connected = profile.channels.get("charger_connected")
    if rating is None or connected is None or not np.any(connected > 0.5):
        return False
    on = rating[connected > 0.5]
    return bool(np.all(np.isfinite(on) & (on > 0)))


def paper_params(model: Model, profiles: Sequence[Profile] = ()) -> list[str]:
    """The paper's parameters this model has, under their names in it (a slot filled by a
    refinement keeps them: ``regen_soc_limit.cutoff_speed_mps``). Where every profile gives
    its charger's rating (:func:`logs_rating`), the charging power the paper tunes is the share
    of that rating the charger delivers, k_del (docs/physics.md §6.1): a rating stated on the
    grid side delivers the charger's efficiency of it."""
    names: tuple[str, ...] = PAPER_PARAMS
    if profiles and all(map(logs_rating, profiles)):
        names = tuple(CHARGER_SHARE if n == CHARGING_POWER else n for n in names)
    return [m for m in map(model.equivalent, names) if m is not None]


LOAD_LEVELS = (0.0, 0.5, 1.0)
"""The paper's passenger-load categories: driver only, half load, full load."""

LANES_PAY_BUS_STEPS = 1e7
"""A run of at least this many bus-steps (a batch of parameter sets over one chunk of a
profile, an eighth of it by default) goes in SIMD lanes even when their loop must be
compiled first; a smaller one only when the loop is compiled already (in this process or the
disk cache). A lane loop compiles in 7-12 s per model and set of free parameters and saves
about 10 ns per bus-step (docs/performance.md). The calibrations the library runs stay below
it (a 13.5 h 10 Hz log's polish: ~3e6 per run), so they use lanes only from a cache that has
them. Measured: on a first run a 4 h 1 Hz day's `diagnose --calibrate` took 51 s with lanes
compiled for it, 40 s without; from a warm cache a 13.5 h 1 Hz diagnosis 36 s with lanes,
37.5 s without, and the 13.5 h 10 Hz twin's calibration with polish 13.3 s with, 14.2 s
without."""
SOC_FLOOR_FRAC = 0.10


@dataclass(frozen=True)
class ParamConstraint:
    """``param`` must stay above ``low`` and below ``high`` (strictly); violations are scaled
    by ``scale`` in the penalty."""

    param: str
    low: float | None
    high: float | None
    scale: float
    text: str


CONSTRAINTS = (
    ParamConstraint("cccv_taper.decay_per_pct", 0.0, None, 0.1, "CV decay factor positive"),
    ParamConstraint("regen_cutoff.cutoff_speed_mps", 0.0, None, 1.0, "cutoff speed positive"),
    ParamConstraint("cccv_taper.cv_soc_pct", 0.0, 100.0, 10.0, "cutoff SoC in (0, 100) %"),
    ParamConstraint("static_rcd.rcd_frac", None, 0.25, 0.25, "RCD below 25 %"),
    ParamConstraint("grid_charger.power_kw", 0.0, None, 10.0, "charging power positive"),
)


def penalty(violation: np.ndarray, scale: float) -> np.ndarray:
    """1 + v / scale where the violation v > 0, else 0."""
    return np.where(violation > 0, 1.0 + violation / scale, 0.0)


def outside(x: np.ndarray, low: float | None, high: float | None, scale: float) -> np.ndarray:
    """Penalty for x not strictly inside (low, high): 1 + distance / scale, 0 inside."""
    total = np.zeros_like(x)
    if low is not None:
        total += np.where(x <= low, 1.0 + (low - x) / scale, 0.0)
    if high is not None:
        total += np.where(x >= high, 1.0 + (x - high) / scale, 0.0)
    return total


def logs_current(profile: Profile) -> bool:
    """Whether a log has the pack current at every row (its charge can be fitted)."""
    current = profile.measured.get("battery_current_a")
    return current is not None and bool(np.isfinite(current).all())


def coulombic_efficiency(model: Model, matrix: np.ndarray) -> np.ndarray:
    """Coulombic efficiency of parameter rows (n, n_params): the share of the charge going in
    that the pack stores (1 where the model has none)."""
    names = [n for n in model.param_names if n.endswith(".coulombic_efficiency")]
    matrix = np.atleast_2d(matrix)
    return matrix[:, model.param_index(names[0])] if names else np.ones(len(matrix))


def capacity_ah(model: Model, matrix: np.ndarray) -> np.ndarray:
    """Pack capacity [Ah] of parameter rows, at the model's starting state (one step)."""
    matrix = np.atleast_2d(matrix)
    states = np.array([model.initial_state(row, {}) for row in matrix])
    i = model.trace_names.index("capacity_ah")
    out = np.zeros((len(matrix), 1, 1), np.float32)
    model.run(matrix, states, np.zeros((1, len(model.input_names), 2)), n_steps=1,
              record_every=1, record_sel=np.array([i], np.int64), record_out=out)
    return out[:, 0, 0].astype(float)


@dataclass(frozen=True)
class Blocks:
    """Blocks of the profiles: the model runs through each profile without a break (every
    state carries on), but its SoC restarts from the measured one at each block's start,
    and only the samples of the blocks that are ``scored`` count."""

    starts: tuple[np.ndarray, ...]  # per profile: first row of each block
    scored: tuple[np.ndarray, ...]  # per profile: bool per block


def measured_soc_at(profile: Profile, rows: np.ndarray) -> np.ndarray:
    """Measured SoC at rows, interpolated between the log's samples."""
    samples = profile.sample_rows("soc_frac")
    return np.interp(rows, samples, profile.measured["soc_frac"][samples])


@dataclass
class _Data:
    """One profile's inputs and measured SoC samples."""

    profile: Profile
    inputs: np.ndarray
    mask: np.ndarray
    rows: np.ndarray
    measured: np.ndarray
    soc_start: float
    first: dict
    initial: dict
    anchors: dict  # row -> measured SoC the model restarts from there
    start_soc: np.ndarray  # per compared row: the SoC the model ran from (its block's start)
    # per compared row: charge out of the pack and into it since that start, / (3600 Q_0)
    discharged: np.ndarray | None
    charged: np.ndarray | None

    def counted(self, eta: np.ndarray) -> np.ndarray:
        """(n, rows) SoC change counted from the current, charge going in at efficiencies
        ``eta`` (n,)."""
        if self.discharged is None or self.charged is None:
            raise ValueError(f"Profile '{self.profile.name}': no charge counted (a problem "
                             "without charge=True, or a log without current).")
        return -(self.discharged[None, :] - eta[:, None] * self.charged[None, :])

    def charge_error(self, sim: np.ndarray, ratio: np.ndarray, eta: np.ndarray,
                     rows: slice | np.ndarray = slice(None)) -> np.ndarray:
        """(n, rows) the SoC change simulated since each row's block started minus the one
        the current counts, both in the starting pack's SoC (Q_0): ``sim`` (n, rows) at the
        ``rows`` selected, ``ratio`` = Q / Q_0 and ``eta`` of each parameter row."""
        return (sim - self.start_soc[rows]) * ratio[:, None] - self.counted(eta)[:, rows]

    def edges(self, chunks: int) -> list[int]:
        """Rows where a run stops: chunk ends and anchors."""
        n = self.inputs.shape[1]
        return sorted({*np.linspace(0, n, chunks + 1).astype(int).tolist(), *self.anchors})

    def anchor(self, row: int, states: np.ndarray, soc_index: int) -> None:
        if row in self.anchors:
            states[:, soc_index] = self.anchors[row]


def require_soc(profile: Profile, why: str) -> np.ndarray:
    """The profile's measured SoC [1], or an error naming the profile and ``why`` it needs
    one."""
    soc = profile.measured.get("soc_frac")
    if soc is None or not np.isfinite(soc).any():
        raise ConfigError(f"Profile '{profile.name}' has no measured SoC: {why}. Give a log "
                          "with a 'soc_pct' (or 'soc_frac') column.")
    return soc


class CalibrationProblem:
    """Free parameters, their box and the cost of candidates on measured profiles.

    Parameters
    ----------
    model
        The built model.
    profiles
        Measured profiles (several: consecutive segments or days); each needs measured SoC.
    free
        Qualified names to fit (default: the paper's seven that the model has).
    bounds
        ``{name: (low, high)}`` narrowing the declared/configured bounds (prior ranges).
    fixed
        ``{name: value}`` known parameters (e.g. the battery capacity).
    categorical_load
        Restrict ``passenger_load.load_frac`` to the paper's three categories.
    chunks
        Parts of the day between which hopeless candidates are dropped (1: never).
    initial
        Per profile, initial states other than SoC (``cabin_temp_degc``...), e.g. carried over
        from the window before; SoC always starts at the first measured value.
    blocks
        Score only some blocks of each profile, the SoC restarting at each block's start
        (held-out validation); default: every sample, one run from the first.
    charge
        Fit the charge counted from the logged pack current too (every profile needs
        ``battery_current_a``).
    """

    def __init__(self, model: Model, profiles: Sequence[Profile], free: Sequence[str] | None = None,
                 bounds: Mapping[str, Sequence[float]] | None = None,
                 fixed: Mapping[str, float] | None = None, categorical_load: bool = False,
                 chunks: int = 8, initial: Sequence[Mapping[str, float]] | None = None,
                 blocks: Blocks | None = None, charge: bool = False):
        self.model = model
        self.notes: list[str] = []
        self.warnings: list[str] = []
        profiles = as_profiles(profiles, "calibrate")
        if isinstance(free, str):
            raise ConfigError(f"free = {free!r}: give a list of qualified names, "
                              f"[{free!r}].")
        fixed = dict(fixed or {})
        self.base = model.param_vector(fixed)
        rated = all(map(logs_rating, profiles))
        if free is None:
            free = paper_params(model, profiles)
            missing = [p for p in PAPER_PARAMS if model.equivalent(p) is None]
            if missing:
                self.notes.append(f"the model lacks {', '.join(missing)}: not fitted")
            if rated and model.equivalent(CHARGER_SHARE):
                self.notes.append(f"the log gives the charger's rating: {CHARGER_SHARE} (the "
                                  f"share of it delivered) is fitted in place of {CHARGING_POWER}")
        elif rated and CHARGING_POWER in free:
            self.notes.append(
                f"{CHARGING_POWER} moves nothing: the log gives the charger's rating, which the "
                f"model takes in its place (fit {CHARGER_SHARE}, the share of the rating the "
                "charger delivers, for the charging power)")
        free = [p for p in free if p not in fixed]
        if not free:
            raise ConfigError("Nothing to calibrate: give free parameters (--params, or free= "
                              "in Python) that the model has and that are not fixed.")
        for name in free:
            model.param_index(name)  # unknown names fail with a close match
            if model.param_info(name).whole:
                raise ConfigError(f"'{name}' is a count (a whole number): a search cannot "
                                  "fit it. Fix: give its value (--fix, --set) and leave it "
                                  "out of the free parameters.")
        self.free = list(free)
        self.index = np.array([model.param_index(p) for p in self.free])
        self.low = model.bounds[self.index, 0].copy()
        self.high = model.bounds[self.index, 1].copy()
        for name, pair in (bounds or {}).items():
            if name not in self.free:
                raise ConfigError(f"A range is given for '{name}', which is not a free "
                                  f"parameter ({', '.join(self.free)}).")
            i = self.free.index(name)
            low, high = (float(v) for v in pair)
            if not self.low[i] <= low < high <= self.high[i]:
                raise ConfigError(
                    f"The range [{low:g}, {high:g}] for '{name}' must lie inside its bounds "
                    f"[{self.low[i]:g}, {self.high[i]:g}] (a range may narrow them, never "
                    "widen them).")
            self.low[i], self.high[i] = low, high
            default = self.base[self.index[i]]
            if not low <= default <= high:
                raise ConfigError(
                    f"The range [{low:g}, {high:g}] for '{name}' excludes its current value "
                    f"{default:g}: widen the range to include it, or fix the parameter at a "
                    f"value inside (--fix {name}=...).")
        self.categorical = categorical_load and "passenger_load.load_frac" in self.free
        self.chunks = max(1, int(chunks))
        # Q_0, the pack the counted charge is expressed in (a record run: only when needed)
        self.capacity_ah = float(capacity_ah(model, self.base)[0]) if charge else None
        initial = list(initial) if initial is not None else [{} for _ in profiles]
        self.data = [self._prepare(p, dict(init), blocks, k, charge)
                     for k, (p, init) in enumerate(zip(profiles, initial, strict=True))]
        self.soc_index = model.state_names.index("soc_frac")
        all_meas = np.concatenate([d.measured for d in self.data])
        self.n_samples = len(all_meas)
        self.span = float(np.max(all_meas) - np.min(all_meas))
        if self.span <= 0:
            raise ConfigError("The measured SoC never changes: there is nothing to fit. Give a "
                              "log in which the battery is used (or charged).")
        self.charge = charge
        if charge:
            all_charge = np.concatenate([d.counted(coulombic_efficiency(model, self.base))[0]
                                         for d in self.data])
            self.charge_span = float(np.ptp(all_charge))
            if self.charge_span <= 0:
                raise ConfigError("The logged battery current never moves any charge: there "
                                  "is nothing to fit. Give a log in which the pack is used.")
        self.constraints = [c for c in CONSTRAINTS if c.param in model.param_names]
        self.evaluations = 0
        self.simulated_steps = 0

    # -- data ------------------------------------------------------------------------------
    def _prepare(self, profile: Profile, initial: dict, blocks: Blocks | None, k: int,
                 charge: bool) -> _Data:
        soc = require_soc(profile, "calibration fits the model to it")
        rows = profile.sample_rows("soc_frac")
        rows = rows[np.isfinite(soc[rows])]
        anchors = {}
        if blocks is not None:
            starts = np.asarray(blocks.starts[k], int)
            block = np.searchsorted(starts, rows, side="right") - 1
            rows = rows[np.asarray(blocks.scored[k], bool)[block]]
            anchors = dict(zip(starts.tolist(), measured_soc_at(profile, starts).tolist(),
                               strict=True))
        if len(rows) < 2:
            raise ConfigError(f"Profile '{profile.name}' has fewer than two SoC samples.")
        inputs = self.model.input_array(profile)
        mask = np.zeros(profile.n_steps, np.bool_)
        mask[rows] = True
        first = dict(zip(self.model.input_names, inputs[:, 0], strict=True))
        connected = profile.channel("charger_connected") > 0.5
        edges = np.diff(np.concatenate([[0], connected.astype(int), [0]]))
        starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        short = np.flatnonzero((stops - starts) * profile.dt_s < 60.0)
        if short.size:
            self.warnings.append(
                f"{profile.name}: {short.size} charging event(s) shorter than 1 min (at "
                f"{', '.join(f'{starts[i] * profile.dt_s:.0f} s' for i in short[:5])})")
        initial = {**self.model.measured_states(profile), **initial}
        soc_start = anchors.get(0, float(soc[rows[0]]))
        starts = np.array(sorted({0, *anchors}))
        start_of = starts[np.searchsorted(starts, rows, side="right") - 1]
        start_soc = np.array([anchors.get(int(a), soc_start) for a in start_of])
        discharged = charged = None
        if charge:
            if not logs_current(profile):
                raise ConfigError(f"Profile '{profile.name}' has no battery current at every "
                                  "row: the charge it counts cannot be fitted. Fit the SoC "
                                  "alone, or give a log with 'battery_current_a'.")
            current = profile.measured["battery_current_a"]

            def since_start(part: np.ndarray) -> np.ndarray:  # [Q_0] since the block's start
                ah = np.concatenate([[0.0], np.cumsum(part[:-1]) * profile.dt_s / 3600.0])
                return (ah[rows] - ah[start_of]) / self.capacity_ah

            discharged = since_start(np.maximum(current, 0.0))
            charged = since_start(np.maximum(-current, 0.0))
        return _Data(profile, inputs, mask, rows, soc[rows], soc_start, first, initial, anchors,
                     start_soc, discharged, charged)

    # -- parameters ------------------------------------------------------------------------
    def values(self, u: np.ndarray) -> np.ndarray:
        """Free-parameter values for normalised points ``u`` (n, n_free)."""
        x = self.low + np.clip(u, 0.0, 1.0) * (self.high - self.low)
        if self.categorical:
            i = self.free.index("passenger_load.load_frac")
            levels = np.array(LOAD_LEVELS)
            x[:, i] = levels[np.argmin(np.abs(x[:, i, None] - levels), axis=1)]
        return x

    def normalise(self, values: np.ndarray) -> np.ndarray:
        return (np.asarray(values, dtype=float) - self.low) / (self.high - self.low)

    def points(self, named: Sequence[Mapping[str, float]]) -> np.ndarray:
        """Normalised points (n, n_free) for values by name (the model's own where a point
        omits a free parameter), clipped to the box."""
        rows = np.tile(self.base[self.index], (len(named), 1))
        for row, values in zip(rows, named, strict=True):
            for i, name in enumerate(self.free):
                row[i] = values.get(name, row[i])
        return np.clip(self.normalise(rows), 0.0, 1.0)

    def params(self, u: np.ndarray) -> np.ndarray:
        """Full parameter matrix (n, n_params) for normalised points ``u``."""
        u = np.atleast_2d(u)
        matrix = np.tile(self.base, (len(u), 1))
        matrix[:, self.index] = self.values(u)
        return matrix

    def parameter_penalties(self, matrix: np.ndarray) -> np.ndarray:
        return sum((outside(matrix[:, self.model.param_index(c.param)], c.low, c.high, c.scale)
                    for c in self.constraints), np.zeros(len(matrix)))

    # -- cost ------------------------------------------------------------------------------
    def cost(self, u: np.ndarray, threshold: float = np.inf) -> np.ndarray:
        """Cost of candidates ``u`` (n, n_free); candidates that cannot beat ``threshold`` get
        a lower bound above it."""
        matrix = self.params(u)
        n = len(matrix)
        fixed_part = self.parameter_penalties(matrix)
        sse = np.zeros(n)
        charge_sse = np.zeros(n)
        if self.charge:
            ratio = capacity_ah(self.model, matrix) / self.capacity_ah
            eta = coulombic_efficiency(self.model, matrix)
        soc_min = np.full(n, np.inf)
        alive = np.arange(n)
        for d in self.data:
            if alive.size == 0:
                break
            states = np.array([self.model.initial_state(matrix[i], d.first, d.soc_start,
                                                        **d.initial) for i in alive])
            acc = self.model.new_accumulators(len(alive))
            edges = d.edges(self.chunks)
            for a, b in zip(edges[:-1], edges[1:], strict=True):
                if b <= a or alive.size == 0:
                    continue
                d.anchor(a, states, self.soc_index)
                in_chunk = (d.rows >= a) & (d.rows < b)
                out = np.zeros((len(alive), int(in_chunk.sum()), 1), np.float32)
                # SIMD lanes where their loop is compiled already or the batch repays it
                lanes = (len(alive) * (b - a) >= LANES_PAY_BUS_STEPS
                         or self.model.lanes_ready(matrix[alive]))
                self.model.run(matrix[alive], states, d.inputs, step0=np.full(len(alive), a),
                               n_steps=b - a, record_out=out, sample_mask=d.mask, acc=acc,
                               lanes=lanes)
                self.simulated_steps += len(alive) * (b - a)
                sim = out[:, :, 0].astype(float)
                err = sim - d.measured[in_chunk]
                sse[alive] += np.sum(err * err, axis=1)
                if self.charge:
                    err = d.charge_error(sim, ratio[alive], eta[alive], in_chunk)
                    charge_sse[alive] += np.sum(err * err, axis=1)
                soc_min[alive] = np.minimum(soc_min[alive], acc[:, self.model.accumulator_names
                                                                 .index("soc_min")])
                bound = (self.fit_cost(sse[alive], charge_sse[alive]) + fixed_part[alive]
                         + penalty(SOC_FLOOR_FRAC - soc_min[alive], SOC_FLOOR_FRAC))
                keep = bound <= threshold
                if not keep.all():
                    states, acc = states[keep], acc[keep]
                    alive = alive[keep]
        self.evaluations += n
        return (self.fit_cost(sse, charge_sse) + fixed_part
                + penalty(SOC_FLOOR_FRAC - soc_min, SOC_FLOOR_FRAC))

    def fit_cost(self, sse: np.ndarray, charge_sse: np.ndarray) -> np.ndarray:
        """The NRMSE of the SoC from its sum of squared errors; with ``charge``, the rms of it
        and the NRMSE of the counted charge."""
        nrmse = np.sqrt(sse / self.n_samples) / self.span
        if not self.charge:
            return nrmse
        charge = np.sqrt(charge_sse / self.n_samples) / self.charge_span
        return np.sqrt(0.5 * (nrmse**2 + charge**2))

    def residuals(self, u: np.ndarray) -> np.ndarray:
        """Scaled residuals (n, n_samples), (sim - meas) / (span sqrt(n_samples)), whose norm
        is the NRMSE (with ``charge``, the counted charge's scaled by its span follow, and the
        norm is the cost's rms of the two): for least-squares polishing and the Jacobian (no
        penalties)."""
        matrix = self.params(u)
        parts, charges = [], []
        scale = 1.0 / (np.sqrt(self.n_samples) * self.span)
        if self.charge:
            ratio = capacity_ah(self.model, matrix) / self.capacity_ah
            eta = coulombic_efficiency(self.model, matrix)
        for d in self.data:
            sim = self.simulate(d, matrix)
            parts.append((sim - d.measured) * scale)
            if self.charge:
                charges.append(d.charge_error(sim, ratio, eta)
                               / (np.sqrt(self.n_samples) * self.charge_span))
        self.evaluations += len(matrix)
        if self.charge:
            return np.sqrt(0.5) * np.concatenate(parts + charges, axis=1)
        return np.concatenate(parts, axis=1)

    def charge_nrmse(self, sims: Sequence[np.ndarray], params: np.ndarray) -> float:
        """NRMSE of the counted charge for one parameter vector, from its simulated SoC at
        each profile's compared samples (``sims``, one array per profile)."""
        matrix = params[None, :]
        ratio = capacity_ah(self.model, matrix) / self.capacity_ah
        eta = coulombic_efficiency(self.model, matrix)
        err = np.concatenate([d.charge_error(np.asarray(sim, float)[None, :], ratio, eta)[0]
                              for d, sim in zip(self.data, sims, strict=True)])
        return float(np.sqrt(np.mean(err * err)) / self.charge_span)

    def simulate(self, d: _Data, matrix: np.ndarray) -> np.ndarray:
        """(n, n_samples) simulated SoC of parameter rows at a profile's compared samples."""
        states = np.array([self.model.initial_state(row, d.first, d.soc_start, **d.initial)
                           for row in matrix])
        out = np.zeros((len(matrix), len(d.rows), 1), np.float32)
        edges = d.edges(1)
        done = 0
        for a, b in zip(edges[:-1], edges[1:], strict=True):
            d.anchor(a, states, self.soc_index)
            n_out = int(np.count_nonzero((d.rows >= a) & (d.rows < b)))
            part = np.zeros((len(matrix), max(n_out, 1), 1), np.float32)
            self.model.run(matrix, states, d.inputs, step0=np.full(len(matrix), a),
                           n_steps=b - a, record_out=part, sample_mask=d.mask)
            out[:, done:done + n_out] = part[:, :n_out]
            done += n_out
        self.simulated_steps += len(matrix) * d.inputs.shape[1]
        return out[:, :, 0].astype(float)

    def noise_nrmse(self) -> float:
        """The NRMSE a perfect model would still have: the SoC log's own resolution and noise.

        Quantisation to steps q leaves q / sqrt(12); white noise of standard deviation s shows
        in second differences of the samples as s sqrt(6). The larger of the two, over the
        measured range, is the floor."""
        floors = []
        for d in self.data:
            steps = np.abs(np.diff(d.measured))
            steps = steps[steps > 1e-9]
            quantum = float(np.min(steps)) if steps.size else 0.0
            white = float(np.std(np.diff(d.measured, 2)) / np.sqrt(6.0)) if len(d.measured) > 3 \
                else 0.0
            floors.append(max(quantum / np.sqrt(12.0), white))
        return float(np.max(floors)) / self.span

    # -- reporting -------------------------------------------------------------------------
    def named(self, u: np.ndarray) -> dict[str, float]:
        return dict(zip(self.free, self.values(np.atleast_2d(u))[0].tolist(), strict=True))
