"""The reference a bus follows in the environments: a course driven under ECO-driving caps.

A virtual reference vehicle runs along the course (:mod:`ebus_env.envs.course`) and writes, row
by row at the model's time step, what the model's driver tracks (reference speed and its
acceleration) and what the bus meets (grade, stops with open doors, layovers on a charger)::

    v_target = min(v_course(s + max(v, 1 m/s) x 1 s), v_cap, sqrt(2 b (s_stop - s)))
    a_wanted = clip((v_target - v) / 1 s, -1.5 b, a_cap)
    a       <- a + clip(a_wanted - a, -3 j dt, j dt)      (jerk-limited ramp, paper App. B.1)

so a cap lowers the speed or the acceleration but never moves a stop: the bus stops exactly at
each stop and a lap is as long as before; it only takes longer. At the terminal the bus lays
over on a charger until the timetable's departure (at least ``layover_min_s``): the slack in
the layover absorbs delay before the next lap starts late.

One compiled function advances the reference by ``n`` rows from its state vector
(``STATE_NAMES``), or fewer: with ``at_stops`` it stops after the row in which the vehicle
departs (from a stop or a layover) or begins a layover, so that decisions fall at stops;
the environment keeps one state per bus. What it drives comes in two typed structs (numba
``structref``: named fields, passed by reference to compiled code): the course's arrays
(:class:`Track`) and how the line is run (:class:`Driving`).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba.core import types
from numba.experimental import structref

from ebus_env.envs.course import Course

STATE_NAMES = ("s_m", "v_mps", "a_mps2", "mode", "timer_s", "stop", "lap", "time_s",
               "departure_delay_s")
S, V, A, MODE, TIMER, STOP, LAP, TIME, DEP_DELAY = range(len(STATE_NAMES))
DRIVE, DWELL, LAYOVER = 0.0, 1.0, 2.0
ROW_NAMES = ("speed_ref_mps", "accel_ref_mps2", "grade_frac", "charger_connected",
             "charger_rating_w", "door_open")
LOOKAHEAD_S = 1.0
TAU_S = 1.0
ARRIVED_M = 0.3  # a stop this close, nearly standing: arrived (snapped onto it)

_VECTOR = types.float64[::1]


@structref.register
class TrackType(types.StructRef):
    """numba's type of a :class:`Track`."""


class Track(structref.StructRefProxy):
    """A course's arrays for compiled code (the fields of
    :class:`ebus_env.envs.course.Course`), made by :func:`track_of`. The fields are read in
    compiled code only; ``TRACK`` gives their numba types, in this order."""

    step_m: float  # the grid's step [m]
    length_m: float  # the terminal's position: a lap's length [m]
    speed_mps: np.ndarray  # the reference driver's speed at each grid point [m/s]
    grade_frac: np.ndarray  # the grade at each grid point [1]
    stop_m: np.ndarray  # the stops' positions [m], the last the terminal
    dwell_s: np.ndarray  # the standing time at each stop [s]
    baseline_s: np.ndarray  # the timetable: time from the lap's start to each grid point [s]


structref.define_boxing(TrackType, Track)
TRACK = TrackType([("step_m", types.float64), ("length_m", types.float64),
                   ("speed_mps", _VECTOR), ("grade_frac", _VECTOR), ("stop_m", _VECTOR),
                   ("dwell_s", _VECTOR), ("baseline_s", _VECTOR)])


@structref.register
class DrivingType(types.StructRef):
    """numba's type of a :class:`Driving`."""


class Driving(structref.StructRefProxy):
    """How the reference vehicle runs its course, for compiled code, made by :func:`driving`.
    The fields are read in compiled code only; ``DRIVING`` gives their numba types, in this
    order."""

    lap_period_s: float  # timetable time from one departure to the next (lap + layover) [s]
    layover_min_s: float  # the shortest layover [s]
    charge_at_terminal: float  # 1.0: the terminal's charger is connected on layovers, else 0.0
    jerk_mps3: float  # the driver's comfort limit on jerk [m/s^3]
    decel_mps2: float  # the driver's comfort deceleration [m/s^2]
    dt_s: float  # the row step [s]
    at_stops: bool  # end a decision at a departure or the start of a layover


structref.define_boxing(DrivingType, Driving)
DRIVING = DrivingType([("lap_period_s", types.float64), ("layover_min_s", types.float64),
                       ("charge_at_terminal", types.float64), ("jerk_mps3", types.float64),
                       ("decel_mps2", types.float64), ("dt_s", types.float64),
                       ("at_stops", types.boolean)])


