"""Blocks: the schedule of one vehicle, its trips in order with the chargers it meets.

A :class:`Block` is what a bus does in a service day (a GTFS ``block_id``, a "rotation" or
"duty" in other tools): its trips in time order, each from a start stop to an end stop,
with layovers between them, at terminal stops that may hold opportunity chargers, and a depot
charger where it sleeps. Times are seconds after the service day's midnight and may pass
24:00 (86,400 s), as GTFS allows for trips that run after midnight.

A trip's drive comes from one of:

* its **timetable** (``stops``: each stop's arrival and departure and its distance along the
  trip; a GTFS trip), driven by :func:`drive_rows`' driver model: between two stops the bus
  accelerates at ``accel_mps2``, cruises, and brakes at ``decel_mps2`` (a trapezoid), with
  the cruise speed chosen so that it arrives when the timetable says (capped by the speed
  limit and ``max_speed_kmh``; late when even the cap cannot make it, catching up at later
  stops), then stands ``dwell_s`` at the stop (at least; longer where the timetable says);
* a shipped **cycle** or **King County route** (``cycle: sort2``, ``cycle: kc45_out``), driven
  as the cycle drives it from the trip's start (a hand-written schedule without GTFS).

The same format is written by hand (YAML or JSON, :func:`load_blocks`)::

    blocks:
      - block_id: 45-1
        chargers: {kc45_A: {count: 1, power_kw: 300}}   # terminal stop -> plugs, kW
        depot: {count: 4, power_kw: 100}
        trips:
          - {trip_id: t1, cycle: kc45_out, start: "06:00"}          # stops kc45_A -> kc45_B
          - {trip_id: t2, cycle: kc45_back, start: "06:55"}
          - {trip_id: t3, cycle: sort2, start: "07:50", start_stop: kc45_A, end_stop: kc45_A}
          - trip_id: t4                                   # or by its timetable
            stops: [{stop_id: kc45_A, arrival: "08:30", distance_m: 0},
                    {stop_id: kc45_B, arrival: "09:10", distance_m: 12000}]
            altitude: [[0, 40.0], [6000, 85.0], [12000, 60.0]]   # optional, [m, m]

and read from GTFS by :mod:`ebus_env.gtfs`. :meth:`Block.profile` gives the block's 10 Hz
drive as a :class:`~ebus_env.profile.Profile` with the charger channels
(``charger_connected``: 1 on a layover at a stop with a charger; ``charger_rating_w``), so a
model predicts the SoC at each planned charger and at the block's end (``Block.layovers``
says when each one is met).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numba
import numpy as np

from ebus_env.errors import ConfigError
from ebus_env.profile import Profile

__all__ = ["Block", "Charger", "Layover", "StopTime", "Trip", "blocks_from_dict",
           "blocks_to_dict", "clock", "load_blocks", "seconds"]  # the stable API

DAY_S = 86400.0
ACCEL_MPS2 = 1.0  # the driver model's acceleration and braking (as ebus_env.routes plans)
DECEL_MPS2 = 0.8
MAX_SPEED_KMH = 50.0  # the cap without a speed limit: an urban bus
DWELL_S = 20.0  # the least standing time at a stop
HOLD_FRAC = 0.6  # with slack in the timetable: cruise at least at this share of the cap and
# hold at the next stop (a driver who waits at a timepoint rather than crawl)


@dataclass(frozen=True)
class StopTime:
    """A timetabled stop of a trip: arrival and departure [s after midnight], distance along
    the trip [m]."""

    stop_id: str
    arrival_s: float
    departure_s: float
    distance_m: float


@dataclass(frozen=True)
class Charger:
    """Chargers at a terminal stop or at the depot: ``count`` plugs of ``power_kw`` each."""

    count: int
    power_kw: float


@dataclass(frozen=True, eq=False)
class Trip:
    """One trip of a block (see the module docstring for the two ways to give its drive).

    ``altitude``: (distance along the trip [m], altitude [m]) for the grade (None: flat);
    ``speed_limit``: (distance [m], limit [km/h]) (None: ``max_speed_kmh``);
    ``passengers``: on board (None: the study's profile); ``revenue``: False for a deadhead.
    """

    trip_id: str
    route: str
    start_s: float
    end_s: float
    start_stop: str
    end_stop: str
    distance_m: float
    stops: tuple[StopTime, ...] = ()
    cycle: str | None = None
    altitude: tuple[np.ndarray, np.ndarray] | None = None
    speed_limit: tuple[np.ndarray, np.ndarray] | None = None
    passengers: float | None = None
    revenue: bool = True

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s


@dataclass(frozen=True)
class Layover:
    """Standing between two trips at ``stop_id`` from ``start_s`` to ``end_s``, on
    ``charger`` where the stop has one."""

    stop_id: str
    start_s: float
    end_s: float
    charger: Charger | None

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s


@dataclass(frozen=True, eq=False)
class Block:
    """A vehicle's trips in time order, the chargers at terminal stops (stop id ->
    :class:`Charger`) and its depot's (None: the block does not charge at a depot)."""

    block_id: str
    trips: tuple[Trip, ...]
    chargers: dict[str, Charger] = field(default_factory=dict)
    depot: Charger | None = None

    @property
    def start_s(self) -> float:
        return self.trips[0].start_s

    @property
    def end_s(self) -> float:
        return self.trips[-1].end_s

    @property
    def distance_m(self) -> float:
        return float(sum(t.distance_m for t in self.trips))

    def layovers(self) -> list[Layover]:
        """The standing times between trips, in order (negative durations: see
        :meth:`problems`)."""
        return [Layover(a.end_stop, a.end_s, b.start_s, self.chargers.get(a.end_stop))
                for a, b in zip(self.trips[:-1], self.trips[1:], strict=True)]

    def problems(self) -> list[str]:
        """What keeps the block from being driven as given: a trip that starts before the
        previous one ends (overlapping layovers), or at another stop than it ended at (a
        deadhead missing). Empty when it can be driven."""
        out = []
        for a, b in zip(self.trips[:-1], self.trips[1:], strict=True):
            if b.start_s < a.end_s - 1e-6:
                out.append(f"trip {b.trip_id} starts at {clock(b.start_s)}, before trip "
                           f"{a.trip_id} ends at {clock(a.end_s)} (the layovers overlap)")
            if b.start_stop != a.end_stop:
                out.append(f"trip {b.trip_id} starts at stop {b.start_stop}, trip {a.trip_id} "
                           f"ends at {a.end_stop}: no deadhead between them")
        return out

    def profile(self, dt_s: float = 0.1, passengers: float = 0.0,
                ambient_degc: float | None = None) -> Profile:
        """The block's drive from its first departure to its last arrival, one row per
        ``dt_s``: reference speed, grade, charger connection and rating on layovers at a
        charger, passengers (a trip's own where given, else ``passengers``) and, where given,
        a constant ambient. ``start_time_h`` is the first departure's hour (may pass 24)."""
        if self.problems():
            raise ConfigError(f"Block {self.block_id}: {'; '.join(self.problems())}.")
        n = int(round((self.end_s - self.start_s) / dt_s)) + 1
        channels = drive_rows(self, 0, n, dt_s, passengers)
        if ambient_degc is not None:
            channels["ambient_degc"] = np.full(n, float(ambient_degc))
        notes = [f"block {self.block_id}: {len(self.trips)} trips, "
                 f"{self.distance_m / 1e3:.1f} km; driver model {ACCEL_MPS2:g}/{DECEL_MPS2:g} "
                 f"m/s^2 meeting the timetable, at least {DWELL_S:g} s at each stop"]
        if any(t.altitude is None and t.cycle is None for t in self.trips):
            notes.append("grade zero on trips without an altitude profile")
        return Profile(channels, dt_s, f"block {self.block_id}", self.start_s / 3600.0,
                       notes=notes)


