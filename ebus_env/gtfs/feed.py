"""A GTFS feed's service day as blocks, with every repair said.

Reading uses partridge (a small, pandas-based GTFS reader): it reads a zip or a folder,
applies ``calendar.txt`` and the exceptions of ``calendar_dates.txt`` to find the services of
a date, loads only those trips, and parses ``HH:MM:SS`` times past 24:00 (a trip after
midnight belongs to the day its service started) to seconds after midnight. The rest is here:

* ``frequencies.txt``: a trip run at a headway is copied to each departure of its windows
  (``trip_id@HH:MM:SS``), its stop times shifted;
* stop times missing at stops that are not timepoints are interpolated by distance (said);
* distance along a trip: ``shape_dist_traveled`` (its unit found against the stops'
  straight-line distances: m, km, mi or ft), else the stops projected on the trip's shape,
  else the straight lines between stops (said); a stop further than ``SHAPE_MATCH_M`` from its
  shape is a shape that does not match: that trip's distances come from its stops (said);
* grade from a user's altitude CSV (``shape_id, shape_dist_traveled, altitude_m``, in the
  feed's distance unit), speed limits from a CSV of the same form with
  ``speed_limit_kmh``; trips without one drive flat / under ``MAX_SPEED_KMH`` (counted);
* blocks from ``block_id``, else :func:`ebus_env.gtfs.scheduling.chain_trips`; trips with no
  stop times, blocks whose layovers overlap, and blocks mixing electrified and other routes
  (``mixed_blocks: report``) are listed, not driven.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass, field
from datetime import date as Date
from pathlib import Path

import numpy as np
import pandas as pd

from ebus_env.blocks import Block, Charger, StopTime, Trip, clock
from ebus_env.errors import ConfigError

REQUIRED = ("routes.txt", "trips.txt", "stop_times.txt", "stops.txt")
SHAPE_MATCH_M = 150.0  # a stop further than this from its trip's shape: the shape does not match
UNITS = {"m": 1.0, "km": 1000.0, "mi": 1609.344, "ft": 0.3048}
EARTH_M = 6371008.8


@dataclass
class NetworkDay:
    """The blocks of a service day and what was done to get them.

    ``blocks``: the blocks to drive (electrified); ``not_driven``: block id -> why (layovers
    that overlap, a deadhead that does not fit, a mixed block with ``mixed_blocks: report``);
    ``trips_not_served``: trip ids of the electrified routes that no driven block serves,
    with the reason; ``notes``: every repair and assumption, in words; ``flat_trips``: trips
    without an altitude profile (grade zero).
    """

    date: Date
    blocks: list[Block]
    not_driven: dict[str, str] = field(default_factory=dict)
    trips_not_served: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    flat_trips: int = 0
    scheduled: str = ""  # how the blocks were made

    @property
    def trips(self) -> int:
        return sum(sum(t.revenue for t in b.trips) for b in self.blocks)


def _files(path: Path) -> set[str]:
    if path.is_dir():
        return {p.name for p in path.iterdir()}
    if zipfile.is_zipfile(path):
        with zipfile.ZipFile(path) as z:
            return {Path(n).name for n in z.namelist()}
    raise ConfigError(f"GTFS feed {path}: neither a folder nor a zip file.")


def haversine_m(lat1, lon1, lat2, lon2):
    """Great-circle distance [m] between points given in degrees (arrays broadcast)."""
    p1, p2 = np.radians(lat1), np.radians(lat2)
    dp, dl = p2 - p1, np.radians(np.asarray(lon2) - np.asarray(lon1))
    h = np.sin(dp / 2) ** 2 + np.cos(p1) * np.cos(p2) * np.sin(dl / 2) ** 2
    return 2 * EARTH_M * np.arcsin(np.sqrt(np.minimum(h, 1.0)))


def check_feed(path: str | Path) -> Path:
    """The feed's path, or a ConfigError naming what is missing."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"GTFS feed {path} does not exist: give a zip or a folder of .txt "
                          "files.")
    files = _files(path)
    missing = [f for f in REQUIRED if f not in files]
    if "calendar.txt" not in files and "calendar_dates.txt" not in files:
        missing.append("calendar.txt or calendar_dates.txt")
    if missing:
        raise ConfigError(f"GTFS feed {path} lacks {', '.join(missing)}: a feed needs routes, "
                          "trips, stop times, stops and a calendar to give a service day.")
    return path