@numba.njit(cache=True)
def _new_track(step_m: float, length_m: float, speed_mps: np.ndarray, grade_frac: np.ndarray,
               stop_m: np.ndarray, dwell_s: np.ndarray, baseline_s: np.ndarray) -> Track:
    t: Track = structref.new(TRACK)  # type: ignore[call-arg]  # numba passes its typing context
    t.step_m, t.length_m = step_m, length_m
    t.speed_mps, t.grade_frac, t.stop_m, t.dwell_s, t.baseline_s = (
        speed_mps, grade_frac, stop_m, dwell_s, baseline_s)
    return t


def track_of(course: Course) -> Track:
    """The arrays of ``course`` as a :class:`Track` (they are shared, not copied)."""
    def vector(x: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(x, dtype=np.float64)

    return _new_track(float(course.step_m), course.length_m, vector(course.speed_mps),
                      vector(course.grade_frac), vector(course.stop_m), vector(course.dwell_s),
                      vector(course.baseline_s))


@numba.njit(cache=True)
def _new_driving(lap_period_s: float, layover_min_s: float, charge_at_terminal: float,
                 jerk_mps3: float, decel_mps2: float, dt_s: float, at_stops: bool) -> Driving:
    d: Driving = structref.new(DRIVING)  # type: ignore[call-arg]  # numba passes its typing context
    d.lap_period_s, d.layover_min_s, d.charge_at_terminal = (lap_period_s, layover_min_s,
                                                             charge_at_terminal)
    d.jerk_mps3, d.decel_mps2, d.dt_s, d.at_stops = jerk_mps3, decel_mps2, dt_s, at_stops
    return d


def driving(*, lap_period_s: float, layover_min_s: float, charge_at_terminal: bool,
            jerk_mps3: float, decel_mps2: float, dt_s: float, at_stops: bool = False) -> Driving:
    """A :class:`Driving` from its fields (see there)."""
    return _new_driving(float(lap_period_s), float(layover_min_s),
                        1.0 if charge_at_terminal else 0.0, float(jerk_mps3),
                        float(decel_mps2), float(dt_s), bool(at_stops))


def new_state(first_departure_s: float = 0.0) -> np.ndarray:
    """At the start of service: departing on the first lap, or (``first_departure_s`` > 0)
    laying over on the charger until then (a fleet's later buses)."""
    state = np.zeros(len(STATE_NAMES))
    if first_departure_s > 0.0:
        state[MODE], state[LAP] = LAYOVER, -1.0
        state[TIMER], state[TIME] = first_departure_s, -first_departure_s
    return state


@numba.njit(cache=True, nogil=True)
def advance_one(state: np.ndarray, track: Track, drive: Driving, v_cap: float, a_cap: float,
                charger_w: float, n: int, out: np.ndarray, rows_at: np.ndarray) -> int:
    """Advance one reference ``state`` by up to ``n`` rows along ``track`` (a :class:`Track`)
    as ``drive`` (a :class:`Driving`) says, under the caps ``v_cap`` [m/s] and ``a_cap``
    [m/s^2], a charger of ``charger_w`` [W] on layovers; writes channel ``c`` of
    ``ROW_NAMES`` into ``out[rows_at[c], :]`` (-1: not written). Returns the rows written
    (``n``, or fewer with ``drive.at_stops``: see the module docstring)."""
    speed, grade, stop_m, dwell_s = track.speed_mps, track.grade_frac, track.stop_m, track.dwell_s
    step_m = track.step_m
    jerk, decel, dt = drive.jerk_mps3, drive.decel_mps2, drive.dt_s
    lap_period_s, layover_min_s = drive.lap_period_s, drive.layover_min_s
    charger_connected, at_stops = drive.charge_at_terminal, drive.at_stops
    last = len(speed) - 1
    final_stop = len(stop_m) - 1
    # the state in locals (registers) while the rows run; written back at the end
    s, v, a, mode, timer = state[S], state[V], state[A], state[MODE], state[TIMER]
    stop, lap, time_s, dep_delay = state[STOP], state[LAP], state[TIME], state[DEP_DELAY]
    c_speed, c_accel, c_grade, c_connected, c_rating, c_door = rows_at[0], rows_at[1], \
        rows_at[2], rows_at[3], rows_at[4], rows_at[5]
    per_step = 1.0 / step_m  # a multiplication where the rows' chain would wait on a division
    done = n
    for row in range(n):
        connected = 0.0
        door = 0.0
        v_next = 0.0
        boundary = False  # departing, or beginning a layover
        if mode == DRIVE:
            k = int(stop)
            remaining = stop_m[k] - s
            i = min(int((s + max(v, 1.0) * LOOKAHEAD_S) * per_step), last)
            target = min(speed[i], v_cap)
            braking = 2.0 * decel * max(remaining - ARRIVED_M, 0.0)  # v^2 that still stops
            if target * target > braking:
                target = math.sqrt(braking)
            wanted = min(max((target - v) * (1.0 / TAU_S), -1.5 * decel), a_cap)
            a = a + min(max(wanted - a, -3.0 * jerk * dt), jerk * dt)
            v_next = v + a * dt
            if v_next < 0.0:
                v_next = 0.0
                a = -v / dt
            s = s + 0.5 * (v + v_next) * dt
            if s >= stop_m[k] or (stop_m[k] - s < ARRIVED_M and v_next < 0.1):
                s = stop_m[k]
                v_next = 0.0
                a = 0.0
                mode = DWELL
                timer = dwell_s[k]
        elif mode == DWELL:  # standing at a stop, doors open
            door = 1.0
            timer -= dt
            if timer <= 0.0:
                k = int(stop)
                if k == final_stop:  # the terminal: lay over until the timetable's departure
                    departure = (lap + 1.0) * lap_period_s
                    mode = LAYOVER
                    timer = max(layover_min_s, departure - (time_s + dt))
                else:
                    stop = k + 1.0
                    mode = DRIVE
                boundary = True
        else:  # layover at the terminal
            connected = charger_connected
            timer -= dt
            if timer <= 0.0:
                lap += 1.0
                s = 0.0
                stop = 0.0
                mode = DRIVE
                dep_delay = time_s + dt - lap * lap_period_s
                boundary = True
        if c_speed >= 0:
            out[c_speed, row] = v
        if c_accel >= 0:
            out[c_accel, row] = (v_next - v) * (1.0 / dt)
        if c_grade >= 0:
            out[c_grade, row] = grade[min(int(s * per_step), last)]
        if c_connected >= 0:
            out[c_connected, row] = connected
        if c_rating >= 0:
            out[c_rating, row] = charger_w if connected > 0.0 else math.nan
        if c_door >= 0:
            out[c_door, row] = door
        v = v_next
        time_s += dt
        if at_stops and boundary:
            done = row + 1
            break
    state[S], state[V], state[A], state[MODE], state[TIMER] = s, v, a, mode, timer
    state[STOP], state[LAP], state[TIME], state[DEP_DELAY] = stop, lap, time_s, dep_delay
    return done


def advance(states: np.ndarray, speed: np.ndarray, grade: np.ndarray, step_m: float,
            stop_m: np.ndarray, dwell_s: np.ndarray, v_cap: np.ndarray, a_cap: np.ndarray,
            jerk: float, decel: float, lap_period_s: float, layover_min_s: float,
            charger_connected: float, charger_w: np.ndarray, dt: float, n: int,
            inputs: np.ndarray, rows_at: np.ndarray) -> None:
    """Advance the reference of each bus ``b`` by ``n`` rows of ``dt`` from ``states[b]``
    (updated in place), writing its rows into ``inputs[b, rows_at[c], :n]`` for each
    channel ``c`` of ``ROW_NAMES`` (-1: the model does not read it), on a course given by its
    arrays. Per bus: ``v_cap``, ``a_cap``, ``charger_w``; ``lap_period_s``: timetable time from
    one departure to the next (lap plus scheduled layover). A loop over :func:`advance_one`,
    for tests and scripts; the environments call that in their compiled passes."""
    speed = np.ascontiguousarray(speed, dtype=np.float64)
    track = _new_track(float(step_m), float(stop_m[-1]), speed,
                       np.ascontiguousarray(grade, dtype=np.float64),
                       np.ascontiguousarray(stop_m, dtype=np.float64),
                       np.ascontiguousarray(dwell_s, dtype=np.float64),
                       np.zeros_like(speed))  # no timetable: advancing does not read it
    drive = _new_driving(float(lap_period_s), float(layover_min_s), float(charger_connected),
                         float(jerk), float(decel), float(dt), False)
    rows_at = np.asarray(rows_at, dtype=np.int64)
    for b in range(states.shape[0]):
        advance_one(states[b], track, drive, float(v_cap[b]), float(a_cap[b]),
                    float(charger_w[b]), int(n), inputs[b], rows_at)


@numba.njit(cache=True, nogil=True)
def schedule_delay_s(state: np.ndarray, track: Track, lap_period_s: float) -> float:
    """How late the bus is against the timetable [s] (negative: early). On a layover: how
    late it will leave."""
    if state[MODE] == LAYOVER:
        return max(state[TIME] + state[TIMER] - (state[LAP] + 1) * lap_period_s, 0.0)
    baseline_s = track.baseline_s
    i = min(int(state[S] / track.step_m), len(baseline_s) - 1)
    due = state[LAP] * lap_period_s + baseline_s[i]
    if state[MODE] == DWELL:
        due += track.dwell_s[int(state[STOP])] - state[TIMER]
    return state[TIME] - due