# -- the driver model -------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Plan:
    """A block's drive in closed form: moves between stops (start time, phase durations,
    cruise speed, distance offset along its trip, trip index) and cycle trips (start time,
    trip index), from which :func:`drive_rows` writes any window of rows."""

    t0: np.ndarray  # each move's departure [s]
    t_acc: np.ndarray
    t_cruise: np.ndarray
    t_dec: np.ndarray
    v: np.ndarray  # cruise speed [m/s]
    d0: np.ndarray  # distance along the trip at the move's start [m]
    trip: np.ndarray  # trip index of each move
    stop: tuple[str, ...]  # the stop each move leaves
    late_s: float  # the most the drive ran behind the timetable


def _move(d_m: float, t_s: float, v_cap: float) -> tuple[float, float, float, float]:
    """(t_acc, t_cruise, t_dec, v) of a trapezoid covering ``d_m`` in at most ``t_s``:
    v^2 k - v T + D = 0, k = 1/(2a) + 1/(2b), the smaller root; at the cap (late) when even
    it needs longer; at least HOLD_FRAC of the cap (holding at the next stop)."""
    k = 0.5 / ACCEL_MPS2 + 0.5 / DECEL_MPS2
    v_top = min(v_cap, np.sqrt(d_m / k))  # the fastest trapezoid (a triangle below the cap)
    disc = t_s * t_s - 4.0 * k * d_m
    v = v_top if disc <= 0.0 else min(v_top, (t_s - np.sqrt(disc)) / (2.0 * k))
    v = max(v, min(v_top, HOLD_FRAC * v_cap))
    t_acc, t_dec = v / ACCEL_MPS2, v / DECEL_MPS2
    return t_acc, max(d_m / v - k * v, 0.0), t_dec, v


