"""Windowed (online) tuning: refine the parameters window by window as the day's data comes in.

The paper's window technique makes tuning faster and usable online. The details are not
published; this is what is done here (every constant is a setting):

1. **Windows by driving category.** Each minute of a log is charging (plugged in), idle
   (standing), stop-and-go (stands part of the minute) or constant speed. A window ends where
   the category changes, once it is at least ``min_window_min`` long (and at most
   ``max_window_min``), so that windows close on whole charging events or drives. The first
   window lasts until it has seen every category of the log, so that its search can tell
   every parameter (the charging ones need a charging event).
2. **Tune window by window.** The first window gets a global search: iSOPT
   (``first_iterations``), then a Levenberg-Marquardt polish of its best distinct points.
   After each later window the estimate is refined on all data up to its end (an online tuner
   has exactly that) with a few Levenberg-Marquardt iterations (``iterations``) from the
   previous estimate, which first predicts the new window: that prediction error is what an
   online user sees. (Local steps cannot leave a wrong valley; a global search on all data
   so far at every window would cost as much as offline tuning.)
   Before tuning, the previous parameters predict window w: that prediction error is what an
   online user sees.
3. **Stop when converged, else repeat over the day.** When, on ``settle`` consecutive windows,
   the normalised parameters move by less than ``tolerance`` and the previous estimate
   predicts the new window within ``prediction_ratio`` times its fit so far, tuning stops (the
   rest of the data is not needed). If the day ends first, the whole day is tuned again, up to
   ``passes`` times.

Early windows are short, later ones are warm-started and brief, and tuning stops once the
estimate settles, so the total simulated time is well below offline tuning's.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ebus_env.calibration.isopt import History, ISOPTSettings, Progress, isopt
from ebus_env.calibration.local import distinct_starts, polish
from ebus_env.calibration.problem import CalibrationProblem
from ebus_env.errors import ConfigError
from ebus_env.profile import STANDING_SPEED_MPS, Profile

CATEGORIES = ("charging", "idle", "stop-and-go", "constant speed")


@dataclass
class WindowSettings:
    min_window_min: float = 60.0
    max_window_min: float = 180.0
    first_iterations: int = 30
    iterations: int = 5
    tolerance: float = 0.03
    settle: int = 3
    passes: int = 2
    prediction_ratio: float = 1.5
    nrmse_floor: float = 0.002  # fits below this count as equal (SoC resolution)


def categorise(profile: Profile) -> np.ndarray:
    """Driving category (index into CATEGORIES) of each whole minute of a profile."""
    per_min = int(round(60.0 / profile.dt_s))
    n = profile.n_steps // per_min
    if n == 0:
        return np.zeros(0, dtype=int)
    v = profile.channels["speed_ref_mps"][: n * per_min].reshape(n, per_min)
    plugged = profile.channel("charger_connected")[: n * per_min].reshape(n, per_min)
    standing = (v < STANDING_SPEED_MPS).mean(axis=1)
    cat = np.full(n, 3)
    cat[standing > 0.1] = 2
    cat[standing > 0.95] = 1
    cat[plugged.mean(axis=1) > 0.5] = 0
    return cat


def window_ends(profile: Profile, settings: WindowSettings) -> list[tuple[int, str]]:
    """(end row, category of the data just before it) of each window of a profile."""
    cat = categorise(profile)
    per_min = int(round(60.0 / profile.dt_s))
    if len(cat) < settings.min_window_min:
        raise ConfigError(
            f"Profile '{profile.name}' is {profile.duration_s / 60:.0f} min long, shorter than "
            f"one window ({settings.min_window_min:g} min): tune it offline (without "
            "--windowed) or give a longer log.")
    # the first window lasts until it has seen every category the log has (a first search on
    # a window without charging could not tell the charging parameters)
    first_seen = max(int(np.flatnonzero(cat == c)[0]) for c in np.unique(cat))
    ends: list[tuple[int, str]] = []
    start = 0
    for minute in range(1, len(cat) + 1):
        length = minute - start
        boundary = minute == len(cat) or cat[minute] != cat[minute - 1]
        if not ends and minute <= first_seen:
            continue
        if (boundary and length >= settings.min_window_min) or length >= settings.max_window_min:
            ends.append((minute * per_min, CATEGORIES[cat[minute - 1]]))
            start = minute
    if ends[-1][0] < profile.n_steps:
        ends[-1] = (profile.n_steps, ends[-1][1])  # the last window holds the tail
    return ends


def tune_windowed(problem: CalibrationProblem, settings: ISOPTSettings,
                  window_settings: WindowSettings | None = None, progress: Progress | None = None,
                  start_u: np.ndarray | None = None
                  ) -> tuple[np.ndarray, float, History, int, bool, list[dict[str, Any]]]:
    """Windowed tuning of ``problem`` (see module docstring). Returns (best u, its cost on all
    data, history, evaluations, interrupted, per-window log). ``start_u`` (normalised
    parameters, e.g. the last fit of a bus whose data keep coming) warm-starts it: every
    window, the first too, is then refined locally from it, with no global search."""
    ws = window_settings or WindowSettings()
    profiles = [d.profile for d in problem.data]
    plan = [(i, end, cat) for i, p in enumerate(profiles) for end, cat in window_ends(p, ws)]
    bounds = {p: (problem.low[j], problem.high[j]) for j, p in enumerate(problem.free)}
    fixed = {n: v for n, v in zip(problem.model.param_names, problem.base, strict=True)
             if n not in problem.free}
    history = History()
    log: list[dict] = []
    spent = 0
    interrupted = False
    u: np.ndarray | None = None if start_u is None else np.asarray(start_u, float).copy()
    settled = 0
    previous_fit = np.inf
    try:
        for sweep in range(ws.passes):
            steps = plan if sweep == 0 else plan[-1:]
            for k, (i, end, category) in enumerate(steps):
                data_seen = profiles[:i] + [profiles[i].slice(0, end)]
                sub = CalibrationProblem(problem.model, data_seen, problem.free, bounds, fixed,
                                         problem.categorical, problem.chunks,
                                         charge=problem.charge)
                end_h = (sum(p.duration_s for p in profiles[:i]) + end * profiles[i].dt_s) / 3600.0
                row: dict[str, Any] = {"pass": sweep + 1, "end_h": end_h, "category": category}
                if u is not None:
                    # the previous estimate predicts the new data (what an online user sees)
                    start = log[-1]["end_h"] if log and log[-1]["pass"] == sweep + 1 else 0.0
                    row["prediction_nrmse"] = _window_error(sub, u, start)
                if u is None:
                    # a global search on the first window
                    run = isopt(sub.cost, len(problem.free),
                                replace(settings, iterations=ws.first_iterations,
                                        seed=settings.seed + 100 * sweep + k))
                    interrupted = run.interrupted
                    x_all, c_all = run.history.all_evaluated()
                    starts = distinct_starts(x_all, c_all)
                    row["search"] = "global"
                else:
                    starts = u[None]
                    row["search"] = "local"
                points, _, _ = polish(sub, starts, iterations=ws.iterations)
                costs = sub.cost(points)
                new_u, cost = points[int(np.argmin(costs))], float(costs.min())
                moved = np.inf if u is None else float(np.max(np.abs(new_u - u)))
                spent += sub.evaluations
                problem.simulated_steps += sub.simulated_steps
                u = new_u
                row.update({"nrmse_so_far": float(cost), "moved": moved,
                            "evaluations": sub.evaluations})
                log.append(row)
                history.best_cost.append(float(cost))
                history.best_x.append(u.copy())
                history.evaluations.append(spent)
                if progress:
                    progress(len(log), float(cost), spent)
                if interrupted:
                    raise KeyboardInterrupt
                # settled: the estimate stopped moving and predicted the new window about as
                # well as it fits the data before it
                predicted = row.get("prediction_nrmse", np.inf) <= ws.prediction_ratio * max(
                    previous_fit, ws.nrmse_floor)
                settled = settled + 1 if (moved < ws.tolerance and predicted) else 0
                previous_fit = float(cost)
                if settled >= ws.settle:
                    break
            if settled >= ws.settle:
                break
    except KeyboardInterrupt:
        interrupted = True
    if u is None:
        raise KeyboardInterrupt("interrupted before the first window was tuned")
    cost = float(problem.cost(u[None])[0])
    history.x, history.cost = [u[None]], [np.array([cost])]
    return u, cost, history, spent + problem.evaluations, interrupted, log


def _window_error(seen: CalibrationProblem, u: np.ndarray, start_h: float) -> float:
    """NRMSE of ``u`` on the data of ``seen`` after ``start_h`` hours (the new window)."""
    residual = seen.residuals(u[None])[0] * np.sqrt(seen.n_samples) * seen.span
    offsets = np.cumsum([0.0] + [d.profile.duration_s for d in seen.data])[:-1] / 3600.0
    times = np.concatenate([off + d.rows * d.profile.dt_s / 3600.0
                            for off, d in zip(offsets, seen.data, strict=True)])
    new = times >= start_h - 1e-9
    measured = np.concatenate([d.measured for d in seen.data])[new]
    span = np.ptp(measured)
    return float(np.sqrt(np.mean(residual[new] ** 2)) / span) if span > 0 else float("nan")
