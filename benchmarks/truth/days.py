"""The driving plan of a randomised service day on King County Metro routes.

A bus runs one route out and back (direction 0, then 1, ...) for ``hours``, with a layover at
each terminal, where an opportunity charger may stand. Along each leg it stops at served bus
stops (doors open while passengers board and alight), at red signals and in traffic queues.

The speed the driver aims for is built over distance, then mapped to time:

1. a ceiling ``v_max(s) = f_traffic * f_segment * v_limit(s)``, the posted limit scaled by the
   day's congestion and a draw (0.7-1.05) for every 150 m (traffic, turns, parked cars);
2. a forward pass ``v[i+1] = min(v_max, sqrt(v[i]^2 + 2 a(v) ds))`` with a comfort acceleration
   that falls with speed, ``a(v) = a_0 max(0.35, 1 - v / 22 m/s)``, and a backward pass
   ``v[i] = min(v[i], sqrt(v[i+1]^2 + 2 d ds))`` with a comfort deceleration ``d``, both to
   zero at every stop point (the usual "speed ceiling with acceleration limits" profile);
3. time ``dt_i = 2 ds / (v_i + v_{i+1})``, with the dwell at each stop point inserted.

Comfort limits for city buses (a_0 0.8-1.3 m/s^2, d 0.9-1.4 m/s^2) follow the range of
measured bus accelerations in the aggregated King County acceleration profile of
reRoute_Dynamics (0.03-0.23 g, ``data/routes/king_county/SOURCE.md``).

Dwell times follow the passenger service times of the Transit Capacity and Quality of Service
Manual, 3rd ed. (TCRP Report 165, 2013), Chapter 6 ("Bus Transit Capacity"), dwell time
section: a door open/close time of 2-5 s plus about 2.5 s per boarding and 1.5-2 s per
alighting passenger.

The elevation is the LiDAR profile of the route files, cleaned of spikes (running median over
~45 m) and smoothed (running mean over ~80 m), the source's own advice; grade is its slope,
limited to +-10 %. Whether the simulator uses the grade is the case's choice.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

ROUTE_DIR = Path(__file__).resolve().parents[2] / "data" / "routes" / "king_county"
ROUTES = {
    "rt7": ("rt7_sh10007006_d0.csv", "rt7_sh10007006_d1.csv"),
    "rt44": ("rt44_sh11044004_d0.csv", "rt44_sh11044004_d1.csv"),
    "rt45": ("rt45_sh31045010_d0.csv", "rt45_sh31045010_d1.csv"),
}
CLIMATES = ("cold", "mild", "hot", "season")
TIMEZONE = "America/Los_Angeles"  # King County's local time, the logs' UTC offset
GRID_M = 2.0  # distance step of the speed profile
MAX_GRADE_FRAC = 0.10
CAPACITY_PASSENGERS = 85  # a 12 m bus: about 30 seated + 55 standing
PLAN_COLUMNS = ("time_s", "clock_h", "speed_target_mps", "grade_frac", "altitude_m",
                "door_open", "charging", "charger_kw", "ambient_degc", "passengers",
                "solar_w_per_m2", "distance_m", "leg")

# Season of each climate: months for the date, sunrise/sunset [h] in Seattle (47.6 N; NOAA
# solar calculator, mid-month) and the clear-sky peak global irradiance [W/m^2] on the
# horizontal at that time of year.
_SEASONS = {
    "cold": {"months": (12, 1, 2), "sun_h": (7.9, 16.6), "peak_w_per_m2": 300.0,
             "mean_degc": (-8.0, 3.0), "swing_k": (2.0, 5.0)},
    "mild": {"months": (4, 5, 9, 10), "sun_h": (6.6, 19.3), "peak_w_per_m2": 650.0,
             "mean_degc": (9.0, 18.0), "swing_k": (3.0, 6.0)},
    "hot": {"months": (7, 8), "sun_h": (5.5, 20.8), "peak_w_per_m2": 880.0,
            "mean_degc": (25.0, 31.0), "swing_k": (4.0, 7.0)},
    # the days of a multi-day bus, November to February: each day's weather drawn on its
    # own from a mild autumn day to a hard frost (Seattle's daily means span about this)
    "season": {"months": (11, 12, 1, 2), "sun_h": (7.6, 16.7), "peak_w_per_m2": 320.0,
               "mean_degc": (-8.0, 14.0), "swing_k": (2.0, 6.0)},
}


@dataclass(frozen=True)
class Leg:
    """One direction of a route on a ``GRID_M`` grid."""

    name: str
    distance_m: np.ndarray
    altitude_m: np.ndarray
    grade_frac: np.ndarray
    limit_mps: np.ndarray
    stops_m: np.ndarray  # served-stop candidates, terminals excluded
    signals_m: np.ndarray


def _running(values: np.ndarray, width: int, how) -> np.ndarray:
    half = width // 2
    padded = np.pad(values, half, mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)
    return how(windows, axis=1)


def load_leg(file_name: str) -> Leg:
    """Read one tidy route file and bring it onto the distance grid."""
    table = pd.read_csv(ROUTE_DIR / file_name)
    dist = table["distance_m"].to_numpy(float)
    keep = np.concatenate(([True], np.diff(dist) > 0.0))  # repeated points carry no length
    dist, table = dist[keep], table[keep]
    grid = np.arange(0.0, dist[-1], GRID_M)
    elev_raw = np.interp(grid, dist, table["elevation_m"].to_numpy(float))
    elev = _running(_running(elev_raw, int(45 / GRID_M), np.median), int(80 / GRID_M), np.mean)
    grade = np.clip(np.gradient(elev, GRID_M), -MAX_GRADE_FRAC, MAX_GRADE_FRAC)
    # altitude consistent with the clipped grade the bus feels
    altitude = elev[0] + np.concatenate(([0.0], np.cumsum(0.5 * (grade[1:] + grade[:-1])
                                                          * GRID_M)))
    limit = np.interp(grid, dist, table["speed_limit_kmh"].to_numpy(float)) / 3.6
    stops = dist[table["stop_id_or_-1"].to_numpy() != -1]
    stops = stops[(stops > 50.0) & (stops < dist[-1] - 50.0)]
    signals = dist[table["signal_id_or_-1"].to_numpy() != -1]
    signals = signals[(signals > 30.0) & (signals < dist[-1] - 30.0)]
    return Leg(file_name, grid, altitude, grade, limit, stops, signals)


def _leg_profile(leg: Leg, rng: np.random.Generator, congestion: float, accel_mps2: float,
                 decel_mps2: float, board_rate: float, start_load: int) -> dict[str, np.ndarray]:
    """One leg, per grid point: arrival and departure time from the leg's start [s], speed
    [m/s], door flag and passengers on board after the stop."""
    n = len(leg.distance_m)
    seg = (leg.distance_m // 150.0).astype(int)  # a fresh traffic factor every ~150 m
    ceiling = np.maximum(congestion * leg.limit_mps * rng.uniform(0.7, 1.05, seg[-1] + 1)[seg],
                         3.0)
    wait = np.zeros(n)
    door = np.zeros(n, dtype=int)
    pax = np.full(n, start_load)
    stop = np.zeros(n, dtype=bool)
    for pos in leg.signals_m:  # red signals
        if rng.random() < 0.45:
            i = int(pos / GRID_M)
            stop[i], wait[i] = True, rng.uniform(5.0, 50.0)
    queue_per_km = max(0.0, 3.0 * (1.0 - congestion))  # none in free flow, ~1.2/km at f = 0.6
    for pos in rng.uniform(100.0, leg.distance_m[-1] - 100.0,
                           rng.poisson(queue_per_km * leg.distance_m[-1] / 1000.0)):
        i = int(pos / GRID_M)
        if not stop[i]:
            stop[i], wait[i] = True, rng.uniform(3.0, 25.0)
    on_board = start_load
    for pos in leg.stops_m:  # bus stops, in order: the bus stops only if someone gets on/off
        i = int(pos / GRID_M)
        alight = rng.binomial(on_board, 0.12)
        board = min(rng.poisson(board_rate), CAPACITY_PASSENGERS - on_board + alight)
        if board + alight == 0:
            continue
        on_board += board - alight
        stop[i], door[i] = True, 1
        wait[i] = max(wait[i], rng.uniform(2.0, 5.0) + 2.5 * board
                      + rng.uniform(1.5, 2.0) * alight)
        pax[i:] = on_board
    stop[0] = stop[-1] = True
    # the terminal: everyone alights
    door[-1] = 1 if on_board else 0
    wait[-1] = rng.uniform(1.5, 2.0) * on_board
    pax[-1] = 0
    v = np.empty(n)
    v[0] = 0.0
    for i in range(n - 1):
        a = accel_mps2 * max(0.35, 1.0 - v[i] / 22.0)
        v[i + 1] = 0.0 if stop[i + 1] else min(ceiling[i + 1],
                                                np.sqrt(v[i] ** 2 + 2.0 * a * GRID_M))
    for i in range(n - 2, -1, -1):
        v[i] = min(v[i], np.sqrt(v[i + 1] ** 2 + 2.0 * decel_mps2 * GRID_M))
    dt = 2.0 * GRID_M / np.maximum(v[1:] + v[:-1], 0.05)
    arrive = np.concatenate(([0.0], np.cumsum(dt + wait[:-1])))
    return {"arrive_s": arrive, "depart_s": arrive + wait, "speed_mps": v, "door": door,
            "pax": pax}


def _peak(clock_h: float) -> float:
    """Rush-hour weight in [0, 1]: morning peak near 08:00, evening peak near 17:00."""
    return max(np.exp(-(((clock_h % 24.0) - 8.0) / 1.2) ** 2),
               np.exp(-(((clock_h % 24.0) - 17.0) / 1.5) ** 2))


def ambient_profile(rng: np.random.Generator, clock_h: np.ndarray, climate: str) -> np.ndarray:
    """Ambient temperature [degC]: a daily cosine with its maximum at 15:00 plus a slow
    weather wander (AR(1), 30 min correlation time, 0.6 K spread)."""
    season = _SEASONS[climate]
    mean = rng.uniform(*season["mean_degc"])
    swing = rng.uniform(*season["swing_k"])
    n = len(clock_h)
    step = rng.normal(0.0, 1.0, n)
    rho = np.exp(-1.0 / 1800.0)
    wander = np.empty(n)
    wander[0] = 0.6 * step[0]
    for i in range(1, n):  # the loop is cheap next to the leg profiles
        wander[i] = rho * wander[i - 1] + 0.6 * np.sqrt(1.0 - rho * rho) * step[i]
    return mean + swing * np.cos(2.0 * np.pi * (clock_h - 15.0) / 24.0) + wander


def solar_profile(rng: np.random.Generator, clock_h: np.ndarray, climate: str) -> np.ndarray:
    """Global horizontal irradiance [W/m^2]: a half sine between sunrise and sunset scaled by
    the season's clear-sky peak and a cloud factor drawn per day."""
    season = _SEASONS[climate]
    rise, set_ = season["sun_h"]
    phase = np.clip((clock_h % 24.0 - rise) / (set_ - rise), 0.0, 1.0)
    return season["peak_w_per_m2"] * rng.uniform(0.25, 1.0) * np.sin(np.pi * phase)