def _partridge():
    import warnings

    import partridge as ptg

    warnings.filterwarnings("ignore", module="partridge")  # its pandas deprecations, not ours
    return ptg


def _load(path: Path, services):
    """The feed's tables, read and parsed (times to seconds) by partridge on first use. Its
    pruning along the files' dependencies is left out (a config with its parsers but no
    edges): pandas' string ``isin`` is slow on large tables, so the day's trips and their stop
    times are picked here (:func:`_in`)."""
    ptg = _partridge()
    from partridge.config import add_node_config, empty_config

    return ptg.load_feed(str(path), config=add_node_config(empty_config()))


def _in(column: pd.Series, values) -> np.ndarray:
    """Where ``column``'s values are among ``values`` (hashed, as plain Python strings)."""
    return column.astype(object).isin(set(map(str, values))).to_numpy()


def _by_date(path: Path, day: Date) -> frozenset:
    dates = _partridge().read_service_ids_by_date(str(path))
    if day not in dates:
        span = f"{min(dates)} to {max(dates)}" if dates else "no date at all"
        raise ConfigError(f"GTFS feed {path}: no service runs on {day} (its calendar covers "
                          f"{span}); give a date of the feed's calendar.")
    return dates[day]


def _expand_frequencies(trips: pd.DataFrame, times: pd.DataFrame, freq: pd.DataFrame,
                        notes: list[str]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Each frequency-based trip copied to every departure of its windows."""
    if freq is None or freq.empty:
        return trips, times
    new_trips, new_times = [], []
    copies = 0
    for trip_id, windows in freq.groupby("trip_id"):
        base = times[times["trip_id"] == trip_id]
        if base.empty:
            continue
        t0 = base["departure_time"].min()
        row = trips[trips["trip_id"] == trip_id]
        for _, w in windows.iterrows():
            start, end, headway = float(w["start_time"]), float(w["end_time"]), \
                float(w["headway_secs"])
            if not headway > 0 or end <= start:
                raise ConfigError(f"frequencies.txt: trip {trip_id} has headway_secs = "
                                  f"{w['headway_secs']} from {clock(start)} to {clock(end)}: "
                                  "give a headway > 0 and end_time after start_time.")
            for dep in np.arange(start, end, headway):
                name = f"{trip_id}@{clock(dep)}"
                copy = base.copy()
                copy["arrival_time"] += dep - t0
                copy["departure_time"] += dep - t0
                copy["trip_id"] = name
                new_times.append(copy)
                new_trips.append(row.assign(trip_id=name))
                copies += 1
    notes.append(f"frequencies.txt: {freq['trip_id'].nunique()} trip(s) run at headways "
                 f"expanded into {copies} departures")
    keep = ~_in(trips["trip_id"], freq["trip_id"])
    trips = pd.concat([trips[keep], *new_trips], ignore_index=True)
    times = pd.concat([times[~_in(times["trip_id"], freq["trip_id"])], *new_times],
                      ignore_index=True)
    return trips, times


def _shape_points(shapes: pd.DataFrame) -> dict[str, pd.DataFrame]:
    if shapes is None or shapes.empty:
        return {}
    shapes = shapes.sort_values(["shape_id", "shape_pt_sequence"])
    return {str(k): g for k, g in shapes.groupby("shape_id")}


def _along_shape(lat, lon, shape: pd.DataFrame) -> tuple[np.ndarray, float]:
    """Stops projected onto a shape's polyline, in order (never backwards): distance along the
    shape [m] and the largest gap from a stop to the line [m] (a local flat projection)."""
    slat, slon = shape["shape_pt_lat"].to_numpy(float), shape["shape_pt_lon"].to_numpy(float)
    k = np.radians(1.0) * EARTH_M
    cos = np.cos(np.radians(slat.mean()))
    px, py = slon * k * cos, slat * k
    sx, sy = np.asarray(lon, float) * k * cos, np.asarray(lat, float) * k
    dx, dy = np.diff(px), np.diff(py)
    seg = np.hypot(dx, dy)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    out, worst, pos = np.zeros(len(sx)), 0.0, 0.0
    for i in range(len(sx)):
        u = np.clip(((sx[i] - px[:-1]) * dx + (sy[i] - py[:-1]) * dy)
                    / np.maximum(seg * seg, 1e-9), 0.0, 1.0)
        along = cum[:-1] + u * seg
        gap = np.hypot(px[:-1] + u * dx - sx[i], py[:-1] + u * dy - sy[i])
        gap = np.where(along >= pos - 1.0, gap, np.inf)  # never backwards
        j = int(np.argmin(gap))
        worst = max(worst, float(gap[j]))
        out[i] = pos = float(along[j])
    return out, worst


def _profile_csv(path: str | Path | None, column: str, factor: float, what: str
                 ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """A per-shape CSV (shape_id, shape_dist_traveled, ``column``) as arrays in metres."""
    if path is None:
        return {}
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"{what} file {path} does not exist.")
    frame = pd.read_csv(path, dtype={"shape_id": str})
    need = ["shape_id", "shape_dist_traveled", column]
    missing = [c for c in need if c not in frame.columns]
    if missing:
        raise ConfigError(f"{what} file {path} lacks the column(s) {', '.join(missing)}; give "
                          f"{', '.join(need)} (distances in the feed's unit).")
    bad = frame[column].isna() | frame["shape_dist_traveled"].isna()
    if bad.any():
        raise ConfigError(f"{what} file {path}, row {int(np.flatnonzero(bad)[0]) + 2}: empty "
                          f"{column} or shape_dist_traveled.")
    out = {}
    for shape_id, g in frame.groupby("shape_id"):
        g = g.sort_values("shape_dist_traveled")
        out[str(shape_id)] = (g["shape_dist_traveled"].to_numpy(float) * factor,
                              g[column].to_numpy(float))
    return out


def _unit(times: pd.DataFrame, straight: np.ndarray) -> tuple[float, str]:
    """The unit of ``shape_dist_traveled``: the one that makes it closest to (and not much
    shorter than) the stops' straight-line distances."""
    given = times["shape_dist_traveled"].to_numpy(float)
    ok = np.isfinite(given) & (straight > 0)
    if not ok.any():
        return 1.0, "m"
    ratio = float(np.median(straight[ok] / np.maximum(given[ok], 1e-9)))
    name = min(UNITS, key=lambda u: abs(np.log(max(ratio, 1e-9) / UNITS[u]) - np.log(1.1)))
    return UNITS[name], name


def read_network_day(feed: str | Path, day: Date | str, *, routes=None,
                     altitude: str | Path | None = None, speed_limits: str | Path | None = None,
                     chargers: dict[str, Charger] | None = None, depot: Charger | None = None,
                     min_layover_s: float = 180.0, deadhead_speed_kmh: float = 25.0,
                     detour_factor: float = 1.3, mixed_blocks: str = "whole") -> NetworkDay:
    """The blocks of a service day of a GTFS feed (zip or folder), for the ``routes``
    (route_short_name or route_id; None: all) to electrify. See the module docstring."""
    from ebus_env.gtfs.scheduling import chain_trips, deadhead

    path = check_feed(feed)
    day = Date.fromisoformat(str(day)) if not isinstance(day, Date) else day
    if mixed_blocks not in ("whole", "report"):
        raise ConfigError(f"mixed_blocks = {mixed_blocks!r}: give 'whole' (electrify a block "
                          "with all its trips) or 'report' (list it, do not drive it).")
    services = _by_date(path, day)
    f = _load(path, services)
    notes: list[str] = [f"service {day}: {len(services)} service id(s) "
                        f"({', '.join(sorted(map(str, services))[:5])})"]
    trips = f.trips[_in(f.trips["service_id"], services)].copy()
    times = f.stop_times[_in(f.stop_times["trip_id"], trips["trip_id"])].copy()
    stops = f.stops
    route_names = f.routes.set_index("route_id")
    short = route_names["route_short_name"] if "route_short_name" in route_names else \
        pd.Series(dtype=str)
    trips["route_name"] = [str(short.get(r, r)) if pd.notna(short.get(r, None)) else str(r)
                           for r in trips["route_id"]]
    electric = set(map(str, routes)) if routes else None
    if electric is not None:
        known = set(trips["route_name"]) | set(map(str, trips["route_id"]))
        unknown = sorted(electric - known)
        if unknown:
            raise ConfigError(f"routes {unknown} run no trip on {day}; routes that do: "
                              f"{', '.join(sorted(set(trips['route_name'])))}.")
    freq = getattr(f, "frequencies", None)
    trips, times = _expand_frequencies(trips, times, freq, notes)
    times = times.sort_values(["trip_id", "stop_sequence"])
    no_times = sorted(set(trips["trip_id"]) - set(times["trip_id"]))
    not_served: dict[str, str] = {}
    if no_times:
        notes.append(f"{len(no_times)} trip(s) have no stop times and are not driven: "
                     f"{', '.join(no_times[:5])}{' ...' if len(no_times) > 5 else ''}")
        for t in no_times:
            not_served[t] = "no stop times in stop_times.txt"
        trips = trips[~_in(trips["trip_id"], no_times)]
    # times at stops that are not timepoints: interpolated by distance below
    stop_xy = stops.set_index("stop_id")[["stop_lat", "stop_lon"]]
    missing_stops = sorted(set(times["stop_id"]) - set(stop_xy.index))
    if missing_stops:
        raise ConfigError(f"stop_times.txt names stop(s) {', '.join(map(str, missing_stops[:5]))} "
                          "that stops.txt lacks: add them to stops.txt.")
    lat = stop_xy["stop_lat"].reindex(times["stop_id"]).to_numpy(float)
    lon = stop_xy["stop_lon"].reindex(times["stop_id"]).to_numpy(float)
    same = times["trip_id"].to_numpy()
    first = np.concatenate([[True], same[1:] != same[:-1]])
    step = np.where(first, 0.0, haversine_m(np.roll(lat, 1), np.roll(lon, 1), lat, lon))
    straight = pd.Series(step).groupby(same).cumsum().to_numpy()
    has_dist = "shape_dist_traveled" in times and times["shape_dist_traveled"].notna().any()
    factor, unit = _unit(times, straight) if has_dist else (1.0, "m")
    if has_dist:
        notes.append(f"shape_dist_traveled read in {unit} (against the stops' straight lines)")
    shapes = _shape_points(getattr(f, "shapes", None))
    alt = _profile_csv(altitude, "altitude_m", factor, "altitude")
    lim = _profile_csv(speed_limits, "speed_limit_kmh", factor, "speed limit")
    info = {r["trip_id"]: r for r in trips.to_dict("records")}
    made: dict[str, Trip] = {}
    repairs = {"interpolated": 0, "projected": 0, "straight": 0, "mismatch": []}
    flat = 0
    # every trip's rows as slices of plain arrays (times are sorted by trip, stop_sequence)
    trip_col = times["trip_id"].astype(str).to_numpy()
    starts = np.flatnonzero(np.concatenate([[True], trip_col[1:] != trip_col[:-1]]))
    ends = np.append(starts[1:], len(trip_col))
    arr_all = times["arrival_time"].to_numpy(float)
    dep_all = times["departure_time"].to_numpy(float)
    stop_all = times["stop_id"].astype(str).to_numpy()
    seq_all = times["stop_sequence"].to_numpy()
    dist_all = times["shape_dist_traveled"].to_numpy(float) * factor if has_dist else \
        np.full(len(times), np.nan)
    for lo, hi in zip(starts, ends, strict=True):
        trip_id = trip_col[lo]
        row = info.get(trip_id)
        if row is None:
            continue
        shape = row.get("shape_id")
        shape_id = str(shape) if shape is not None and pd.notna(shape) and str(shape) else None
        d = dist_all[lo:hi]
        if not np.isfinite(d).all():
            if shape_id in shapes:
                d, worst = _along_shape(lat[lo:hi], lon[lo:hi], shapes[shape_id])
                if worst > SHAPE_MATCH_M:
                    repairs["mismatch"].append(f"{trip_id} ({worst:.0f} m from {shape_id})")
                    d = straight[lo:hi]
                else:
                    repairs["projected"] += 1
            else:
                d = straight[lo:hi]
                repairs["straight"] += 1
        if hi - lo < 2:
            not_served[trip_id] = "fewer than two stop times"
            continue
        arr, dep = arr_all[lo:hi], dep_all[lo:hi]
        arr = np.where(np.isnan(arr), dep, arr)
        dep = np.where(np.isnan(dep), arr, dep)
        if np.isnan(arr[[0, -1]]).any():
            raise ConfigError(f"stop_times.txt: trip {trip_id} has no time at its first or "
                              "last stop; GTFS requires both.")
        if np.isnan(arr).any():
            known = ~np.isnan(arr)
            arr = np.interp(d, d[known], arr[known])
            dep = np.where(np.isnan(dep), arr, dep)
            repairs["interpolated"] += 1
        back = (np.diff(arr) < 0) | (np.diff(d) < -1.0)
        if back.any():
            seq = seq_all[lo + int(np.argmax(back)) + 1]
            raise ConfigError(f"stop_times.txt: trip {trip_id} goes back in time or distance "
                              f"at stop_sequence {seq}: fix its times or shape_dist_traveled.")
        offset = float(d[0]) if has_dist else 0.0  # where the trip starts on its shape
        d = np.maximum.accumulate(d - d[0])
        ids = stop_all[lo:hi]
        st = tuple(map(StopTime, ids.tolist(), arr.tolist(), dep.tolist(), d.tolist()))
        a_prof = None
        if shape_id in alt:
            a_prof = _clip_profile(*alt[shape_id], offset, d[-1])
        else:
            flat += 1
        l_prof = _clip_profile(*lim[shape_id], offset, d[-1]) if shape_id in lim else None
        made[trip_id] = Trip(trip_id, str(row["route_name"]), float(dep[0]), float(arr[-1]),
                             ids[0], ids[-1], float(d[-1]), st, altitude=a_prof,
                             speed_limit=l_prof)
    if repairs["interpolated"]:
        notes.append(f"{repairs['interpolated']} trip(s) had stops without times (not "
                     "timepoints): times interpolated by distance between timepoints")
    if repairs["projected"]:
        notes.append(f"{repairs['projected']} trip(s) without shape_dist_traveled: stops "
                     "projected onto their shape")
    if repairs["straight"]:
        notes.append(f"{repairs['straight']} trip(s) without a shape: distance from straight "
                     "lines between stops (short of the road's)")
    if repairs["mismatch"]:
        notes.append(f"{len(repairs['mismatch'])} trip(s) whose shape does not match their "
                     f"stops (> {SHAPE_MATCH_M:g} m): distance from straight lines between "
                     f"stops instead: {', '.join(repairs['mismatch'][:3])}")
    if flat:
        notes.append(f"grade zero on {flat} trip(s): "
                     + ("no altitude file given" if altitude is None else
                        "their shape is not in the altitude file"))
    # blocks: the feed's block_id, else chained by the scheduler
    ordered = trips[_in(trips["trip_id"], made)].copy()
    ordered["start"] = [made[t].start_s for t in ordered["trip_id"]]
    ordered = ordered.sort_values("start")
    has_block = "block_id" in ordered and ordered["block_id"].notna()
    groups: dict[str, list[Trip]] = {}
    if has_block is not False and has_block.any():
        for block_id, g in ordered[has_block].groupby("block_id", sort=False):
            groups[str(block_id)] = [made[t] for t in g["trip_id"]]
    loose = [made[t] for t in (ordered["trip_id"] if has_block is False
                               else ordered.loc[~has_block, "trip_id"])]
    if electric is not None:  # only the trips to electrify need a vehicle of the study's
        loose = [t for t in loose if t.route in electric or _route_id(trips, t) in electric]
    xy = {str(k): (float(v["stop_lat"]), float(v["stop_lon"])) for k, v in stop_xy.iterrows()}
    scheduled = "block_id"
    if loose:
        chained = chain_trips(loose, xy, min_layover_s, deadhead_speed_kmh, detour_factor)
        for i, chain in enumerate(chained):
            groups[f"auto{i + 1}"] = chain
        scheduled = ("block_id, and " if groups.keys() - {f"auto{i + 1}" for i in
                                                              range(len(chained))} else "") + \
            (f"vehicle scheduling (greedy, min layover {min_layover_s / 60:g} min, deadheads at "
             f"{deadhead_speed_kmh:g} km/h x {detour_factor:g} detour) for {len(loose)} trips "
             "without one")
        notes.append(f"{len(loose)} trip(s) without block_id chained into {len(chained)} "
                     "block(s) by the greedy vehicle scheduler")
    blocks, not_driven = [], {}
    for block_id, chain in groups.items():
        routes_in = {t.route for t in chain}
        if electric is not None and not routes_in & electric:
            continue
        if electric is not None and routes_in - electric:
            if mixed_blocks == "report":
                not_driven[block_id] = (f"mixes electrified and other routes "
                                        f"({', '.join(sorted(routes_in))})")
                for t in chain:
                    if t.route in electric:
                        not_served[t.trip_id] = f"block {block_id} mixes routes"
                continue
        full = chain if block_id.startswith("auto") else \
            _with_deadheads(chain, xy, min_layover_s, deadhead_speed_kmh, detour_factor, deadhead)
        block = Block(block_id, tuple(full),
                      {k: v for k, v in (chargers or {}).items()
                       if any(t.end_stop == k for t in full)}, depot)
        problems = block.problems()
        if problems:
            not_driven[block_id] = "; ".join(problems)
            for t in chain:
                not_served[t.trip_id] = f"block {block_id} cannot be driven"
            continue
        blocks.append(block)
    if electric is not None and mixed_blocks == "whole":
        mixed = sum(1 for b in blocks if {t.route for t in b.trips if t.revenue} - electric)
        if mixed:
            notes.append(f"{mixed} block(s) mix electrified and other routes: electrified whole "
                         "(every trip of the block)")
    short = [b.block_id for b in blocks if any(
        lay.duration_s < min_layover_s - 1e-6 for lay in b.layovers())]
    if short:
        notes.append(f"{len(short)} block(s) have a layover shorter than "
                     f"{min_layover_s / 60:g} min (driven as timetabled): "
                     f"{', '.join(short[:5])}")
    return NetworkDay(day, blocks, not_driven, not_served, notes, flat, scheduled)


def _route_id(trips: pd.DataFrame, trip: Trip) -> str:
    row = trips.loc[trips["trip_id"] == trip.trip_id.split("@")[0], "route_id"]
    return str(row.iloc[0]) if len(row) else ""


def _clip_profile(x, z, offset_m: float, length_m: float):
    """A shape's profile (distance along the shape [m], value) along a trip that starts
    ``offset_m`` into the shape and runs ``length_m``: from 0 at its first stop."""
    lo, hi = np.searchsorted(x, [offset_m - 50.0, offset_m + length_m + 50.0])
    if hi - lo < 2:
        return (x - offset_m, z)
    return (x[lo:hi] - offset_m, z[lo:hi])


def _with_deadheads(chain, xy, min_layover_s, speed_kmh, detour, deadhead):
    """A block's trips with a deadhead wherever a trip starts at another stop than the last
    one ended (the block's problems then say when it does not fit)."""
    out = [chain[0]]
    for b in chain[1:]:
        a = out[-1]
        if b.start_stop != a.end_stop:
            out.append(deadhead(a.end_stop, b.start_stop, a.end_s, xy, speed_kmh, detour))
        out.append(b)
    return out
