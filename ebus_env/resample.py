"""Bring time series onto the simulation grid.

* ``linear``: linear interpolation, for signals sampled as coarsely as the grid or more
  coarsely (up-sampling, e.g. a 1 Hz log to 10 Hz);
* ``mean``: the mean of the linearly interpolated signal over each grid step's window
  [t - dt/2, t + dt/2], for finer signals (down-sampling, e.g. 20 Hz to 10 Hz): it keeps the
  integral, so speed keeps its distance;
* ``hold``: the last sample at or before each grid time, for flags and counts.
"""

from __future__ import annotations

import numpy as np


def grid(t_start_s: float, t_end_s: float, dt_s: float) -> np.ndarray:
    """Uniform grid from ``t_start_s`` covering ``t_end_s`` (within half a step)."""
    n = int(np.floor((t_end_s - t_start_s) / dt_s + 0.5)) + 1
    return t_start_s + dt_s * np.arange(n)


def window_mean(time_s: np.ndarray, values: np.ndarray, grid_s: np.ndarray,
                dt_s: float) -> np.ndarray:
    """Mean of the piecewise-linear signal over [t - dt/2, t + dt/2] (clipped to its span)."""
    area = np.concatenate([[0.0], np.cumsum(0.5 * (values[1:] + values[:-1]) * np.diff(time_s))])
    lo = np.clip(grid_s - 0.5 * dt_s, time_s[0], time_s[-1])
    hi = np.clip(grid_s + 0.5 * dt_s, time_s[0], time_s[-1])
    width = hi - lo
    mean = np.interp(grid_s, time_s, values)  # fallback where the window has no width
    ok = width > 0
    mean[ok] = (np.interp(hi[ok], time_s, area) - np.interp(lo[ok], time_s, area)) / width[ok]
    return mean


def hold(time_s: np.ndarray, values: np.ndarray, grid_s: np.ndarray) -> np.ndarray:
    """Last sample at or before each grid time (the first sample before the log starts)."""
    idx = np.searchsorted(time_s, grid_s + 1e-9, side="right") - 1
    return values[np.clip(idx, 0, len(values) - 1)]


def resample(time_s: np.ndarray, values: np.ndarray, grid_s: np.ndarray, dt_s: float,
             kind: str = "auto") -> np.ndarray:
    """Resample ``values(time_s)`` onto ``grid_s`` (see module docstring); ``auto`` takes
    ``mean`` when the samples are finer than the grid, else ``linear``."""
    time_s = np.asarray(time_s, dtype=float)
    values = np.asarray(values, dtype=float)
    if kind == "auto":
        kind = "mean" if np.median(np.diff(time_s)) < dt_s * 0.999 else "linear"
    if kind == "linear":
        return np.interp(grid_s, time_s, values)
    if kind == "mean":
        return window_mean(time_s, values, grid_s, dt_s)
    if kind == "hold":
        return hold(time_s, values, grid_s)
    raise ValueError(f"Unknown resampling kind '{kind}' (linear, mean, hold, auto).")
