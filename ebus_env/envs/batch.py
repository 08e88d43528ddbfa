"""The buses behind the environments, in arrays: N buses of one env config advanced together.

``EBus-v0`` is a batch of one, its native vector env a batch of ``num_envs`` and each line of
``EBusFleet-v0`` a batch of its buses: all run the same code, so they agree step for step.
A decision is three compiled passes over the buses:

1. ``_before``: map the actions, set the day's ambient and passengers, drive the reference
   vehicles (:mod:`ebus_env.envs.reference_vehicle`) under the caps, writing the model's input rows;
2. the bus model's kernel (:mod:`ebus_env.model`): the physics at ``dt_s``, all buses in one
   call;
3. ``_after``: energy, peak, comfort, delay and reserve of the decision, and the new
   observation.

Large batches are split over threads (the compiled passes release the GIL). The passes take
the buses as one typed struct, :class:`BatchArrays` (a numba ``structref``: fields by name,
passed by reference), whose docstring is the one place that says which array carries what;
``_before`` also takes the decision's actions, passed down from :meth:`BusBatch.step`.
Per-bus bookkeeping lives in ``book`` (columns ``BOOK``), the decision's figures in ``out``
(columns ``OUT``), the reward's quantities in ``quantities`` (columns
:data:`ebus_env.envs.reward.QUANTITIES`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numba
import numpy as np
from numba.core import types
from numba.experimental import structref

from ebus_env.config import load_bus
from ebus_env.effects.vehicle import COMMUTER_SHAPE
from ebus_env.envs import reference_vehicle as reference
from ebus_env.envs.course import Course, course_from_cycle, course_from_log, course_from_route
from ebus_env.envs.env_config import EnvConfig
from ebus_env.envs.reward import QUANTITIES, comfort_band_degc
from ebus_env.errors import CompositionError, ConfigError
from ebus_env.model.threads import default_threads, run_chunks
from ebus_env.units import J_PER_KWH

OBSERVATIONS = (  # name, unit, low, high
    ("soc", "1", 0.0, 1.0),
    ("cabin_temp_degc", "degC", -40.0, 60.0),
    ("ambient_degc", "degC", -40.0, 50.0),
    ("passengers", "1", 0.0, 250.0),
    ("speed_kmh", "km/h", 0.0, 120.0),
    ("time_of_day_h", "h", 0.0, 24.0),
    ("distance_to_charger_km", "km", 0.0, 200.0),
    ("schedule_delay_min", "min", -60.0, 60.0),
    ("charger_connected", "1", 0.0, 1.0),
    ("course_speed_kmh", "km/h", 0.0, 120.0),
    ("grade_pct", "%", -20.0, 20.0),
    ("service_left_h", "h", 0.0, 24.0),
    ("comfort_low_degc", "degC", -40.0, 60.0),
    ("comfort_high_degc", "degC", -40.0, 60.0),
    ("peak_grid_kw", "kW", 0.0, 5000.0),
    ("layover_left_min", "min", 0.0, 600.0),
)
OBS_LOW = np.array([o[2] for o in OBSERVATIONS], np.float32)
OBS_HIGH = np.array([o[3] for o in OBSERVATIONS], np.float32)

BOOK = ("ambient_mean_degc", "passengers_base_frac", "passengers_peak_frac", "capacity",
        "decision", "peak_grid_kw", "departure_delay_s", "cabin_before_degc",
        "distance_before_m", "lap_before", "elapsed_rows")
(AMBIENT_MEAN, PASSENGERS_BASE, PASSENGERS_PEAK, CAPACITY, DECISION, PEAK_KW, DEP_DELAY,
 CABIN_BEFORE, DISTANCE_BEFORE, LAP_BEFORE, ELAPSED_ROWS) = range(len(BOOK))
OUT = ("battery_kwh", "grid_kwh", "grid_kw", "peak_grid_kw", "peak_grid_kw_in_step",
       "battery_shortfall_kwh", "schedule_delay_min", "distance_km", "comfort_low_degc",
       "comfort_high_degc", "ambient_degc", "passengers", "empty", "duration_s")
_OUT = {name: i for i, name in enumerate(OUT)}

# indices into the model's arrays (-1: the model has no such input/parameter/state)
AT = ("in_ambient", "in_passengers", "in_time", "p_setpoint", "p_pulse", "s_soc", "s_speed",
      "s_cabin", "s_distance", "a_motor", "a_charger", "a_shortfall", "a_ohmic",
      "a_coulombic", "a_grid", "a_peak_grid")
(IN_AMBIENT, IN_PASSENGERS, IN_TIME, P_SETPOINT, P_PULSE, S_SOC, S_SPEED, S_CABIN, S_DISTANCE,
 A_MOTOR, A_CHARGER, A_SHORTFALL, A_OHMIC, A_COULOMBIC, A_GRID, A_PEAK_GRID) = range(len(AT))
SHAPE_H = np.array(COMMUTER_SHAPE.presets["commuter"].x, float)
SHAPE = np.array(COMMUTER_SHAPE.presets["commuter"].y, float)
_CONNECTED = reference.ROW_NAMES.index("charger_connected")
_RATING = reference.ROW_NAMES.index("charger_rating_w")
THREADS_FROM = 16  # buses per batch from which a decision is split over threads


@structref.register
class BatchArraysType(types.StructRef):
    """numba's type of a :class:`BatchArrays`."""