def plan(block: Block) -> Plan:
    """The moves of ``block``'s timetable trips (cycle trips are driven as their cycle)."""
    rows: list[tuple] = []
    stops: list[str] = []
    late = 0.0
    for k, trip in enumerate(block.trips):
        if trip.cycle is not None or len(trip.stops) < 2:
            continue
        st = trip.stops
        t = st[0].departure_s
        for a, b in zip(st[:-1], st[1:], strict=True):
            d = b.distance_m - a.distance_m
            cap = MAX_SPEED_KMH / 3.6
            if trip.speed_limit is not None:
                x, lim = trip.speed_limit
                inside = (x >= a.distance_m) & (x <= b.distance_m)
                here = np.interp([a.distance_m, b.distance_m], x, lim)
                cap = float(min(np.min(lim[inside], initial=np.inf), here.min())) / 3.6
            if d > 0.5:
                t_acc, t_cru, t_dec, v = _move(d, b.arrival_s - t, cap)
                rows.append((t, t_acc, t_cru, t_dec, v, a.distance_m, k))
                stops.append(a.stop_id)
                arrive = t + t_acc + t_cru + t_dec
            else:
                arrive = t
            late = max(late, arrive - b.arrival_s)
            last = b is st[-1]
            t = max(b.departure_s, arrive + (0.0 if last else DWELL_S))
    a = np.array(rows, float).reshape(-1, 7)
    return Plan(a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4], a[:, 5], a[:, 6].astype(int),
                tuple(stops), late)


@lru_cache(maxsize=64)
def _cycle_rows(name: str, dt_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(speed [m/s], grade, distance [m]) of a shipped cycle or King County route at
    ``dt_s``, row by row."""
    p = cycle_of(name).profile(dt_s)
    v = p.channel("speed_ref_mps")
    return v, p.channel("grade_frac"), np.cumsum(v) * dt_s


def cycle_of(name: str):
    """A shipped cycle (``sort2``...) or a King County route direction (``kc45_out``, planned
    under its speed limits with 20 s at each stop)."""
    from ebus_env.cycles import load_cycle
    from ebus_env.routes import ROUTES, load_route

    if name in ROUTES:
        return load_route(name).cycle(dt_s=0.5)
    return load_cycle(name)


@lru_cache(maxsize=4096)
def _grade_along(trip: Trip) -> tuple[np.ndarray, np.ndarray]:
    from ebus_env.grade import grade_from_altitude

    x, z = trip.altitude
    return x, grade_from_altitude(x, z)[0]


@numba.njit(cache=True, nogil=True)
def _fill_moves(t0, t_acc, t_cruise, t_dec, v, d0, trip, start_s, dt_s, first, speed, dist,
                trip_of):
    """The moves' speed [m/s] and distance along the trip [m] at rows ``first`` ... (row i at
    ``start_s + i dt_s``), and each row's trip (-1 before the first move), in one pass."""
    j = -1
    m = len(t0)
    for r in range(len(speed)):
        t = start_s + (first + r) * dt_s
        while j + 1 < m and t0[j + 1] <= t:
            j += 1
        if j < 0:
            trip_of[r] = -1
            continue
        tau = t - t0[j]
        ta, tc, td, vc = t_acc[j], t_cruise[j], t_dec[j], v[j]
        a = vc / ta if ta > 0.0 else 0.0
        b = vc / td if td > 0.0 else 0.0
        if tau < ta:
            speed[r] = a * tau
            dist[r] = d0[j] + 0.5 * a * tau * tau
        elif tau < ta + tc:
            speed[r] = vc
            dist[r] = d0[j] + 0.5 * vc * ta + vc * (tau - ta)
        else:
            t3 = min(tau - ta - tc, td)
            speed[r] = max(vc - b * t3, 0.0) if tau - ta - tc < td else 0.0
            dist[r] = d0[j] + 0.5 * vc * ta + vc * tc + vc * t3 - 0.5 * b * t3 * t3
        trip_of[r] = trip[j]


