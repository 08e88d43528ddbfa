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

Large batches are split over threads (the compiled passes release the GIL). Per-bus
bookkeeping lives in ``book`` (columns ``BOOK``), the decision's figures in ``out``
(columns ``OUT``), the reward's quantities in ``quantities`` (columns
:data:`ebus_env.envs.reward.QUANTITIES`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numba
import numpy as np

from ebus_env.config import load_bus
from ebus_env.effects.vehicle import COMMUTER_SHAPE
from ebus_env.envs import reference_vehicle as reference
from ebus_env.envs.course import Course, course_from_cycle, course_from_log, course_from_route
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

# constants of a batch, in one array for the compiled passes
CONST = ("start_time_h", "service_h", "ambient_amplitude_k", "reserve_soc_pct",
         "charge_at_terminal", "lap_period_s", "layover_min_s", "jerk_mps3", "decel_mps2",
         "dt_s", "charger_w", "length_m", "step_m", "soc_min", "at_stops")
(C_START, C_SERVICE, C_AMPLITUDE, C_RESERVE, C_CHARGE, C_PERIOD, C_LAYOVER,
 C_JERK, C_DECEL, C_DT, C_CHARGER, C_LENGTH, C_STEP, C_SOC_MIN, C_AT_STOPS) = range(len(CONST))
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

@numba.njit(cache=True, nogil=True)
def ambient_degc(mean_degc, amplitude_k, hour):
    """Daily cycle: coldest at 05:00, warmest at 15:00, half-cosines between."""
    since = (hour - 5.0) % 24.0
    if since <= 10.0:
        return mean_degc - amplitude_k * math.cos(math.pi * since / 10.0)
    return mean_degc + amplitude_k * math.cos(math.pi * (since - 10.0) / 14.0)


@numba.njit(cache=True, nogil=True)
def passengers(capacity, base_frac, peak_frac, hour):
    """Commuter day (``COMMUTER_SHAPE``): ``base`` between peaks, ``peak`` at 07:30-09:00
    and 16:30-18:00, as fractions of the capacity."""
    return capacity * (base_frac + (peak_frac - base_frac) * np.interp(hour, SHAPE_H, SHAPE))


@numba.njit(cache=True, nogil=True, inline="always")
def _elapsed_h(book_b, const):
    return book_b[ELAPSED_ROWS] * const[C_DT] / 3600.0


@numba.njit(cache=True, nogil=True, inline="always")
def _hour(book_b, const):
    return (const[C_START] + _elapsed_h(book_b, const)) % 24.0


@numba.njit(cache=True, nogil=True, inline="always")
def _service_left_h(book_b, const):
    return max(const[C_SERVICE] - _elapsed_h(book_b, const), 0.0)


@numba.njit(cache=True, nogil=True)
def _before(lo, hi, values, book, params, states, ref, inputs, const, at, row_h, speed, grade,
            stop_m, dwell_s, rows_at, n_rows, rows):
    """Actions in physical units ``values`` (N, 5) -> parameters, input rows, reference, and
    the rows of the decision of each bus (``rows``: ``n_rows``, or fewer to the next stop)."""
    for b in range(lo, hi):
        bk = book[b]
        hour = _hour(bk, const)
        if at[P_SETPOINT] >= 0:
            params[b, at[P_SETPOINT]] = values[b, 2]
        if at[P_PULSE] >= 0:
            params[b, at[P_PULSE]] = values[b, 4]
        bk[LAP_BEFORE] = ref[b, reference.LAP]
        bk[CABIN_BEFORE] = states[b, at[S_CABIN]] if at[S_CABIN] >= 0 else math.nan
        bk[DISTANCE_BEFORE] = states[b, at[S_DISTANCE]]
        rows[b] = reference.advance_one(
            ref[b], speed, grade, const[C_STEP], stop_m, dwell_s, values[b, 0] / 3.6,
            values[b, 1], const[C_JERK], const[C_DECEL], const[C_PERIOD], const[C_LAYOVER],
            const[C_CHARGE], values[b, 3] * const[C_CHARGER], const[C_DT], n_rows, inputs[b],
            rows_at, const[C_AT_STOPS] > 0.0)
        if at[IN_AMBIENT] >= 0:
            inputs[b, at[IN_AMBIENT], :] = ambient_degc(bk[AMBIENT_MEAN], const[C_AMPLITUDE], hour)
        if at[IN_PASSENGERS] >= 0:
            inputs[b, at[IN_PASSENGERS], :] = passengers(bk[CAPACITY], bk[PASSENGERS_BASE],
                                                         bk[PASSENGERS_PEAK], hour)
        if at[IN_TIME] >= 0:
            for r in range(n_rows):
                inputs[b, at[IN_TIME], r] = (hour + row_h[r]) % 24.0


