"""Measured-like logs made by the model itself, degraded the way real logs are.

A synthetic twin has known parameters, so calibration and diagnostics can be checked against
the truth: simulate a profile, then sample it like a data logger (1 Hz, 0.5 Hz, ...), quantise
the SoC like a BMS (0.1-1 %), add noise, and cut a gap.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ebus_env.profile import Profile


def synthetic_log(model, profile: Profile, params: Mapping[str, float] | None = None,
                  soc_start: float = 0.95, period_s: float = 1.0, soc_step_pct: float = 0.1,
                  soc_noise_pct: float = 0.0, gap_s: tuple[float, float] | None = None,
                  seed: int = 0, **initial: float):
    """A log (pandas DataFrame with canonical columns) of ``model`` driven through ``profile``.

    Parameters
    ----------
    model, profile, params
        The model, its inputs and the true parameter values (overrides by qualified name).
    soc_start
        Initial SoC [0-1].
    period_s
        Sampling period of the log [s] (a multiple of the model's step).
    soc_step_pct
        SoC quantisation [%-points] (0: none), applied after the noise.
    soc_noise_pct
        Standard deviation of Gaussian noise on SoC [%-points].
    gap_s
        (start, end) [s]: rows in this interval are missing.
    seed
        Noise seed.
    initial
        Other initial states (``cabin_temp_degc=...``).

    Columns: ``time_s, speed_kmh, soc_pct, ambient_degc, charging``, ``grade_frac`` and
    ``passengers`` when the profile has them, ``battery_current_a, battery_voltage_v`` (their
    means over each period).
    """
    import pandas as pd

    result = model.simulate(profile, params, soc_start=soc_start, **initial)
    stride = max(1, int(round(period_s / model.dt_s)))
    rows = np.arange(0, profile.n_steps, stride)
    t = profile.time_s[rows]
    rng = np.random.default_rng(seed)
    soc = 100.0 * result.trace("soc_frac")[rows] + rng.normal(0.0, soc_noise_pct, len(rows))
    if soc_step_pct > 0:
        soc = np.round(soc / soc_step_pct) * soc_step_pct
    frame = pd.DataFrame({
        "time_s": t,
        "speed_kmh": 3.6 * result.trace("speed_mps")[rows],
        "soc_pct": np.clip(soc, 0.0, 100.0),
        "ambient_degc": profile.channel("ambient_degc")[rows],
        "charging": (profile.channel("charger_connected")[rows] > 0.5).astype(int),
    })
    if "grade_frac" in profile.channels:
        frame["grade_frac"] = profile.channels["grade_frac"][rows]
    if "passenger_count" in profile.channels:
        frame["passengers"] = profile.channels["passenger_count"][rows]
    if "charger_rating_w" in profile.channels:
        rating = profile.channels["charger_rating_w"][rows]
        if np.isfinite(rating).any():
            frame["charger_kw"] = np.where(np.isfinite(rating), rating / 1e3, 0.0)
    # a BMS logs its sensors' mean over each period (what its coulomb count integrates): an
    # instant's value would alias the model's steps within a period
    counts = np.diff(np.append(rows, profile.n_steps))
    for name in ("battery_current_a", "battery_voltage_v"):
        frame[name] = np.add.reduceat(result.trace(name), rows) / counts
    if gap_s is not None:
        frame = frame[(frame.time_s < gap_s[0]) | (frame.time_s >= gap_s[1])]
    return frame.reset_index(drop=True)