class BatchArrays(structref.StructRefProxy):
    """What the compiled passes of a :class:`BusBatch` read and write, by name: the one place
    that says which array carries what. Row ``b`` of a per-bus array is bus ``b``; the arrays
    are the batch's own (``BusBatch.states`` is ``states`` here), changed in place only. Made
    by :class:`BusBatch`; the fields are read in compiled code only; ``BATCH_ARRAYS`` gives
    their numba types, in this order. Where the model has no such input, parameter, state or
    accumulator, an index is -1.
    """

    # -- per bus (n rows), written by the passes and the model's kernel
    params: np.ndarray  # (n, n_params): the model's parameters (the actions set setpoint, duty)
    states: np.ndarray  # (n, n_states): the model's states
    ref: np.ndarray  # (n, len(reference_vehicle.STATE_NAMES)): the reference vehicles
    inputs: np.ndarray  # (n, n_inputs, n_rows): the decision's input rows
    acc: np.ndarray  # (n, n_accumulators): the decision's energy sums [J] and extremes
    book: np.ndarray  # (n, len(BOOK)): bookkeeping between decisions, columns BOOK
    rows: np.ndarray  # (n,) int64: the rows of each bus's last decision
    obs: np.ndarray  # (n, len(OBSERVATIONS)) float32: the observations
    quantities: np.ndarray  # (n, len(reward.QUANTITIES)): the reward's quantities
    out: np.ndarray  # (n, len(OUT)): the decision's figures
    # -- where the model keeps what the passes use
    at: np.ndarray  # (len(AT),) int64: index of each AT name in the model's inputs (in_),
    #                 parameters (p_), states (s_) or accumulators (a_)
    rows_at: np.ndarray  # (len(reference_vehicle.ROW_NAMES),) int64: the input of each channel
    load_cols: np.ndarray  # int64: the accumulators of the DC loads
    # -- constants
    track: reference.Track  # the course
    drive: reference.Driving  # how it is run
    n_rows: int  # the rows of a whole decision
    row_h: np.ndarray  # (n_rows,): each row's time from the decision's start [h]
    start_time_h: float  # the start of service [h]
    service_h: float  # the length of service [h]
    ambient_amplitude_k: float  # the day's ambient swing [K]
    reserve_soc_pct: float  # the SoC reserve below which the reward charges a deficit [%]
    charger_w: float  # the terminal charger's rating [W]
    soc_min_frac: float  # the pack's SoC floor [1] (0: none)


structref.define_boxing(BatchArraysType, BatchArrays)
_F64_2D, _F64_1D, _I64_1D = types.float64[:, ::1], types.float64[::1], types.int64[::1]
BATCH_ARRAYS = BatchArraysType([
    ("params", _F64_2D), ("states", _F64_2D), ("ref", _F64_2D),
    ("inputs", types.float64[:, :, ::1]), ("acc", _F64_2D), ("book", _F64_2D),
    ("rows", _I64_1D), ("obs", types.float32[:, ::1]), ("quantities", _F64_2D),
    ("out", _F64_2D), ("at", _I64_1D), ("rows_at", _I64_1D), ("load_cols", _I64_1D),
    ("track", reference.TRACK), ("drive", reference.DRIVING), ("n_rows", types.int64),
    ("row_h", _F64_1D), ("start_time_h", types.float64), ("service_h", types.float64),
    ("ambient_amplitude_k", types.float64), ("reserve_soc_pct", types.float64),
    ("charger_w", types.float64), ("soc_min_frac", types.float64)])


