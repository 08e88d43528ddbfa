"""A course: the line a bus drives lap after lap, in the distance domain.

ECO-driving changes *how* the bus drives, not *where*: the stops stay where they are and a lap
stays as long. So the environments describe a line by distance (a 1 m grid): the speed the
reference driver drives at each metre, the grade, the stops with their dwell times, and the
baseline time to reach each metre (the timetable). :mod:`ebus_env.envs.reference_vehicle` drives it
under the agent's speed and acceleration caps.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ebus_env.cycles import Cycle, load_cycle
from ebus_env.errors import ConfigError

STEP_M = 1.0
STANDING_MPS = 0.05


@dataclass(frozen=True)
class Course:
    """One lap of a line on a grid of about ``STEP_M``, from a terminal to the next.

    ``speed_mps[i]``: the reference driver's speed at ``i * step_m`` (the cycle's or the route
    plan's); ``grade_frac[i]``; ``stop_m``: stop positions in (0, length], the last the
    terminal; ``dwell_s``: standing time at each; ``baseline_s[i]``: time from the lap's start
    to metre ``i`` driving the reference (dwells included): the timetable.
    """

    name: str
    step_m: float
    speed_mps: np.ndarray
    grade_frac: np.ndarray
    stop_m: np.ndarray
    dwell_s: np.ndarray
    baseline_s: np.ndarray

    @property
    def length_m(self) -> float:
        return float(self.stop_m[-1])

    @property
    def lap_time_s(self) -> float:
        """Baseline time of one lap, terminal to terminal (the last dwell excluded)."""
        return float(self.baseline_s[-1])

    @property
    def mean_speed_kmh(self) -> float:
        return 3.6 * self.length_m / self.lap_time_s


def _standing_runs(standing: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) sample of each run of True."""
    edges = np.diff(np.concatenate([[0], standing.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1, strict=True))


def _first_passage_s(s: np.ndarray, t: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Time at which a non-decreasing distance ``s(t)`` first reaches each ``grid`` point."""
    i = np.clip(np.searchsorted(s, grid, side="left"), 1, len(s) - 1)
    gap = s[i] - s[i - 1]
    frac = np.where(gap > 0, (grid - s[i - 1]) / np.where(gap > 0, gap, 1.0), 1.0)
    return t[i - 1] + np.clip(frac, 0.0, 1.0) * (t[i] - t[i - 1])


def course_from_cycle(cycle: Cycle | str) -> Course:
    """A cycle as a course: its speed by distance, each stand-still a stop with its duration
    (a stand-still at the start is the departure, not a stop; the end is the terminal)."""
    if isinstance(cycle, str):
        cycle = load_cycle(cycle)
    t = np.asarray(cycle.time_s, float)
    v = np.asarray(cycle.speed_kmh, float) / 3.6
    s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    length = float(s[-1])
    if length < 10 * STEP_M:
        raise ConfigError(f"Cycle '{cycle.name}' covers {length:.1f} m: too short for a course.")
    grid = np.linspace(0.0, length, int(np.ceil(length / STEP_M)) + 1)
    moving = v > STANDING_MPS
    # speed by distance: the cycle's speed where it passed, from its moving samples
    order = np.flatnonzero(moving)
    speed = np.interp(grid, s[order], v[order])
    speed[-1] = 0.0
    grade = np.zeros_like(grid) if cycle.grade_frac is None else np.interp(
        grid, s[order], np.asarray(cycle.grade_frac, float)[order])
    stops, dwells = [], []
    for first, last in _standing_runs(~moving):
        if first == 0 or s[first] >= length - STEP_M:
            continue  # standing at the start (the departure) or at the end (the terminal)
        stops.append(float(s[first]))
        dwells.append(float(t[last] - t[first]))
    stops.append(length)
    dwells.append(0.0)
    departure = t[max(int(np.argmax(moving)) - 1, 0)]
    baseline = _first_passage_s(s, t, grid) - departure
    return Course(cycle.name, float(grid[1]), speed, grade, np.array(stops), np.array(dwells), baseline)


def course_from_route(name: str, dwell_s: float = 20.0) -> Course:
    """A King County route planned under its speed limits (see
    :meth:`ebus_env.routes.Route.cycle`) as a course: one direction (``kc45_out``) or, for a
    bare route (``kc45``), out and back as one trip."""
    from ebus_env.routes import load_route

    legs = [name] if name.endswith(("_out", "_back")) else [f"{name}_out", f"{name}_back"]
    cycles = [load_route(leg).cycle(dwell_s=dwell_s, dt_s=0.5) for leg in legs]
    trip = cycles[0] if len(cycles) == 1 else cycles[0].then(cycles[1])
    return course_from_cycle(trip)


def course_from_log(path: str | Path, columns: dict | str | None = None) -> Course:
    """A measured log's speed profile (and grade, where the log has ``grade_pct`` or
    ``altitude_m``) as a course: one trip, each stand-still a stop. Loaded and checked by
    :func:`ebus_env.io.measured.load_log` (``columns``: its column map or preset); the log's
    SoC, ambient and passengers are not used (the env draws the day)."""
    from ebus_env.io.measured import load_log

    profile = load_log(path, dt_s=0.1, columns=columns).profile
    return course_from_cycle(Cycle(Path(path).stem, profile.time_s,
                                   3.6 * profile.channel("speed_ref_mps"),
                                   profile.channel("grade_frac")))