def _rows_of(t_from: float, t_to: float, start_s: float, first: int, n: int, dt_s: float
             ) -> slice:
    """The rows of [t_from, t_to) among rows first .. first + n - 1 (row i at start + i dt)."""
    lo = int(np.ceil((t_from - start_s) / dt_s - 1e-9)) - first
    hi = int(np.ceil((t_to - start_s) / dt_s - 1e-9)) - first
    return slice(min(max(lo, 0), n), min(max(hi, 0), n))


def drive_rows(block: Block, first: int, stop: int, dt_s: float, passengers: float = 0.0,
               block_plan: Plan | None = None) -> dict[str, np.ndarray]:
    """Rows ``first`` to ``stop`` - 1 of the block's drive (row ``i`` at ``start_s + i dt_s``):
    ``speed_ref_mps``, ``grade_frac``, ``charger_connected``, ``charger_rating_w`` (NaN off a
    charger), ``passenger_count`` and ``distance_m`` (along the current trip)."""
    p = block_plan if block_plan is not None else plan(block)
    n = stop - first
    start = block.start_s
    speed, grade, dist = np.zeros(n), np.zeros(n), np.zeros(n)
    trip_of = np.full(n, -1, np.int64)
    if len(p.t0):
        _fill_moves(p.t0, p.t_acc, p.t_cruise, p.t_dec, p.v, p.d0, p.trip, start, dt_s, first,
                    speed, dist, trip_of)
    connected = np.zeros(n)
    rating = np.full(n, np.nan)
    people = np.full(n, float(passengers))
    for k, trip in enumerate(block.trips):
        rows = _rows_of(trip.start_s, trip.end_s, start, first, n, dt_s)
        if rows.start >= rows.stop:
            continue
        if trip.passengers is not None or not trip.revenue:
            people[rows] = trip.passengers if trip.passengers is not None else 0.0
        if trip.cycle is not None:
            v_c, g_c, d_c = _cycle_rows(trip.cycle, dt_s)
            r = np.minimum(np.arange(rows.start, rows.stop) + first
                           - int(round((trip.start_s - start) / dt_s)), len(v_c) - 1)
            speed[rows], grade[rows], dist[rows] = v_c[r], g_c[r], d_c[r]
        elif trip.altitude is not None:
            x, g = _grade_along(trip)
            mine = trip_of[rows] == k
            grade[rows] = np.where(mine, np.interp(dist[rows], x, g), 0.0)
    for lay in block.layovers():
        if lay.charger is not None:
            rows = _rows_of(lay.start_s, lay.end_s, start, first, n, dt_s)
            standing = speed[rows] <= 0.0
            connected[rows] = np.where(standing, 1.0, 0.0)
            rating[rows] = np.where(standing, 1e3 * lay.charger.power_kw, np.nan)
    return {"speed_ref_mps": speed, "grade_frac": grade, "charger_connected": connected,
            "charger_rating_w": rating, "passenger_count": people, "distance_m": dist}


def where(block: Block, t_s: float, block_plan: Plan | None = None) -> str:
    """Where the block is at ``t_s``: ``trip <id> after stop <id>``, or ``layover at <stop>``."""
    for trip in block.trips:
        if trip.start_s <= t_s < trip.end_s:
            p = block_plan if block_plan is not None else plan(block)
            i = int(np.searchsorted(p.t0, t_s, side="right")) - 1
            k = block.trips.index(trip)
            if i >= 0 and p.trip[i] == k:
                return f"trip {trip.trip_id} after stop {p.stop[i]}"
            return f"trip {trip.trip_id}"
    for lay in block.layovers():
        if lay.start_s <= t_s < lay.end_s:
            return f"layover at {lay.stop_id}"
    return f"end of block at {block.trips[-1].end_stop}"