@numba.njit(cache=True)
def _new_batch_arrays(params: np.ndarray, states: np.ndarray, ref: np.ndarray,
                      inputs: np.ndarray, acc: np.ndarray, book: np.ndarray, rows: np.ndarray,
                      obs: np.ndarray, quantities: np.ndarray, out: np.ndarray, at: np.ndarray,
                      rows_at: np.ndarray, load_cols: np.ndarray, track: reference.Track,
                      drive: reference.Driving, n_rows: int, row_h: np.ndarray,
                      start_time_h: float, service_h: float, ambient_amplitude_k: float,
                      reserve_soc_pct: float, charger_w: float,
                      soc_min_frac: float) -> BatchArrays:
    d: BatchArrays = structref.new(BATCH_ARRAYS)  # type: ignore[call-arg]  # (numba's typing)
    d.params, d.states, d.ref, d.inputs, d.acc, d.book = params, states, ref, inputs, acc, book
    d.rows, d.obs, d.quantities, d.out = rows, obs, quantities, out
    d.at, d.rows_at, d.load_cols = at, rows_at, load_cols
    d.track, d.drive, d.n_rows, d.row_h = track, drive, n_rows, row_h
    d.start_time_h, d.service_h, d.ambient_amplitude_k = (start_time_h, service_h,
                                                          ambient_amplitude_k)
    d.reserve_soc_pct, d.charger_w, d.soc_min_frac = reserve_soc_pct, charger_w, soc_min_frac
    return d


@numba.njit(cache=True, nogil=True)
def ambient_degc(mean_degc: float, amplitude_k: float, hour: float) -> float:
    """Daily cycle: coldest at 05:00, warmest at 15:00, half-cosines between."""
    since = (hour - 5.0) % 24.0
    if since <= 10.0:
        return mean_degc - amplitude_k * math.cos(math.pi * since / 10.0)
    return mean_degc + amplitude_k * math.cos(math.pi * (since - 10.0) / 14.0)


@numba.njit(cache=True, nogil=True)
def passengers(capacity: float, base_frac: float, peak_frac: float, hour: float) -> float:
    """Commuter day (``COMMUTER_SHAPE``): ``base`` between peaks, ``peak`` at 07:30-09:00
    and 16:30-18:00, as fractions of the capacity."""
    return capacity * (base_frac + (peak_frac - base_frac) * np.interp(hour, SHAPE_H, SHAPE))


@numba.njit(cache=True, nogil=True, inline="always")
def _elapsed_h(book_b: np.ndarray, dt_s: float) -> float:
    return book_b[ELAPSED_ROWS] * dt_s / 3600.0


@numba.njit(cache=True, nogil=True, inline="always")
def _hour(book_b: np.ndarray, start_time_h: float, dt_s: float) -> float:
    return (start_time_h + _elapsed_h(book_b, dt_s)) % 24.0


@numba.njit(cache=True, nogil=True, inline="always")
def _service_left_h(book_b: np.ndarray, service_h: float, dt_s: float) -> float:
    return max(service_h - _elapsed_h(book_b, dt_s), 0.0)


