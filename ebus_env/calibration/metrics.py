"""Fit statistics of simulated against measured SoC.

NRMSE is the paper's equation 1: the RMSE of SoC divided by the range of the measured SoC,
``sqrt(mean((SoC_sim - SoC_meas)^2)) / (max SoC_meas - min SoC_meas)``.
"""

from __future__ import annotations

import numpy as np


def nrmse(simulated: np.ndarray, measured: np.ndarray) -> float:
    """Range-normalised RMSE (paper eq. 1), both in the same unit."""
    span = float(np.max(measured) - np.min(measured))
    rmse = float(np.sqrt(np.mean((simulated - measured) ** 2)))
    return rmse / span if span > 0 else float("nan")


def soc_fit(simulated_frac: np.ndarray, measured_frac: np.ndarray) -> dict:
    """NRMSE, RMSE [%-points], max |error| [%-points], Pearson correlation and final-SoC error
    [%-points] of SoC sampled at the same instants (fractions in, percent out)."""
    sim = 100.0 * np.asarray(simulated_frac, dtype=float)
    meas = 100.0 * np.asarray(measured_frac, dtype=float)
    err = sim - meas
    corr = float(np.corrcoef(sim, meas)[0, 1]) if np.std(sim) > 0 and np.std(meas) > 0 \
        else float("nan")
    return {
        "nrmse": nrmse(sim, meas),
        "rmse_pct": float(np.sqrt(np.mean(err**2))),
        "max_abs_error_pct": float(np.max(np.abs(err))),
        "correlation": corr,
        "final_soc_error_pct": float(err[-1]),
        "samples": int(len(err)),
    }