@numba.njit(cache=True, nogil=True)
def _observe(b, book, states, ref, const, at, speed, grade, baseline_s, dwell_s, obs):
    """The observation of bus ``b`` (``OBSERVATIONS``) into ``obs[b]``."""
    bk = book[b]
    hour = _hour(bk, const)
    ambient = ambient_degc(bk[AMBIENT_MEAN], const[C_AMPLITUDE], hour)
    people = passengers(bk[CAPACITY], bk[PASSENGERS_BASE], bk[PASSENGERS_PEAK], hour)
    low, high = comfort_band_degc(ambient, people, bk[CAPACITY])
    r = ref[b]
    i = min(int(r[reference.S] / const[C_STEP]), len(speed) - 1)
    on_layover = r[reference.MODE] == reference.LAYOVER
    delay_s = reference.schedule_delay_s(r, baseline_s, dwell_s, const[C_STEP], const[C_PERIOD])
    values = (states[b, at[S_SOC]], states[b, at[S_CABIN]] if at[S_CABIN] >= 0 else 0.0,
              ambient, people, 3.6 * states[b, at[S_SPEED]], hour,
              0.0 if on_layover else (const[C_LENGTH] - r[reference.S]) / 1e3,
              delay_s / 60.0, 1.0 if on_layover and const[C_CHARGE] > 0.0 else 0.0,
              3.6 * speed[i], 100.0 * grade[i],
              _service_left_h(bk, const), low, high, bk[PEAK_KW],
              r[reference.TIMER] / 60.0 if on_layover else 0.0)
    for k in range(len(values)):
        v = values[k]
        if not math.isfinite(v):
            v = 0.0
        obs[b, k] = min(max(v, OBS_LOW[k]), OBS_HIGH[k])
    return delay_s


@numba.njit(cache=True, nogil=True)
def _after(lo, hi, book, states, ref, acc, load_cols, const, at, speed, grade, baseline_s,
           dwell_s, rows, obs, quantities, out):
    """Score the decision just run (``quantities``, ``out``) and observe the new state."""
    for b in range(lo, hi):
        bk = book[b]
        a = acc[b]
        hours = rows[b] * const[C_DT] / 3600.0
        hour = _hour(bk, const)
        ambient = ambient_degc(bk[AMBIENT_MEAN], const[C_AMPLITUDE], hour)
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
        deficit = max(const[C_RESERVE] - 100.0 * soc, 0.0) * hours
        # an empty pack (at its SoC floor, or short of power) ends the bus's service early
        empty = a[at[A_SHORTFALL]] > 0.0 or soc <= const[C_SOC_MIN]
        q = quantities[b]
        q[0] = chemical_j / J_PER_KWH
        q[1] = grid_kwh
        q[2] = rise_kw
        q[3] = outside_k * hours
        q[4] = late_min
        q[5] = deficit
        bk[DECISION] += 1.0
        bk[ELAPSED_ROWS] += rows[b]
        q[6] = _service_left_h(bk, const) if empty else 0.0
        delay_s = _observe(b, book, states, ref, const, at, speed, grade, baseline_s, dwell_s,
                           obs)
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