@numba.njit(cache=True, nogil=True)
def _before(lo: int, hi: int, values: np.ndarray, d: BatchArrays) -> None:
    """Pass 1 over buses ``lo..hi-1`` of ``d`` (:class:`BatchArrays`): actions in physical
    units ``values`` (n, 5, columns as ``ACTIONS``) -> parameters, the reference vehicle's
    input rows, ambient, passengers and time of day, and the rows of each bus's decision
    (``rows``: ``n_rows``, or fewer to the next stop)."""
    book, params, states, ref, inputs, rows = d.book, d.params, d.states, d.ref, d.inputs, d.rows
    at, rows_at, row_h, n_rows = d.at, d.rows_at, d.row_h, d.n_rows
    track, drive = d.track, d.drive
    dt_s, start_h, amplitude_k, charger_w = drive.dt_s, d.start_time_h, d.ambient_amplitude_k, \
        d.charger_w
    for b in range(lo, hi):
        bk = book[b]
        hour = _hour(bk, start_h, dt_s)
        if at[P_SETPOINT] >= 0:
            params[b, at[P_SETPOINT]] = values[b, 2]
        if at[P_PULSE] >= 0:
            params[b, at[P_PULSE]] = values[b, 4]
        bk[LAP_BEFORE] = ref[b, reference.LAP]
        bk[CABIN_BEFORE] = states[b, at[S_CABIN]] if at[S_CABIN] >= 0 else math.nan
        bk[DISTANCE_BEFORE] = states[b, at[S_DISTANCE]]
        rows[b] = reference.advance_one(ref[b], track, drive, values[b, 0] / 3.6, values[b, 1],
                                        values[b, 3] * charger_w, n_rows, inputs[b], rows_at)
        if at[IN_AMBIENT] >= 0:
            inputs[b, at[IN_AMBIENT], :] = ambient_degc(bk[AMBIENT_MEAN], amplitude_k, hour)
        if at[IN_PASSENGERS] >= 0:
            inputs[b, at[IN_PASSENGERS], :] = passengers(bk[CAPACITY], bk[PASSENGERS_BASE],
                                                         bk[PASSENGERS_PEAK], hour)
        if at[IN_TIME] >= 0:
            for r in range(n_rows):
                inputs[b, at[IN_TIME], r] = (hour + row_h[r]) % 24.0


@numba.njit(cache=True, nogil=True)
def _observe(b: int, d: BatchArrays) -> float:
    """The observation of bus ``b`` of ``d`` (``OBSERVATIONS``) into ``d.obs[b]``; returns its
    schedule delay [s]."""
    bk, states, at, track, drive = d.book[b], d.states, d.at, d.track, d.drive
    speed, grade = track.speed_mps, track.grade_frac
    hour = _hour(bk, d.start_time_h, drive.dt_s)
    ambient = ambient_degc(bk[AMBIENT_MEAN], d.ambient_amplitude_k, hour)
    people = passengers(bk[CAPACITY], bk[PASSENGERS_BASE], bk[PASSENGERS_PEAK], hour)
    low, high = comfort_band_degc(ambient, people, bk[CAPACITY])
    r = d.ref[b]
    i = min(int(r[reference.S] / track.step_m), len(speed) - 1)
    on_layover = r[reference.MODE] == reference.LAYOVER
    delay_s = reference.schedule_delay_s(r, track, drive.lap_period_s)
    values = (states[b, at[S_SOC]], states[b, at[S_CABIN]] if at[S_CABIN] >= 0 else 0.0,
              ambient, people, 3.6 * states[b, at[S_SPEED]], hour,
              0.0 if on_layover else (track.length_m - r[reference.S]) / 1e3,
              delay_s / 60.0, 1.0 if on_layover and drive.charge_at_terminal > 0.0 else 0.0,
              3.6 * speed[i], 100.0 * grade[i],
              _service_left_h(bk, d.service_h, drive.dt_s), low, high, bk[PEAK_KW],
              r[reference.TIMER] / 60.0 if on_layover else 0.0)
    obs = d.obs
    for k in range(len(values)):
        v = values[k]
        if not math.isfinite(v):
            v = 0.0
        obs[b, k] = min(max(v, OBS_LOW[k]), OBS_HIGH[k])
    return delay_s


