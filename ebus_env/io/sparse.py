"""Sparse logs (Osnabrueck-like): speed, distance and SoC only every few minutes.

The paper reconstructs the drive between two samples from the distance covered: a standard
cycle scaled to the interval's mean speed when its distance fits, otherwise constant speed.
Here, for each interval of duration T and distance d:

* no distance (d < 10 m): standing, on the charger when ``charging`` = 1 at its start;
* on the charger at its start or its end (``charging`` = 1) and distance covered: the drive
  takes d / v_c at the cycle's own mean speed v_c, the rest of the interval is on the charger
  (first when plugged in at the start, last when plugged in at the end);
* the cycle scaled to the mean speed d / T fits when one lap lasts at most T and the scaled
  cycle stays under the vehicle's top speed: laps of it fill T, and the speeds are corrected
  by the (small) factor that makes the distance exactly d;
* otherwise constant speed d / T.


The SoC is compared with the model only at the log's own sample times.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ebus_env.cycles import Cycle, load_cycle
from ebus_env.errors import LogError
from ebus_env.inputs import MAX_STEPS, RANGES, check
from ebus_env.io.measured import (
    MeasuredLog,
    _check_limits,
    _check_values,
    _numeric,
    _time,
    open_log,
)
from ebus_env.profile import Profile

SPARSE_COLUMNS = ("distance_km", "soc_pct", "soc_frac", "charging", "ambient_degc")
"""The columns a sparse log is rebuilt from; others are not read."""


def load_sparse_log(path: str | Path, dt_s: float = 0.1, cycle: str | Cycle = "sort2",
                    columns: dict | str | None = None, max_speed_kmh: float = 80.0,
                    name: str | None = None, start_h: float | None = None) -> MeasuredLog:
    """Read a sparse log (``time_s``, ``distance_km`` cumulative, ``soc_pct`` or ``soc_frac``,
    optional ``charging``, ``ambient_degc``) and reconstruct a 10 Hz profile (see module
    docstring); its columns pass the checks of :func:`~ebus_env.io.measured.load_log`, and
    every sample needs every value. ``start_h``: the time of day of the first row of a log
    without date-times, as in :func:`~ebus_env.io.measured.load_log`."""
    path, report, frame = open_log(path, columns)
    if start_h is not None:
        check("log_start_h", start_h)
    t, start_h, start_date = _time(frame, path, report, start_h)
    if "distance_km" not in frame.columns or not {"soc_pct", "soc_frac"} & set(frame.columns):
        raise LogError("A sparse log needs the columns 'distance_km' and 'soc_pct' (or "
                       "'soc_frac')", path=path,
                       fix="give cumulative distance in 'distance_km' and SoC in 'soc_pct'")
    values = {c: _numeric(frame, c, path) for c in SPARSE_COLUMNS if c in frame.columns}
    for label, column in values.items():
        bad = np.flatnonzero(np.isnan(column))
        if bad.size:
            raise LogError("Missing values", path=path, column=label, rows=bad,
                           fix="a sparse log needs every sample")
    _check_values(frame, values, t, path, report, fill="error", check_units=True)
    distance = values["distance_km"] * 1000.0
    soc = values["soc_pct"] / 100.0 if "soc_pct" in values else values["soc_frac"]
    back = np.flatnonzero(np.diff(distance) < -1e-6) + 1
    if back.size:
        raise LogError("Distance decreases", path=path, column="distance_km", rows=back,
                       fix="give the cumulative distance (odometer)")
    _check_sparse(t, distance, dt_s, path)
    charging = values.get("charging", np.zeros(len(t)))
    ambient = values.get("ambient_degc")
    base = cycle if isinstance(cycle, Cycle) else load_cycle(cycle)
    pieces, connected = [], []
    kinds = {"charging": 0, "standing": 0, "cycle": 0, "constant": 0, "split": 0}
    base_mean = base.mean_speed_kmh / 3.6
    for i in range(len(t) - 1):
        steps = int(round((t[i + 1] - t[i]) / dt_s))
        d = distance[i + 1] - distance[i]
        start_on, end_on = charging[i] > 0.5, charging[i + 1] > 0.5
        if d < 10.0:
            kind = "charging" if start_on else "standing"
            speed, plugged = np.zeros(steps), np.full(steps, float(start_on))
        else:
            drive = steps
            if start_on or end_on:  # part of the interval on the charger
                drive = max(1, min(steps, int(round(d / (base_mean * dt_s)))))
                kinds["split"] += 1
            speed, kind = _fill(base, d / (drive * dt_s), drive, dt_s, max_speed_kmh / 3.6)
            speed *= d / (np.sum(speed) * dt_s)  # the interval's distance, exactly
            rest = np.zeros(steps - drive)
            speed = np.concatenate([rest, speed] if start_on else [speed, rest])
            on = np.ones(steps - drive)
            plugged = np.concatenate([on, np.zeros(drive)] if start_on
                                     else [np.zeros(drive), on])
        kinds[kind] += 1
        pieces.append(speed)
        connected.append(plugged)
    v = np.concatenate(pieces + [[0.0]])
    n = len(v)
    rows = np.concatenate([[0], np.cumsum([len(p) for p in pieces])])
    grid_t = np.arange(n) * dt_s
    channels = {"speed_ref_mps": v, "charger_connected": np.concatenate(connected + [[0.0]])}
    if ambient is not None:
        channels["ambient_degc"] = np.interp(grid_t, t - t[0], ambient)
    measured = {"soc_frac": np.interp(grid_t, rows * dt_s, soc)}
    report.changes.append(
        f"{len(t) - 1} intervals rebuilt: {kinds['cycle']} with {base.name} scaled to their "
        f"mean speed, {kinds['constant']} at constant speed, {kinds['standing']} standing, "
        f"{kinds['charging']} charging; {kinds['split']} of the driven ones partly on the "
        "charger")
    profile = Profile(channels, dt_s, name or path.stem, start_h, measured,
                      list(report.changes), samples={"soc_frac": rows}, date=start_date)
    _check_limits([profile], max_speed_kmh, None, report)
    return MeasuredLog([profile], report)


def _check_sparse(t, distance_m, dt_s: float, path: Path) -> None:
    """Intervals of at least one step with a plausible mean speed, a day that fits in one
    run."""
    short = np.flatnonzero(np.diff(t) < dt_s) + 1
    if short.size:
        raise LogError(f"Samples closer than one time step ({dt_s:g} s)", path=path,
                       column="time_s", rows=short, fix="a sparse log has minutes between "
                       "samples; load a dense log without --sparse")
    speed = RANGES["log_speed_kmh"]
    mean_kmh = 3.6 * np.diff(distance_m) / np.diff(t)
    fast = np.flatnonzero(mean_kmh > speed.high) + 1
    if fast.size:
        raise LogError(f"Distance implies more than {speed.high:g} km/h between samples (e.g. "
                       f"{mean_kmh[fast[0] - 1]:.0f} km/h)", path=path, column="distance_km",
                       rows=fast, fix="give distance in km and time in seconds")
    if t[-1] / dt_s > MAX_STEPS:
        raise LogError(f"The log lasts {t[-1] / 3600:.1f} h, more than one run holds "
                       f"({MAX_STEPS:,} steps of {dt_s:g} s)", path=path, column="time_s",
                       fix="split it into days, or check the time unit (seconds)")


def _fill(cycle: Cycle, mean_mps: float, steps: int, dt_s: float,
          max_speed_mps: float) -> tuple[np.ndarray, str]:
    """Speeds of one interval: laps of the scaled cycle when it fits, else constant."""
    scaled = cycle.scaled(mean_mps * 3.6)
    lap = scaled.lap(dt_s)["speed_ref_mps"]
    if len(lap) <= steps and lap.max() <= max_speed_mps:
        reps = -(-steps // len(lap))
        return np.tile(lap, reps)[:steps].copy(), "cycle"
    return np.full(steps, mean_mps), "constant"