def course_of(cfg) -> Course:
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

    ``params`` (n, n_params), ``states`` (n, n_states): the model's; ``ref`` (n, 9): the
    reference vehicles; ``inputs`` (n, n_inputs, n_rows): the last decision's input rows;
    ``acc`` (n, n_acc): its energy sums [J]. ``offsets_s``: each bus's first departure after
    the start of service (a fleet's headways); the buses wait on the charger until then.
    """

    def __init__(self, cfg, n: int, offsets_s: np.ndarray | None = None):
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

        def index(names, name):
            return names.index(name) if name in names else -1

        def of_any_effect(param):  # a parameter whichever effect fills its slot
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
        self.const = np.zeros(len(CONST))
        self.const[:] = (cfg.start_time_h, cfg.service_h,
                         cfg.ambient_amplitude_k, cfg.reserve_soc_pct,
                         1.0 if cfg.charge_at_terminal else 0.0, self.lap_period_s,
                         60.0 * cfg.min_layover_min, cfg.jerk_mps3, cfg.comfort_decel_mps2,
                         cfg.dt_s, 1e3 * charger_kw, c.length_m, c.step_m,
                         m.params[soc_min_at] if soc_min_at >= 0 else 0.0,
                         1.0 if cfg.decide_at_stops else 0.0)
        self._row_h = np.arange(self.n_rows) * cfg.dt_s / 3600.0
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
        self.values = np.zeros((n, 5))
        self._kernel = m.kernel("run")
        self._input_set = np.arange(n, dtype=np.int64)
        self._step0 = np.zeros(n, np.int64)
        self.rows = np.full(n, self.n_rows, np.int64)  # of each bus's last decision
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
        bk[AMBIENT_MEAN] = cfg.ambient_mean_degc + rng.uniform(-1, 1) * cfg.ambient_random_k
        r = cfg.passengers_random_frac
        base = float(np.clip(cfg.passengers_base_frac + rng.uniform(-r, r), 0.0, 1.0))
        bk[PASSENGERS_BASE] = base
        bk[PASSENGERS_PEAK] = float(np.clip(cfg.passengers_peak_frac + rng.uniform(-r, r),
                                            base, 1.0))
        self.params[b] = m.params
        bk[CAPACITY] = self.capacity
        self.ref[b] = reference.new_state(self.offsets_s[b])
        first = {"speed_ref_mps": 0.0,
                 "ambient_degc": float(ambient_degc(bk[AMBIENT_MEAN], cfg.ambient_amplitude_k,
                                                    cfg.start_time_h % 24.0))}
        self.states[b] = m.initial_state(self.params[b], first,
                                         soc_start=cfg.soc_start_pct / 100.0)
        self.observe(b)

    def observe(self, b: int) -> np.ndarray:
        c = self.course
        _observe(b, self.book, self.states, self.ref, self.const, self.at, c.speed_mps,
                 c.grade_frac, c.baseline_s, c.dwell_s, self.obs)
        return self.obs[b]

    # -- a decision ------------------------------------------------------------------------
    def step(self, values: np.ndarray) -> None:
        """One decision of every bus, actions in physical units ``values`` (n, 5) (columns
        as ``ACTIONS``); results in ``obs``, ``quantities``, ``out``, ``acc``."""
        self.values[:] = values
        run_chunks(self._chunk, self._edges)

    def _chunk(self, lo: int, hi: int) -> None:
        self.drive(lo, hi)
        self.run(lo, hi)

    def drive(self, lo: int, hi: int) -> None:
        """Pass 1: parameters, ambient, passengers and the reference rows of buses lo..hi-1."""
        c = self.course
        _before(lo, hi, self.values, self.book, self.params, self.states, self.ref, self.inputs,
                self.const, self.at, self._row_h, c.speed_mps, c.grade_frac, c.stop_m,
                c.dwell_s, self.rows_at, self.n_rows, self.rows)

    def run(self, lo: int, hi: int) -> None:
        """Passes 2 and 3: the physics of buses lo..hi-1, then score and observe them."""
        c = self.course
        self.acc[lo:hi] = 0.0
        self._kernel(self.params, self.states, self.inputs, self._input_set, self._step0,
                     self.rows, self.config.dt_s, 0, self._no_sel, self._no_rec,
                     self._no_mask, self.acc, lo, hi)
        _after(lo, hi, self.book, self.states, self.ref, self.acc, self._load_cols, self.const,
               self.at, c.speed_mps, c.grade_frac, c.baseline_s, c.dwell_s, self.rows,
               self.obs, self.quantities, self.out)

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
        floor_pct = 100.0 * self.const[C_SOC_MIN]
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
