"""Bus routes with stops, speed limits and elevation, driven as speed profiles.

A :class:`Route` is a line along the road: distance, elevation, speed limit and stops. Its
speed profile is planned in the distance domain: the bus may not exceed the speed limit,
accelerates at ``accel_mps2`` and brakes at ``decel_mps2``, stops at every stop for
``dwell_s`` (forward and backward passes over the distance grid), and the time axis follows
from distance over speed. Grade comes from the elevation smoothed over distance
(:mod:`ebus_env.grade`), so LiDAR spikes do not become grade.

Shipped routes: King County Metro routes 45, 7 and 44, both directions
(``data/routes/king_county``, MIT; see its SOURCE.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ebus_env import paths
from ebus_env.cycles import Cycle
from ebus_env.errors import ConfigError, unknown_name
from ebus_env.grade import grade_from_altitude

ROUTE_DIR = paths.data("routes", "king_county")
ROUTES = {
    "kc45_out": "rt45_sh31045010_d0.csv", "kc45_back": "rt45_sh31045010_d1.csv",
    "kc7_out": "rt7_sh10007006_d0.csv", "kc7_back": "rt7_sh10007006_d1.csv",
    "kc44_out": "rt44_sh11044004_d0.csv", "kc44_back": "rt44_sh11044004_d1.csv",
}


@dataclass(frozen=True)
class Route:
    """A route: distance [m], elevation [m], speed limit [km/h] per point, stop distances [m]."""

    name: str
    distance_m: np.ndarray
    elevation_m: np.ndarray
    speed_limit_kmh: np.ndarray
    stops_m: np.ndarray

    @property
    def length_m(self) -> float:
        return float(self.distance_m[-1])

    def grade(self, window_m: float = 100.0) -> np.ndarray:
        """Grade at each point, from the elevation smoothed over ``window_m``."""
        return grade_from_altitude(self.distance_m, self.elevation_m, window_m)[0]

    def cycle(self, accel_mps2: float = 1.0, decel_mps2: float = 0.8, dwell_s: float = 20.0,
              step_m: float = 1.0, dt_s: float = 1.0) -> Cycle:
        """The route driven stop to stop, as a cycle with grade (sampled every ``dt_s``)."""
        d = np.arange(0.0, self.length_m, step_m)
        limit = np.interp(d, self.distance_m, self.speed_limit_kmh) / 3.6
        stops = np.unique(np.clip(np.searchsorted(d, self.stops_m), 0, len(d) - 1))
        v = limit.copy()
        v[stops] = 0.0
        v[0] = v[-1] = 0.0
        for i in range(1, len(d)):  # forward: acceleration limit
            v[i] = min(v[i], np.sqrt(v[i - 1] ** 2 + 2 * accel_mps2 * step_m))
        for i in range(len(d) - 2, -1, -1):  # backward: braking limit
            v[i] = min(v[i], np.sqrt(v[i + 1] ** 2 + 2 * decel_mps2 * step_m))
        mean = 0.5 * (v[1:] + v[:-1])
        dt = np.where(mean > 0, step_m / np.maximum(mean, 1e-9), 0.0)
        # a zero-speed point that is passed (v = 0 on both sides: start, stops) gets a dwell
        t = np.concatenate([[0.0], np.cumsum(dt)])
        stop_set = set(stops.tolist()) | {0, len(d) - 1}
        dwell = np.array([dwell_s if i in stop_set else 0.0 for i in range(len(d))])
        t = t + np.cumsum(dwell) - dwell  # dwell happens at the point, before leaving it
        # time samples: standing at each stop for its dwell
        t_points = np.concatenate([t, t + dwell])
        v_points = np.concatenate([v, v])
        d_points = np.concatenate([d, d])
        order = np.argsort(t_points, kind="stable")
        t_points, v_points, d_points = t_points[order], v_points[order], d_points[order]
        keep = np.concatenate([[True], np.diff(t_points) > 1e-9])
        t_points, v_points, d_points = t_points[keep], v_points[keep], d_points[keep]
        grid = np.arange(0.0, t_points[-1], dt_s)
        speed = np.interp(grid, t_points, v_points)
        distance = np.interp(grid, t_points, d_points)
        grade = np.interp(distance, self.distance_m, self.grade())
        return Cycle(self.name, grid, 3.6 * speed, grade,
                     f"route {self.name}, {self.length_m / 1000:.1f} km, {len(stops)} stops",
                     (f"{self.name}: planned at {accel_mps2:g}/{decel_mps2:g} m/s^2 under the "
                      f"speed limits, {dwell_s:g} s at each stop, grade from elevation "
                      "smoothed over 100 m",))

    def altitude_along(self, cycle: Cycle) -> np.ndarray:
        """Elevation [m] at each sample of a cycle driven on this route (its distance)."""
        v = cycle.speed_kmh / 3.6
        distance = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(cycle.time_s))])
        return np.interp(distance, self.distance_m, self.elevation_m)


def load_route(name: str | Path) -> Route:
    """A shipped route by name (``kc45_out``...) or a CSV in the tidy King County format."""
    import pandas as pd

    if str(name) in ROUTES:
        path = ROUTE_DIR / ROUTES[str(name)]
    elif str(name).endswith(".csv"):
        path = Path(name)
    else:
        raise unknown_name("route", str(name), ROUTES)
    try:
        frame = pd.read_csv(path)
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError) as exc:
        raise ConfigError(f"Route {path} cannot be read: {exc}") from None
    columns = ("distance_m", "elevation_m", "speed_limit_kmh", "stop_id_or_-1")
    missing = [c for c in columns if c not in frame.columns]
    if missing or len(frame) < 2:
        raise ConfigError(f"Route {path} needs at least two rows and the columns "
                          f"{', '.join(columns)}; missing: {', '.join(missing) or 'rows'}.")
    stops = frame["distance_m"][frame["stop_id_or_-1"] != -1].to_numpy(float)
    return Route(Path(path).stem if str(name) not in ROUTES else str(name),
                 frame["distance_m"].to_numpy(float), frame["elevation_m"].to_numpy(float),
                 frame["speed_limit_kmh"].to_numpy(float), stops)