# -- the hand-written form --------------------------------------------------------------------
_CLOCK = re.compile(r"^(\d{1,2}):([0-5]\d)(?::([0-5]\d))?$")


def seconds(value, where: str) -> float:
    """``"HH:MM[:SS]"`` (HH may pass 23) or a number of seconds -> seconds after midnight."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    m = _CLOCK.match(str(value).strip())
    if not m:
        raise ConfigError(f"{where} = {value!r}: give a time as 'HH:MM' or 'HH:MM:SS' (hours "
                          "may pass 24 for trips after midnight) or seconds after midnight.")
    return 3600.0 * int(m[1]) + 60.0 * int(m[2]) + float(m[3] or 0)


def clock(t_s: float) -> str:
    """Seconds after midnight as ``HH:MM:SS`` (past 24:00 as GTFS writes it)."""
    t = int(round(t_s))
    return f"{t // 3600:02d}:{t % 3600 // 60:02d}:{t % 60:02d}"


def _charger(data, where: str) -> Charger:
    if not isinstance(data, dict) or set(data) != {"count", "power_kw"}:
        raise ConfigError(f"{where} = {data!r}: give {{count: plugs, power_kw: kW}}.")
    count, kw = data["count"], data["power_kw"]
    if not isinstance(count, int) or count < 0 or not isinstance(kw, (int, float)) or kw <= 0:
        raise ConfigError(f"{where} = {data!r}: count is a whole number >= 0, power_kw > 0.")
    return Charger(count, float(kw))


TRIP_KEYS = {"trip_id", "route", "start", "end", "start_stop", "end_stop", "cycle",
             "passengers", "revenue", "distance_m", "stops", "altitude", "speed_limit"}


def _pairs(value, where: str) -> tuple[np.ndarray, np.ndarray] | None:
    """``[[distance_m, value], ...]`` (increasing distance) as two arrays."""
    if value is None:
        return None
    a = np.asarray(value, float)
    if a.ndim != 2 or a.shape[1] != 2 or len(a) < 2 or (np.diff(a[:, 0]) < 0).any():
        raise ConfigError(f"{where}: give [[distance_m, value], ...], at least two rows, "
                          "distance not decreasing.")
    return a[:, 0], a[:, 1]


def _timetable_trip(data: dict, where: str) -> Trip:
    """A trip given by its stops (the form :func:`blocks_to_dict` writes for a GTFS trip)."""
    stops = []
    for k, stop in enumerate(data["stops"]):
        if not isinstance(stop, dict) or not {"stop_id", "arrival", "distance_m"} <= set(stop):
            raise ConfigError(f"{where}.stops[{k}]: give stop_id, arrival, distance_m (and "
                              "departure when it stands longer).")
        arrive = seconds(stop["arrival"], f"{where}.stops[{k}].arrival")
        leave = seconds(stop.get("departure", stop["arrival"]), f"{where}.stops[{k}].departure")
        stops.append(StopTime(str(stop["stop_id"]), arrive, leave, float(stop["distance_m"])))
    if len(stops) < 2 or any(b.arrival_s < a.departure_s or b.distance_m < a.distance_m
                             for a, b in zip(stops[:-1], stops[1:], strict=True)):
        raise ConfigError(f"{where}.stops: give at least two stops, in time and distance order.")
    return Trip(str(data["trip_id"]), str(data.get("route", "")), stops[0].departure_s,
                stops[-1].arrival_s, stops[0].stop_id, stops[-1].stop_id,
                stops[-1].distance_m - stops[0].distance_m, tuple(stops),
                altitude=_pairs(data.get("altitude"), f"{where}.altitude"),
                speed_limit=_pairs(data.get("speed_limit"), f"{where}.speed_limit"),
                passengers=data.get("passengers"), revenue=bool(data.get("revenue", True)))


def _trip(data: dict, where: str) -> Trip:
    from ebus_env.routes import ROUTES

    if not isinstance(data, dict):
        raise ConfigError(f"{where}: give a mapping with trip_id, cycle and start.")
    unknown = sorted(set(data) - TRIP_KEYS)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; known: {sorted(TRIP_KEYS)}.")
    if "stops" in data and "trip_id" in data:
        return _timetable_trip(data, where)
    for key in ("trip_id", "cycle", "start"):
        if key not in data:
            raise ConfigError(f"{where}: missing '{key}' (a hand-written trip is a shipped cycle "
                              "or King County route, e.g. cycle: kc45_out, from a start time; "
                              "or its stops with times and distances).")
    name = str(data["cycle"])
    try:
        length_m = float(_cycle_rows(name, 0.1)[2][-1])
        duration = cycle_of(name).duration_s
    except ConfigError as e:
        raise ConfigError(f"{where}.cycle: {e}") from None
    start = seconds(data["start"], f"{where}.start")
    end = seconds(data["end"], f"{where}.end") if "end" in data else start + duration
    if end < start + duration - 0.5:
        raise ConfigError(f"{where}: ends at {clock(end)}, but {name} takes "
                          f"{duration / 60:.1f} min from {clock(start)}.")
    base = name.rsplit("_", 1)[0] if name in ROUTES else name
    ends = (f"{base}_A", f"{base}_B") if name.endswith("_out") else \
        (f"{base}_B", f"{base}_A") if name.endswith("_back") else (base, base)
    return Trip(str(data["trip_id"]), str(data.get("route", base)), start, end,
                str(data.get("start_stop", ends[0])), str(data.get("end_stop", ends[1])),
                float(data.get("distance_m", length_m)), cycle=name,
                passengers=data.get("passengers"), revenue=bool(data.get("revenue", True)))


def blocks_to_dict(blocks: list[Block]) -> dict:
    """The hand-written form of ``blocks`` (JSON- and YAML-safe; :func:`blocks_from_dict`
    reads it back): a GTFS block saved for a tool that has no feed."""
    def trip(t: Trip) -> dict:
        out = {"trip_id": t.trip_id, "route": t.route}
        if t.cycle is not None:
            out.update(cycle=t.cycle, start=t.start_s, end=t.end_s,  # seconds: exact
                       start_stop=t.start_stop, end_stop=t.end_stop, distance_m=t.distance_m)
        else:
            out["stops"] = [{"stop_id": s.stop_id, "arrival": s.arrival_s,
                             "departure": s.departure_s, "distance_m": s.distance_m}
                            for s in t.stops]
            for key in ("altitude", "speed_limit"):
                if getattr(t, key) is not None:
                    out[key] = np.column_stack(getattr(t, key)).tolist()
        if t.passengers is not None:
            out["passengers"] = float(t.passengers)
        if not t.revenue:
            out["revenue"] = False
        return out

    def charger(c: Charger) -> dict:
        return {"count": c.count, "power_kw": c.power_kw}

    return {"blocks": [{"block_id": b.block_id, "trips": [trip(t) for t in b.trips],
                        "chargers": {k: charger(v) for k, v in b.chargers.items()},
                        **({"depot": charger(b.depot)} if b.depot else {})} for b in blocks]}


def blocks_from_dict(data: dict, source: str = "blocks") -> list[Block]:
    """Blocks from the hand-written form (see the module docstring)."""
    if not isinstance(data, dict) or not isinstance(data.get("blocks"), list):
        raise ConfigError(f"{source}: give a mapping with 'blocks': a list of blocks.")
    out = []
    for i, item in enumerate(data["blocks"]):
        where = f"{source}: blocks[{i}]"
        if not isinstance(item, dict) or "trips" not in item or not item["trips"]:
            raise ConfigError(f"{where}: give block_id and a list of trips.")
        unknown = sorted(set(item) - {"block_id", "trips", "chargers", "depot"})
        if unknown:
            raise ConfigError(f"{where}: unknown key(s) {unknown}.")
        trips = tuple(_trip(t, f"{where}.trips[{j}]") for j, t in enumerate(item["trips"]))
        chargers = {str(k): _charger(v, f"{where}.chargers.{k}")
                    for k, v in (item.get("chargers") or {}).items()}
        depot = _charger(item["depot"], f"{where}.depot") if item.get("depot") else None
        block = Block(str(item.get("block_id", f"block{i}")),
                      tuple(sorted(trips, key=lambda t: t.start_s)), chargers, depot)
        out.append(block)
    return out


def load_blocks(path: str | Path) -> list[Block]:
    """Blocks from a YAML or JSON file in the hand-written form."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"No blocks file {path}.")
    if path.suffix == ".json":
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as e:
            raise ConfigError(f"{path}: not JSON: {e}") from None
    else:
        from ebus_env.config import read_yaml

        data = read_yaml(path)
    return blocks_from_dict(data, str(path))