def route_day(rng: np.random.Generator, hours: float, start_clock_h: float,
              route: str | None = None, *, climate: str = "mild",
              charger_kw: float | None = None,
              charger_terminals: tuple[int, ...] | None = None,
              date: str | None = None) -> pd.DataFrame:
    """The driving plan of one service day, at 1 Hz.

    Parameters
    ----------
    rng : the day's random generator (traffic, dwell, passengers, weather).
    hours : length of the day [h].
    start_clock_h : clock time of the first sample [h].
    route : ``"rt7"``, ``"rt44"`` or ``"rt45"``; drawn when None.
    climate : ``"cold"`` (winter), ``"mild"`` (spring/autumn), ``"hot"`` (summer) or
        ``"season"`` (a day from November to February, mild to freezing).
    charger_kw : rated power of the terminal chargers [kW]; drawn from 150/300/450 when None.
    charger_terminals : terminals with a charger, ``(0,)`` (where leg 0 starts), ``(1,)`` or
        ``(0, 1)``; drawn when None. Giving either changes nothing else in the day.
    date : the service date (``YYYY-MM-DD``); drawn in the climate's months when None.
        Giving it changes nothing else in the day.

    Returns
    -------
    DataFrame with ``PLAN_COLUMNS``: ``speed_target_mps`` the speed the driver aims for,
    ``grade_frac`` and ``altitude_m`` of the road under the planned position,
    ``door_open``/``charging`` flags, ``charger_kw`` (rated power while charging, else 0),
    ``passengers`` on board, ``distance_m`` along the day and ``leg`` (0, 1, ... one per
    direction; -1 on layovers). ``attrs`` hold ``date``, ``timezone``, ``route``,
    ``climate``, ``charger_kw`` and ``charger_terminals``.
    """
    if climate not in CLIMATES:
        raise ValueError(f"climate {climate!r} is not one of {CLIMATES}")
    if not 0.1 <= hours <= 24.0:
        raise ValueError(f"hours={hours} is outside 0.1-24 h")
    route = route or str(rng.choice(sorted(ROUTES)))
    legs = [load_leg(f) for f in ROUTES[route]]
    season = _SEASONS[climate]
    month = int(rng.choice(season["months"]))
    drawn_date = pd.Timestamp(year=2025, month=month, day=int(rng.integers(1, 29)))
    date = pd.Timestamp(date) if date is not None else drawn_date
    drawn_kw = float(rng.choice([150.0, 300.0, 450.0]))
    drawn_terminals = (0, 1) if rng.random() < 0.4 else (0,)
    charger_kw = float(charger_kw) if charger_kw is not None else drawn_kw
    terminals = tuple(charger_terminals) if charger_terminals is not None else drawn_terminals
    base_congestion = rng.uniform(0.72, 0.95)
    demand = rng.uniform(0.6, 1.4)
    accel = rng.uniform(0.8, 1.3)
    decel = rng.uniform(0.9, 1.4)
    n_total = int(round(hours * 3600.0))
    pieces: list[dict[str, np.ndarray]] = []
    t0, dist0, k = 0, 0.0, 0
    load = 0
    while t0 < n_total:
        leg = legs[k % 2]
        clock = start_clock_h + t0 / 3600.0
        # layover at the terminal this leg starts from, boarding at its end
        layover = int(rng.uniform(300.0, 840.0)) if k else int(rng.uniform(60.0, 180.0))
        board_rate = demand * (1.2 + 3.0 * _peak(clock))
        load = min(int(rng.poisson(3.0 * board_rate)), CAPACITY_PASSENGERS)
        tau = np.arange(layover)
        boarding = tau >= layover - max(20, int(2.5 * load) + 5)
        on_charger = (k % 2) in terminals
        plug = (tau >= rng.uniform(20.0, 60.0)) & (tau < layover - rng.uniform(20.0, 40.0))
        plug &= on_charger
        stand_m = legs[(k - 1) % 2].altitude_m[-1] if k else leg.altitude_m[0]
        pieces.append({"t": t0 + tau, "v": np.zeros(layover), "s": np.full(layover, dist0),
                       "door": boarding.astype(int), "pax": np.where(boarding, load, 0),
                       "charging": plug.astype(int), "leg": np.full(layover, -1),
                       "alt": np.full(layover, stand_m), "grade": np.zeros(layover)})
        t0 += layover
        congestion = float(np.clip(base_congestion - 0.15 * _peak(clock)
                                   + rng.uniform(-0.05, 0.05), 0.5, 1.0))
        prof = _leg_profile(leg, rng, congestion, accel, decel, board_rate, load)
        n = int(np.ceil(prof["depart_s"][-1]))
        tau = np.arange(n, dtype=float)
        knots_t = np.column_stack((prof["arrive_s"], prof["depart_s"])).ravel()
        v = np.interp(tau, knots_t, np.repeat(prof["speed_mps"], 2))
        s = np.interp(tau, knots_t, np.repeat(leg.distance_m, 2))
        i = np.searchsorted(prof["arrive_s"], tau, side="right") - 1
        dwelling = tau < prof["depart_s"][i]
        door = (prof["door"][i] == 1) & dwelling & (tau - prof["arrive_s"][i] >= 1.0) \
            & (prof["depart_s"][i] - tau >= 1.0)
        pieces.append({"t": t0 + tau.astype(int), "v": v, "s": dist0 + s,
                       "door": door.astype(int), "pax": prof["pax"][i],
                       "charging": np.zeros(n, dtype=int), "leg": np.full(n, k),
                       "alt": np.interp(s, leg.distance_m, leg.altitude_m),
                       "grade": np.interp(s, leg.distance_m, leg.grade_frac)})
        t0 += n
        dist0 += leg.distance_m[-1]
        k += 1
    cat = {key: np.concatenate([p[key] for p in pieces])[:n_total] for key in pieces[0]}
    time_s = np.arange(n_total, dtype=float)
    clock_h = start_clock_h + time_s / 3600.0
    plan = pd.DataFrame({
        "time_s": time_s,
        "clock_h": clock_h,
        "speed_target_mps": cat["v"],
        "grade_frac": cat["grade"],
        "altitude_m": cat["alt"],
        "door_open": cat["door"].astype(np.int8),
        "charging": cat["charging"].astype(np.int8),
        "charger_kw": np.where(cat["charging"] == 1, charger_kw, 0.0),
        "ambient_degc": ambient_profile(rng, clock_h, climate),
        "passengers": cat["pax"].astype(int),
        "solar_w_per_m2": solar_profile(rng, clock_h, climate),
        "distance_m": cat["s"],
        "leg": cat["leg"].astype(int),
    })
    plan.attrs.update(date=str(date.date()), timezone=TIMEZONE, route=route, climate=climate,
                      charger_kw=charger_kw, charger_terminals=list(terminals))
    return plan
