"""Turn a clean truth trace into a log that looks like a real bus's 1 Hz telematics.

The clean trace (from ``sim.simulate`` or any other truth source) is a DataFrame at 1 Hz or
finer with

* required: ``time_s`` [s from the start], ``clock_h`` [h, time of day],
  ``speed_mps``, ``soc_frac``;
* optional, logged when present: ``ambient_degc``, ``charging``, ``charger_kw``,
  ``door_open``, ``altitude_m``, ``passengers``; ``battery_current_a`` (> 0 discharging) and
  ``battery_voltage_v`` only with ``current_voltage=True``;
* ``attrs["date"]`` (``YYYY-MM-DD``), the service date for the time stamps.

A truth source decides what the log reveals by the optional columns it leaves in: e.g. a day
whose hidden effect is passenger mass keeps ``passengers``, and the other days drop it.

Degradations, each drawn per day from ``rng``:

* SoC: a BMS coulomb counter with a capacity (gain) error of up to +-1.5 %, a start offset
  (0.3 % rms), a current-sensor drift (random walk, about 0.3 % rms over 10 h) and 0.03 %
  rms noise, rounded to the 0.1 % step of common CAN SoC signals;
* speed: the wheel-speed signal with a tyre-radius scale error (+-1.5 %) and 0.3 km/h rms
  noise while moving, exactly 0 at standstill, in 0.01 km/h;
* altitude: GPS vertical error, correlated (AR(1), 60 s, 3 m rms) plus 0.5 m white, in 0.1 m;
* ambient: a sensor bias of -0.5 to +1.5 K (road and body heat) in 0.5 K steps;
* passengers: automatic passenger counters with a per-day scale error (+-8 %) and a count
  error of about one passenger, rounded, never below zero;
* time: ``timestamp`` (``YYYY-MM-DD HH:MM:SS``) from the clock, or only ``time_s`` from 0
  with ``relative_time=True`` (then nothing in the log tells the clock time);
* pack current and voltage (``current_voltage=True``): a Hall current sensor with a gain
  error of up to +-1 %, an offset of up to +-0.5 A and 0.5 A rms noise, in 0.1 A; the pack
  voltage with a gain error of up to +-0.3 % and 0.2 V rms noise, in 0.1 V. Drawn after every
  other degradation, so the rest of a log is the same with and without them.

:func:`effect_load_kw` gives the bench's oracle column: the power a day's hidden effect adds,
on the log's rows, exactly (a perfect model of the hidden effect, for upper bounds).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

REQUIRED = ("time_s", "clock_h", "speed_mps", "soc_frac")
PASSED = ("ambient_degc", "charging", "charger_kw", "door_open", "altitude_m", "passengers")
SOC_STEP_PCT = 0.1


def _ar1(rng: np.random.Generator, n: int, tau_s: float, sigma: float) -> np.ndarray:
    """Stationary AR(1) noise at 1 Hz with correlation time ``tau_s`` and spread ``sigma``."""
    rho = np.exp(-1.0 / tau_s)
    shocks = rng.normal(0.0, sigma * np.sqrt(1.0 - rho * rho), n)
    shocks[0] = rng.normal(0.0, sigma)
    out = np.empty(n)
    acc = 0.0
    for i in range(n):
        acc = rho * acc + shocks[i]
        out[i] = acc
    return out


def bms_soc_pct(soc_frac: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """SoC as a BMS reports it [%], quantised to ``SOC_STEP_PCT``."""
    n = len(soc_frac)
    gain = 1.0 + rng.uniform(-0.015, 0.015)
    offset = rng.normal(0.0, 0.3)
    drift = np.cumsum(rng.normal(0.0, 0.3 / np.sqrt(36000.0), n))
    noise = rng.normal(0.0, 0.03, n)
    soc = 100.0 * soc_frac
    est = soc[0] + offset + gain * (soc - soc[0]) + drift + noise
    return np.clip(np.round(est / SOC_STEP_PCT) * SOC_STEP_PCT, 0.0, 100.0)


def degrade(clean: pd.DataFrame, rng: np.random.Generator, *, relative_time: bool = False,
            current_voltage: bool = False) -> pd.DataFrame:
    """A 1 Hz log in the canonical columns (see the module docstring) from a clean trace."""
    missing = [c for c in REQUIRED if c not in clean.columns]
    if missing:
        raise ValueError(f"clean trace lacks columns {missing}")
    t_src = clean["time_s"].to_numpy(float)
    t = np.arange(np.ceil(t_src[0]), np.floor(t_src[-1]) + 1.0)

    def at(col: str) -> np.ndarray:
        return np.interp(t, t_src, clean[col].to_numpy(float))

    def held(col: str) -> np.ndarray:  # flags and counts: the value in force at t
        idx = np.searchsorted(t_src, t, side="right") - 1
        return clean[col].to_numpy()[idx]

    n = len(t)
    log: dict[str, np.ndarray] = {}
    if relative_time:
        log["time_s"] = t - t[0]
    else:
        start = pd.Timestamp(clean.attrs.get("date", "2025-01-01"))
        stamps = start + pd.to_timedelta(np.round(at("clock_h") * 3600.0), unit="s")
        log["timestamp"] = stamps.strftime("%Y-%m-%d %H:%M:%S").to_numpy()
    speed_kmh = 3.6 * at("speed_mps")
    moving = speed_kmh > 0.36
    noisy = speed_kmh * (1.0 + rng.uniform(-0.015, 0.015)) + rng.normal(0.0, 0.3, n)
    log["speed_kmh"] = np.round(np.where(moving, np.maximum(noisy, 0.0), 0.0), 2)
    log["soc_pct"] = np.round(bms_soc_pct(at("soc_frac"), rng), 1)
    for col in PASSED:
        if col not in clean.columns:
            continue
        if col == "ambient_degc":
            log[col] = np.round((at(col) + rng.uniform(-0.5, 1.5)) * 2.0) / 2.0
        elif col == "altitude_m":
            log[col] = np.round(at(col) + _ar1(rng, n, 60.0, 3.0) + rng.normal(0.0, 0.5, n), 1)
        elif col == "passengers":
            true = held(col).astype(float)
            counted = true * (1.0 + rng.uniform(-0.08, 0.08)) + rng.normal(0.0, 1.0, n)
            # the counter's error changes only when people board or alight
            change = np.concatenate(([True], np.diff(true) != 0))
            counted = counted[np.maximum.accumulate(np.where(change, np.arange(n), 0))]
            log[col] = np.maximum(np.round(counted), 0.0).astype(int)
        elif col in ("charging", "door_open"):
            log[col] = held(col).astype(int)
        else:
            log[col] = np.round(held(col).astype(float), 1)
    if current_voltage:
        current = at("battery_current_a") * (1.0 + rng.uniform(-0.01, 0.01)) \
            + rng.uniform(-0.5, 0.5) + rng.normal(0.0, 0.5, n)
        voltage = at("battery_voltage_v") * (1.0 + rng.uniform(-0.003, 0.003)) \
            + rng.normal(0.0, 0.2, n)
        log["battery_current_a"] = np.round(current, 1)
        log["battery_voltage_v"] = np.round(voltage, 1)
    return pd.DataFrame(log)


def effect_load_kw(time_s: np.ndarray, added_j: np.ndarray) -> np.ndarray:
    """The oracle column ``logged_load_kw`` on the rows of :func:`degrade`'s log: the mean power
    over each second [kW] of ``added_j``, the energy a hidden effect has added to what the
    pack supplies by ``time_s`` (the day with the effect against the same day without it).
    Not degraded: it stands for a perfect model of the effect."""
    t = np.arange(np.ceil(time_s[0]), np.floor(time_s[-1]) + 1.0)
    energy = np.interp(t, time_s, added_j)
    power = np.diff(energy) if len(t) > 1 else np.zeros(0)
    return np.round(np.append(power, power[-1:] if len(power) else 0.0) / 1e3, 4)
