"""Road grade from an altitude profile, smoothed over distance.

GPS and map altitude is noisy; differentiated sample by sample it gives grades of tens of
percent. The altitude is therefore put on a uniform distance grid, smoothed with a centred
moving average over ``window_m`` metres, differentiated there, and the grade read back at each
sample's distance. While the vehicle stands the distance does not change, so neither does the
grade. Grades beyond ``max_grade_frac`` are clipped and counted.
"""

from __future__ import annotations

import numpy as np

DEFAULT_WINDOW_M = 100.0
DEFAULT_MAX_GRADE_FRAC = 0.15


def grade_from_altitude(distance_m: np.ndarray, altitude_m: np.ndarray,
                        window_m: float = DEFAULT_WINDOW_M, step_m: float = 5.0,
                        max_grade_frac: float = DEFAULT_MAX_GRADE_FRAC) -> tuple[np.ndarray, int]:
    """Grade [rise/run] at each sample, and how many samples were clipped.

    Parameters
    ----------
    distance_m
        Cumulative distance at each sample (non-decreasing) [m].
    altitude_m
        Altitude at each sample [m].
    window_m
        Length of the moving-average window [m].
    step_m
        Spacing of the distance grid [m].
    max_grade_frac
        Largest plausible grade; larger values are clipped.
    """
    distance_m = np.asarray(distance_m, dtype=float)
    altitude_m = np.asarray(altitude_m, dtype=float)
    if distance_m[-1] - distance_m[0] < 2 * step_m:
        return np.zeros_like(distance_m), 0
    # one altitude per distance: average the samples taken at the same place (standing)
    unique_d, inverse = np.unique(distance_m, return_inverse=True)
    sums = np.bincount(inverse, weights=altitude_m)
    counts = np.bincount(inverse)
    unique_alt = sums / counts
    d = np.arange(unique_d[0], unique_d[-1] + step_m, step_m)
    alt = np.interp(d, unique_d, unique_alt)
    half = max(1, int(round(window_m / step_m / 2)))
    kernel = np.ones(2 * half + 1) / (2 * half + 1)
    padded = np.pad(alt, half, mode="edge")
    smooth = np.convolve(padded, kernel, mode="valid")
    grade_grid = np.gradient(smooth, step_m)
    grade = np.interp(distance_m, d, grade_grid)
    clipped = int(np.sum(np.abs(grade) > max_grade_frac))
    return np.clip(grade, -max_grade_frac, max_grade_frac), clipped
