"""The example GTFS feed: King County Metro routes 45, 7 and 44 on a made-up timetable.

Stops, shapes, elevation and speed limits come from the shipped routes
(``data/routes/king_county``, MIT, see its SOURCE.md); the timetable is this project's own,
MADE UP for the example (the agency's is not shipped): each direction's running time is the
route planned under its speed limits (:meth:`ebus_env.routes.Route.cycle`, 20 s per stop)
plus 10 %, departures every ``HEADWAY_MIN`` from 05:30 and the last ones after midnight
(times past 24:00). It covers GTFS's awkward corners on purpose:

* routes 45 and 7 carry ``block_id``; route 44 has none and runs from ``frequencies.txt``
  (the loader chains its trips into blocks);
* route 7 gives times at every other stop only (not timepoints: the loader interpolates);
* the weekday service is removed on 2024-07-04 by ``calendar_dates.txt``, which adds a
  holiday service that runs route 45 only.

The altitude and speed-limit CSVs (``shape_id, shape_dist_traveled, altitude_m`` /
``speed_limit_kmh``) are written beside the feed, as a user gives them for their own feed.

    python -m ebus_env.gtfs.example_feed data/gtfs      # rewrites the shipped files
"""

from __future__ import annotations

import io
import math
import sys
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd

from ebus_env.blocks import clock
from ebus_env.outputs import atomic

FEED = "king_county_example.zip"
ALTITUDE = "king_county_example_altitude.csv"
SPEED_LIMITS = "king_county_example_speed_limits.csv"
HEADWAY_MIN = {"45": 20, "7": 15, "44": 30}
FIRST_S = 5 * 3600 + 1800  # 05:30
LAST_S = 24 * 3600 + 30 * 60  # the last departures at about 00:30 the next morning
LAYOVER_MIN = 8.0  # at least, at each terminal


def _route_tables(number: str):
    from ebus_env.routes import ROUTE_DIR, ROUTES, load_route

    tables = {}
    for leg in ("out", "back"):
        name = f"kc{number}_{leg}"
        route = load_route(name)
        frame = pd.read_csv(ROUTE_DIR / ROUTES[name])
        cycle = route.cycle(dwell_s=20.0, dt_s=1.0)
        v = cycle.speed_kmh / 3.6
        dist = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]))])
        tables[leg] = (route, frame, cycle.time_s, dist)
    return tables