@numba.njit(cache=True, nogil=True)
def _after(lo: int, hi: int, d: BatchArrays) -> None:
    """Pass 3 over buses ``lo..hi-1`` of ``d`` (:class:`BatchArrays`), after the model's
    kernel: score the decision just run (``quantities``, ``out``) and observe the new state."""
    book, states, ref, acc, rows = d.book, d.states, d.ref, d.acc, d.rows
    quantities, out, at, load_cols = d.quantities, d.out, d.at, d.load_cols
    dt_s, start_h, service_h, amplitude_k = d.drive.dt_s, d.start_time_h, d.service_h, \
        d.ambient_amplitude_k
    reserve_soc_pct, soc_min_frac = d.reserve_soc_pct, d.soc_min_frac
    for b in range(lo, hi):
        bk = book[b]
        a = acc[b]
        hours = rows[b] * dt_s / 3600.0
        hour = _hour(bk, start_h, dt_s)
        ambient = ambient_degc(bk[AMBIENT_MEAN], amplitude_k, hour)
        people = passengers(bk[CAPACITY], bk[PASSENGERS_BASE], bk[PASSENGERS_PEAK], hour)
        # battery chemical energy = motor + DC loads - charger - shortfall + ohmic + coulombic
        chemical_j = a[at[A_MOTOR]] - a[at[A_CHARGER]] - a[at[A_SHORTFALL]] + a[at[A_OHMIC]] \
            + a[at[A_COULOMBIC]]
        for c in load_cols:
            chemical_j += a[c]
        grid_kwh = a[at[A_GRID]] / J_PER_KWH
        grid_kw = grid_kwh / hours
        rise_kw = max(grid_kw - bk[PEAK_KW], 0.0)
        bk[PEAK_KW] = max(bk[PEAK_KW], grid_kw)
        low, high = comfort_band_degc(ambient, people, bk[CAPACITY])
        outside_k = 0.0
        if at[S_CABIN] >= 0:
            cabin = 0.5 * (bk[CABIN_BEFORE] + states[b, at[S_CABIN]])
            outside_k = max(low - cabin, cabin - high, 0.0)
        late_min = 0.0
        if ref[b, reference.LAP] > bk[LAP_BEFORE]:  # departed: the delay at this departure
            new = max(ref[b, reference.DEP_DELAY], 0.0)
            late_min = max(new - bk[DEP_DELAY], 0.0) / 60.0
            bk[DEP_DELAY] = new
        soc = states[b, at[S_SOC]]
        deficit = max(reserve_soc_pct - 100.0 * soc, 0.0) * hours
        # an empty pack (at its SoC floor, or short of power) ends the bus's service early
        empty = a[at[A_SHORTFALL]] > 0.0 or soc <= soc_min_frac
        q = quantities[b]
        q[0] = chemical_j / J_PER_KWH
        q[1] = grid_kwh
        q[2] = rise_kw
        q[3] = outside_k * hours
        q[4] = late_min
        q[5] = deficit
        bk[DECISION] += 1.0
        bk[ELAPSED_ROWS] += rows[b]
        q[6] = _service_left_h(bk, service_h, dt_s) if empty else 0.0
        delay_s = _observe(b, d)
        o = out[b]
        o[0] = q[0]
        o[1] = grid_kwh
        o[2] = grid_kw
        o[3] = bk[PEAK_KW]
        o[4] = a[at[A_PEAK_GRID]] / 1e3
        o[5] = a[at[A_SHORTFALL]] / J_PER_KWH
        o[6] = delay_s / 60.0
        o[7] = (states[b, at[S_DISTANCE]] - bk[DISTANCE_BEFORE]) / 1e3
        o[8] = low
        o[9] = high
        o[10] = ambient
        o[11] = people
        o[12] = 1.0 if empty else 0.0
        o[13] = 3600.0 * hours


def course_of(cfg: EnvConfig) -> Course:
    """The line of an env config: laps of a cycle (about an hour between layovers unless
    ``laps_per_trip``), a King County route or a measured log's speed profile."""
    if cfg.route and cfg.log:
        raise ConfigError(f"route = {cfg.route!r} and log = {cfg.log!r}: give one line.")
    if cfg.route:
        return course_from_route(cfg.route)
    if cfg.log:
        return course_from_log(cfg.log, cfg.log_columns)
    if not cfg.cycle:
        raise ConfigError("An env config needs a 'cycle', a 'route' or a 'log'.")
    from ebus_env.cycles import load_cycle

    lap = load_cycle(cfg.cycle)
    laps = cfg.laps_per_trip or max(1, int(round(3600.0 / lap.duration_s)))
    trip = lap
    for _ in range(laps - 1):
        trip = trip.then(lap)
    return replace(course_from_cycle(trip), name=f"{laps} x {cfg.cycle}")


