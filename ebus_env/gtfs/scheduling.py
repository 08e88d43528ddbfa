"""Vehicle scheduling: trips without a ``block_id`` chained into blocks.

Greedy, in departure order (the classic first-fit for interval scheduling): each trip goes to
a vehicle that can be at its first stop in time, that is one whose last trip ended at least
``min_layover_s`` before (plus the deadhead's driving time when it ended at another stop);
among those, one already at that stop before one that must deadhead, then the one that has
waited least (so long layovers stay free for later trips); a new vehicle when none can. Without
deadheads this uses the fewest vehicles a timetable allows (at each departure a vehicle is
added only when every one is busy); with deadheads it is a heuristic, not the min-cost-flow
optimum. A deadhead is the straight line between the stops times ``detour_factor``, driven at
``deadhead_speed_kmh`` with no passengers.
"""

from __future__ import annotations

from ebus_env.blocks import StopTime, Trip


def deadhead(a: str, b: str, start_s: float, xy: dict, speed_kmh: float, detour: float) -> Trip:
    """An empty trip from stop ``a`` to stop ``b`` leaving at ``start_s``."""
    from ebus_env.gtfs.feed import haversine_m

    d = float(haversine_m(*xy[a], *xy[b])) * detour
    duration = d / (speed_kmh / 3.6) + 60.0  # plus a minute of ramps and junctions
    return Trip(f"deadhead {a}->{b}", "deadhead", start_s, start_s + duration, a, b, d,
                (StopTime(a, start_s, start_s, 0.0), StopTime(b, start_s + duration,
                                                               start_s + duration, d)),
                passengers=0.0, revenue=False)


def chain_trips(trips: list[Trip], xy: dict, min_layover_s: float, speed_kmh: float,
                detour: float) -> list[list[Trip]]:
    """The trips (any order) chained into vehicles' trip lists, deadheads included."""
    from ebus_env.gtfs.feed import haversine_m

    vehicles: list[list[Trip]] = []
    for trip in sorted(trips, key=lambda t: (t.start_s, t.trip_id)):
        best, best_key = None, None
        for v in vehicles:
            last = v[-1]
            move_s = 0.0
            if last.end_stop != trip.start_stop:
                d = float(haversine_m(*xy[last.end_stop], *xy[trip.start_stop])) * detour
                move_s = d / (speed_kmh / 3.6) + 60.0 + min_layover_s
            ready = last.end_s + min_layover_s + move_s
            if ready <= trip.start_s:
                key = (move_s > 0.0, trip.start_s - ready)
                if best_key is None or key < best_key:
                    best, best_key = v, key
        if best is None:
            vehicles.append([trip])
            continue
        last = best[-1]
        if last.end_stop != trip.start_stop:
            best.append(deadhead(last.end_stop, trip.start_stop, last.end_s + min_layover_s, xy,
                                 speed_kmh, detour))
        best.append(trip)
    return vehicles