def build() -> dict[str, str]:
    """The feed's files and the two CSVs, as text by file name."""
    stops, shapes, trips, times, freqs, alt, lim = [], [], [], [], [], [], []
    routes = []
    for number in ("45", "7", "44"):
        routes.append({"route_id": f"KC{number}", "agency_id": "EX", "route_short_name": number,
                       "route_long_name": f"King County Metro {number} (made-up timetable)",
                       "route_type": 3})
        tables = _route_tables(number)
        running = {}
        for leg, (_, frame, t, dist) in tables.items():
            shape_id = f"kc{number}_{leg}"
            for _, r in frame.iterrows():
                shapes.append({"shape_id": shape_id, "shape_pt_lat": r["lat_deg"],
                               "shape_pt_lon": r["lon_deg"], "shape_pt_sequence": len(shapes),
                               "shape_dist_traveled": round(r["distance_m"], 2)})
                alt.append({"shape_id": shape_id, "shape_dist_traveled": round(r["distance_m"], 2),
                            "altitude_m": r["elevation_m"]})
                lim.append({"shape_id": shape_id, "shape_dist_traveled": round(r["distance_m"], 2),
                            "speed_limit_kmh": r["speed_limit_kmh"]})
            at = frame[frame["stop_id_or_-1"] != -1]
            ends = ("A", "B") if leg == "out" else ("B", "A")
            legs = []
            for k, (_, r) in enumerate(at.iterrows()):
                first, last = k == 0, k == len(at) - 1
                stop_id = f"kc{number}_{ends[0] if first else ends[1] if last else f'{leg}{k}'}"
                if not (first or last) or leg == "out":  # terminals once
                    stops.append({"stop_id": stop_id, "stop_name": stop_id,
                                  "stop_lat": r["lat_deg"], "stop_lon": r["lon_deg"]})
                when = float(np.interp(r["distance_m"], dist, t))
                legs.append((stop_id, when * 1.1, r["distance_m"], first or last))
            running[leg] = legs
        run_out, run_back = (math.ceil(running[leg][-1][1] / 60.0) * 60.0 for leg in
                             ("out", "back"))
        headway = 60.0 * HEADWAY_MIN[number]
        cycle_s = math.ceil((run_out + run_back + 2 * 60.0 * LAYOVER_MIN) / headway) * headway
        buses = int(cycle_s // headway)
        half = (cycle_s - run_out - run_back) / 2.0
        if number == "44":  # runs from frequencies.txt, no block_id
            for leg, start in (("out", FIRST_S), ("back", FIRST_S + run_out + half)):
                tid = f"kc44_{leg}_f"
                trips.append({"route_id": "KC44", "service_id": "WK", "trip_id": tid,
                              "shape_id": f"kc44_{leg}", "block_id": ""})
                _stop_times(times, tid, start, running[leg], every_stop=True)
                freqs.append({"trip_id": tid, "start_time": clock(start),
                              "end_time": clock(LAST_S), "headway_secs": int(headway),
                              "exact_times": 1})
            continue
        for bus in range(buses):
            dep, n = FIRST_S + bus * headway, 0
            while dep <= LAST_S:
                for leg, run in (("out", run_out), ("back", run_back)):
                    tid = f"kc{number}_b{bus + 1}_{n}"
                    services = ("WK", "HOL") if number == "45" else ("WK",)
                    for service in services:
                        trips.append({"route_id": f"KC{number}", "service_id": service,
                                      "trip_id": f"{tid}_{service}", "shape_id": f"kc{number}_{leg}",
                                      "block_id": f"{number}-{bus + 1}_{service}"})
                        _stop_times(times, f"{tid}_{service}", dep, running[leg],
                                    every_stop=number != "7")
                    dep += run + half
                    n += 1
    calendar = [{"service_id": "WK", "monday": 1, "tuesday": 1, "wednesday": 1, "thursday": 1,
                 "friday": 1, "saturday": 0, "sunday": 0, "start_date": 20240101,
                 "end_date": 20241231}]
    dates = [{"service_id": "WK", "date": 20240704, "exception_type": 2},
             {"service_id": "HOL", "date": 20240704, "exception_type": 1}]
    agency = [{"agency_id": "EX", "agency_name": "Example (made-up timetable on King County "
               "Metro routes)", "agency_url": "https://example.org",
               "agency_timezone": "America/Los_Angeles"}]
    feed = {"agency.txt": agency, "routes.txt": routes, "stops.txt": stops,
            "trips.txt": trips, "stop_times.txt": times, "shapes.txt": shapes,
            "frequencies.txt": freqs, "calendar.txt": calendar, "calendar_dates.txt": dates}
    out = {name: pd.DataFrame(rows).to_csv(index=False, float_format="%.7g")
           for name, rows in feed.items()}
    out[ALTITUDE] = pd.DataFrame(alt).to_csv(index=False, float_format="%.3f")
    out[SPEED_LIMITS] = pd.DataFrame(lim).to_csv(index=False, float_format="%.2f")
    return out


def _stop_times(rows: list, trip_id: str, start_s: float, legs: list, every_stop: bool) -> None:
    for k, (stop_id, t, d, terminal) in enumerate(legs):
        timed = every_stop or terminal or k % 2 == 0
        when = clock(start_s + round(t)) if timed else ""
        rows.append({"trip_id": trip_id, "arrival_time": when, "departure_time": when,
                     "stop_id": stop_id, "stop_sequence": k + 1, "timepoint": int(timed),
                     "shape_dist_traveled": round(d, 2)})


def write(folder: str | Path) -> Path:
    """Write the feed (a zip) and its altitude and speed-limit CSVs into ``folder``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    files = build()
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for name, text in files.items():
            if name.endswith(".txt"):
                info = zipfile.ZipInfo(name, date_time=(2024, 1, 1, 0, 0, 0))
                info.compress_type = zipfile.ZIP_DEFLATED
                z.writestr(info, text)
    with atomic(folder / FEED) as tmp:
        tmp.write_bytes(buf.getvalue())
    for name in (ALTITUDE, SPEED_LIMITS):
        with atomic(folder / name) as tmp:
            tmp.write_text(files[name])
    return folder / FEED


if __name__ == "__main__":
    print(write(sys.argv[1] if len(sys.argv) > 1 else "data/gtfs"))