class BusBatch:
    """``n`` buses of one env config (:class:`ebus_env.envs.common.EnvConfig`), in arrays.

    ``params``, ``states``, ``ref``, ``inputs``, ``acc``, ``book``, ``rows``, ``obs``,
    ``quantities``, ``out``, ``at`` and ``rows_at`` are the arrays of :class:`BatchArrays`
    (``arrays``, which the compiled passes take; its docstring says what each carries):
    change them in place, never rebind them. ``offsets_s``: each bus's first departure after
    the start of service (a fleet's headways); the buses wait on the charger until then.
    """

    def __init__(self, cfg: EnvConfig, n: int, offsets_s: np.ndarray | None = None) -> None:
        if cfg.decision_s < cfg.dt_s or abs(cfg.decision_s / cfg.dt_s
                                             - round(cfg.decision_s / cfg.dt_s)) > 1e-6:
            raise ConfigError(f"decision_s = {cfg.decision_s} must be a multiple of dt_s = "
                              f"{cfg.dt_s}.")
        self.config, self.n = cfg, n
        self.bus = load_bus(cfg.bus, overlays=[cfg.overlay] if cfg.overlay else ())
        self.model = m = self.bus.build(cfg.dt_s)
        self.course = c = course_of(cfg)
        self.n_rows = int(round(cfg.decision_s / cfg.dt_s))  # the longest decision
        self.lap_period_s = c.lap_time_s + 60.0 * cfg.layover_min
        self.service_rows = cfg.service_h * 3600.0 / cfg.dt_s
        self.offsets_s = np.zeros(n) if offsets_s is None else np.asarray(offsets_s, float)
        self.energy_terms = [name for name, mode in m.layout.accumulators if mode == "sum"]
        self._energy_at = [m.accumulator_names.index(t) for t in self.energy_terms]

        def index(names: list[str], name: str) -> int:
            return names.index(name) if name in names else -1

        def of_any_effect(param: str) -> int:  # a parameter whichever effect fills its slot
            return index(m.param_names, next((p for p in m.param_names
                                              if p.endswith("." + param)), ""))

        self._capacity_at = of_any_effect("max_passengers")
        try:  # the parameters the actions set, from whichever effects offer them
            setpoint_at, pulse_at, self.power_at, self.efficiency_at = (m.handle(h) for h in (
                "cabin_setpoint_degc", "charge_pulse_duty", "charger_power_kw",
                "charger_efficiency"))
        except CompositionError as exc:
            raise ConfigError(f"Env bus '{cfg.bus}': {exc} The env's ECO actions set it.") \
                from None
        soc_min_at = of_any_effect("soc_min_frac")
        acc = m.accumulator_names
        self.at = np.array([
            index(m.input_names, "ambient_degc"), index(m.input_names, "passenger_count"),
            index(m.input_names, "time_of_day_h"), setpoint_at, pulse_at,
            index(m.state_names, "soc_frac"),
            index(m.state_names, "speed_mps"), index(m.state_names, "cabin_temp_degc"),
            index(m.state_names, "distance_m"), index(acc, "motor"), index(acc, "charger"),
            index(acc, "battery_shortfall"), index(acc, "battery_ohmic_loss"),
            index(acc, "coulombic_loss"), index(acc, "grid"), index(acc, "peak_grid")], np.int64)
        self._load_cols = np.array([acc.index(t) for t in m.layout.load_terms], np.int64)
        self.rows_at = np.array([index(m.input_names, name) for name in reference.ROW_NAMES],
                                np.int64)
        charger_kw = cfg.charger_kw if cfg.charger_kw is not None else m.params[self.power_at]
        self.charger_w = float(1e3 * charger_kw)  # the terminal charger's rating [W]
        self.soc_min_frac = float(m.params[soc_min_at]) if soc_min_at >= 0 else 0.0
        n_in = len(m.input_names)
        self.params = np.repeat(m.params[None, :], n, axis=0)
        self.states = np.zeros((n, len(m.state_names)))
        self.ref = np.zeros((n, len(reference.STATE_NAMES)))
        self.inputs = np.zeros((n, n_in, self.n_rows))  # solar stays 0
        self.acc = m.new_accumulators(n)
        self.book = np.zeros((n, len(BOOK)))
        self.obs = np.zeros((n, len(OBSERVATIONS)), np.float32)
        self.quantities = np.zeros((n, len(QUANTITIES)))
        self.out = np.zeros((n, len(OUT)))
        self.rows = np.full(n, self.n_rows, np.int64)  # of each bus's last decision
        drive = reference.driving(
            lap_period_s=self.lap_period_s, layover_min_s=60.0 * cfg.min_layover_min,
            charge_at_terminal=cfg.charge_at_terminal, jerk_mps3=cfg.jerk_mps3,
            decel_mps2=cfg.comfort_decel_mps2, dt_s=cfg.dt_s, at_stops=cfg.decide_at_stops)
        self.arrays = _new_batch_arrays(
            params=self.params, states=self.states, ref=self.ref, inputs=self.inputs,
            acc=self.acc, book=self.book, rows=self.rows, obs=self.obs,
            quantities=self.quantities, out=self.out, at=self.at, rows_at=self.rows_at,
            load_cols=self._load_cols, track=reference.track_of(c), drive=drive,
            n_rows=self.n_rows, row_h=np.arange(self.n_rows) * cfg.dt_s / 3600.0,
            start_time_h=float(cfg.start_time_h), service_h=float(cfg.service_h),
            ambient_amplitude_k=cfg.ambient_day[1],
            reserve_soc_pct=float(cfg.reserve_soc_pct), charger_w=self.charger_w,
            soc_min_frac=self.soc_min_frac)
        # the model's kernel (Model.run's arguments): each bus on its own input rows from row
        # 0 for rows[b] steps, no trace, energy sums into acc
        self._kernel = m.kernel("run")
        self._input_set = np.arange(n, dtype=np.int64)
        self._step0 = np.zeros(n, np.int64)
        self._no_sel = np.zeros(0, np.int64)
        self._no_rec = np.zeros((n, 0, 0), np.float32)
        self._no_mask = np.zeros(1, np.bool_)
        threads = default_threads() if n >= THREADS_FROM else 1
        self._edges = np.linspace(0, n, threads + 1).astype(int).tolist()

    # -- episodes --------------------------------------------------------------------------
    def reset(self, b: int, rng: np.random.Generator) -> None:
        """Start bus ``b`` on a new day drawn from ``rng``: the day's mean ambient, and the
        passenger base and peak (in that order, each uniform)."""
        cfg, m, bk = self.config, self.model, self.book[b]
        bk[:] = 0.0
        mean_degc, amplitude_k = cfg.ambient_day
        bk[AMBIENT_MEAN] = mean_degc + rng.uniform(-1, 1) * cfg.ambient_random_k
        r = cfg.passengers_random_frac
        base = float(np.clip(cfg.passengers_base_frac + rng.uniform(-r, r), 0.0, 1.0))
        bk[PASSENGERS_BASE] = base
        bk[PASSENGERS_PEAK] = float(np.clip(cfg.passengers_peak_frac + rng.uniform(-r, r),
                                            base, 1.0))
        self.params[b] = m.params
        bk[CAPACITY] = self.capacity
        self.ref[b] = reference.new_state(self.offsets_s[b])
        first = {"speed_ref_mps": 0.0,
                 "ambient_degc": float(ambient_degc(bk[AMBIENT_MEAN], amplitude_k,
                                                    cfg.start_time_h % 24.0))}
        self.states[b] = m.initial_state(self.params[b], first,
                                         soc_start=cfg.soc_start_pct / 100.0)
        self.observe(b)

    def observe(self, b: int) -> np.ndarray:
        """Bus ``b``'s observation (``OBSERVATIONS``), a row of ``obs``."""
        _observe(b, self.arrays)
        return self.obs[b]

    # -- a decision ------------------------------------------------------------------------
    def step(self, values: np.ndarray) -> None:
        """One decision of every bus, actions in physical units ``values`` (n, 5) (columns
        as ``ACTIONS``); results in ``obs``, ``quantities``, ``out``, ``acc``."""
        def chunk(lo: int, hi: int) -> None:
            self.drive(lo, hi, values)
            self.run(lo, hi)

        run_chunks(chunk, self._edges)

    def drive(self, lo: int, hi: int, values: np.ndarray) -> None:
        """Pass 1 over buses lo..hi-1 under their actions in physical units ``values``
        (n, 5): parameters, ambient, passengers and the reference rows."""
        _before(lo, hi, np.ascontiguousarray(values, dtype=np.float64), self.arrays)

    def run(self, lo: int, hi: int) -> None:
        """Passes 2 and 3: the physics of buses lo..hi-1, then score and observe them."""
        self.acc[lo:hi] = 0.0
        self._kernel(self.params, self.states, self.inputs, self._input_set, self._step0,
                     self.rows, self.config.dt_s, 0, self._no_sel, self._no_rec,
                     self._no_mask, self.acc, lo, hi)
        _after(lo, hi, self.arrays)

    # -- the charger rows a site shares ---------------------------------------------------
    @property
    def has_charger(self) -> bool:
        """Whether the bus model reads a charger's connection and rating (a site can share)."""
        return bool(self.rows_at[_CONNECTED] >= 0 and self.rows_at[_RATING] >= 0)

    @property
    def charger_efficiency(self) -> float:
        """The bus's charger efficiency (grid to pack) [1]."""
        return float(self.params[0, self.efficiency_at])

    def charger_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """Views (n, n_rows) of the last drive's charger rows: connected (0/1) and rating [W]
        (NaN off the charger), to be shared by a site before :meth:`run` (in place)."""
        return (self.inputs[:, self.rows_at[_CONNECTED], :],
                self.inputs[:, self.rows_at[_RATING], :])

    # -- results ---------------------------------------------------------------------------
    @property
    def capacity(self) -> float:
        """Passenger capacity of the bus (0 without a passenger effect)."""
        return float(self.model.params[self._capacity_at]) if self._capacity_at >= 0 else 0.0

    def decisions(self) -> np.ndarray:
        return self.book[:, DECISION]

    def elapsed_h(self) -> np.ndarray:
        """Service time run so far [h], per bus."""
        return self.book[:, ELAPSED_ROWS] * self.config.dt_s / 3600.0

    def ended(self) -> tuple[np.ndarray, np.ndarray]:
        """(battery empty, end of service) per bus, after a decision."""
        return (self.out[:, _OUT["empty"]] > 0.0,
                self.book[:, ELAPSED_ROWS] >= self.service_rows - 0.5)

    def end_reason(self, b: int) -> str:
        """Why bus ``b``'s service ended, in words ('' while it runs): an empty battery (the
        BMS opened the pack at its SoC floor, or it could not carry the loads), with the time
        of day and the distance of the day, or the end of service."""
        empty, end = self.ended()
        if not empty[b]:
            return "end of service" if end[b] else ""
        hour = (self.config.start_time_h + self.elapsed_h()[b]) % 24.0
        km = self.states[b, self.at[S_DISTANCE]] / 1e3
        soc_pct = 100.0 * self.states[b, self.at[S_SOC]]
        floor_pct = 100.0 * self.soc_min_frac
        why = (f"the BMS opened the pack at its SoC floor ({floor_pct:.0f} %)"
               if soc_pct <= floor_pct + 1e-6 else
               f"the pack could not carry the loads at {soc_pct:.1f} % SoC (its cell voltage "
               "floor)")
        return (f"battery empty at {int(hour):02d}:{int(hour * 60) % 60:02d}, {km:.1f} km into "
                f"the day: {why}")

    def column(self, name: str) -> np.ndarray:
        """A column of ``out`` by name."""
        return self.out[:, _OUT[name]]

    def breakdown_matrix_kwh(self) -> np.ndarray:
        """(n, len(energy_terms)): the last decision's energy by term [kWh]."""
        return self.acc[:, self._energy_at] / J_PER_KWH

    def breakdown_kwh(self, b: int) -> dict[str, float]:
        acc = self.acc[b].tolist()  # one bus: Python floats are quicker than a numpy gather
        return {t: acc[j] / J_PER_KWH for t, j in zip(self.energy_terms, self._energy_at, strict=True)}

    def cabin_degc(self, b: int) -> float:
        i = self.at[S_CABIN]
        return float(self.states[b, i]) if i >= 0 else float("nan")
