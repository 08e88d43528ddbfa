"""Turn a clean truth trace into a log that looks like a real bus's 1 Hz telematics.

The clean trace (from ``sim.simulate`` or any other truth source) is a DataFrame at 1 Hz or
finer with

* required: ``time_s`` [s from the start], ``clock_h`` [h, time of day],
  ``speed_mps``, ``soc_frac``;
* optional, logged when present: ``ambient_degc``, ``charging``, ``charger_kw``,
  ``door_open``, ``altitude_m``, ``passengers``; ``battery_current_a`` (> 0 discharging) and
  ``battery_voltage_v`` (the BMS log's; see below);
* ``attrs``: ``date`` (``YYYY-MM-DD``), the service date of the time stamps; ``timezone``
  (an IANA name), the local zone whose UTC offset the time stamps carry; ``capacity_ah`` (the
  pack's rated capacity, which the BMS counts charge against) and ``chemistry``.

A truth source decides what the log reveals by the optional columns it leaves in: e.g. a day
whose hidden effect is passenger mass keeps ``passengers``, and the other days drop it.

Degradations, each drawn per day from ``rng``:

* pack current and voltage (a BMS log): a Hall current sensor with a gain error of up to
  +-1 %, an offset of up to +-0.5 A and 0.5 A rms noise, logged in 0.1 A; the pack voltage
  with a gain error of up to +-0.3 % and 0.2 V rms noise, in 0.1 V;
* SoC, as the BMS estimates it (:func:`bms_soc_pct`): coulomb counting of that same sensor's
  current against the BMS's capacity (its error up to +-1.5 %), from a start read off the
  rested pack's OCV in the morning (0.3 % rms for NMC, 0.6 % for the flat LFP curve), pulled
  back to the truth where a BMS recalibrates (after 20 min at rest, and when a charge reaches
  the top of the pack), rounded to the 0.1 % step of common CAN SoC signals. The sensor's
  offset makes the estimate drift slowly, about 1 % over a day at 0.5 A;
* speed: the wheel-speed signal with a tyre-radius scale error (+-1.5 %) and 0.3 km/h rms
  noise while moving, exactly 0 at standstill, in 0.01 km/h;
* altitude: GPS vertical error, correlated (AR(1), 60 s, 3 m rms) plus 0.5 m white, in 0.1 m;
* ambient: a sensor bias of -0.5 to +1.5 K (road and body heat) in 0.5 K steps;
* passengers: automatic passenger counters with a per-day scale error (+-8 %) and a count
  error of about one passenger, rounded, never below zero;
* time: ``timestamp`` (ISO 8601 local date-time with its UTC offset,
  ``2025-01-15T07:00:00-08:00``) from the clock, or only ``time_s`` from 0 with
  ``relative_time=True`` (then nothing in the log tells the clock time).

Every draw is made whether or not the log keeps the current and voltage
(``current_voltage``): a SoC-only log is the same day's BMS log without those two columns.
A clean trace without ``battery_current_a`` (another source's) gets the SoC estimate of a
BMS whose counter errs by a capacity error, a start offset and a random-walk drift.

:func:`effect_load_kw` gives the bench's oracle column: the power a day's hidden effect adds,
on the log's rows, exactly (a perfect model of the hidden effect, for upper bounds).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

REQUIRED = ("time_s", "clock_h", "speed_mps", "soc_frac")
PASSED = ("ambient_degc", "charging", "charger_kw", "door_open", "altitude_m", "passengers")
BMS_COLUMNS = ("battery_current_a", "battery_voltage_v")
SOC_STEP_PCT = 0.1
START_ERROR_PCT = {"LFP": 0.6, "NMC": 0.3}  # OCV read-off at the morning rest [% rms]
REST_CURRENT_C = 0.02  # a pack at rest draws less than this [C] ...
REST_S = 1200.0  # ... for this long before the BMS reads its OCV again
FULL_SOC_FRAC = 0.975  # a charge that reaches this SoC resets the count to the top
RECAL_TAU_S = 600.0  # the estimate joins its new reference over this time (a filter)


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


def bms_soc_pct(soc_frac: np.ndarray, rng: np.random.Generator,
                sensed_current_a: np.ndarray | None = None, true_current_a: np.ndarray | None = None,
                capacity_ah: float = 0.0, chemistry: str | None = None,
                dt_s: float = 1.0) -> np.ndarray:
    """SoC as a BMS reports it [%], quantised to ``SOC_STEP_PCT``.

    With the sensed current: ``SoC_k = SoC_{k-1} - I_sensed dt / (3600 Q_bms) + c_k``, from
    ``SoC_0 = SoC_true,0 + e_0`` (the morning OCV read-off), ``Q_bms = Q (1 + e_Q)``, and
    ``c_k`` the recalibrations: after ``REST_S`` below ``REST_CURRENT_C`` (an OCV reading, with
    the start's error) or when a charge reaches ``FULL_SOC_FRAC`` (to 0.2 % rms), the
    estimate joins the reference with time constant ``RECAL_TAU_S``. Without it: a capacity
    error, a start offset, a random-walk drift (0.3 % rms over 10 h) and 0.03 % noise.
    """
    n = len(soc_frac)
    gain = 1.0 + rng.uniform(-0.015, 0.015)
    if sensed_current_a is None:
        offset = rng.normal(0.0, 0.3)
        drift = np.cumsum(rng.normal(0.0, 0.3 / np.sqrt(36000.0), n))
        noise = rng.normal(0.0, 0.03, n)
        soc = 100.0 * soc_frac
        est = soc[0] + offset + gain * (soc - soc[0]) + drift + noise
        return np.clip(np.round(est / SOC_STEP_PCT) * SOC_STEP_PCT, 0.0, 100.0)
    start_sd = START_ERROR_PCT.get(chemistry or "", 0.5)
    q_as = 3600.0 * capacity_ah * gain
    step = sensed_current_a * dt_s / q_as
    rest_limit_a = REST_CURRENT_C * capacity_ah
    est = np.empty(n)
    est[0] = soc_frac[0] + rng.normal(0.0, start_sd) / 100.0
    pending = 0.0  # what the estimate still has to move towards its last reference
    joined = 1.0 - np.exp(-dt_s / RECAL_TAU_S)
    rest_s = 0.0
    topped = False
    for k in range(1, n):
        est[k] = est[k - 1] - step[k - 1]
        rest_s = rest_s + dt_s if abs(true_current_a[k]) < rest_limit_a else 0.0
        charging_top = true_current_a[k] < 0.0 and soc_frac[k] >= FULL_SOC_FRAC
        if rest_s >= REST_S:  # an OCV reading at rest
            pending = soc_frac[k] + rng.normal(0.0, start_sd) / 100.0 - est[k]
            rest_s = -np.inf  # once per rest
        elif charging_top and not topped:
            pending = soc_frac[k] + rng.normal(0.0, 0.2) / 100.0 - est[k]
        topped = charging_top or (topped and true_current_a[k] < 0.0)
        move = pending * joined
        est[k] += move
        pending -= move
    return np.clip(np.round(100.0 * est / SOC_STEP_PCT) * SOC_STEP_PCT, 0.0, 100.0)


def time_stamps(date: str, clock_h: np.ndarray, timezone: str | None) -> np.ndarray:
    """ISO 8601 local date-times of the clock hours on ``date`` [h from its midnight], with
    the zone's UTC offset (``2025-01-15T07:00:00-08:00``), or without one where no zone is
    given. A date-time that the zone skips or repeats (a daylight-saving change) is an error:
    the bench's service dates avoid them."""
    local = pd.Timestamp(date) + pd.to_timedelta(np.round(clock_h * 3600.0), unit="s")
    if timezone is None:
        return pd.DatetimeIndex(local).strftime("%Y-%m-%d %H:%M:%S").to_numpy()
    zoned = pd.DatetimeIndex(local).tz_localize(timezone, ambiguous="raise",
                                                nonexistent="raise")
    text = pd.Series(zoned.strftime("%Y-%m-%dT%H:%M:%S%z"))
    return (text.str[:-2] + ":" + text.str[-2:]).to_numpy()


def degrade(clean: pd.DataFrame, rng: np.random.Generator, *, relative_time: bool = False,
            current_voltage: bool = False) -> pd.DataFrame:
    """A 1 Hz log in the canonical columns (see the module docstring) from a clean trace."""
    missing = [c for c in REQUIRED if c not in clean.columns]
    if missing:
        raise ValueError(f"clean trace lacks columns {missing}")
    if current_voltage and any(c not in clean.columns for c in BMS_COLUMNS):
        raise ValueError(f"a BMS log needs {BMS_COLUMNS} in the clean trace")
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
        log["timestamp"] = time_stamps(clean.attrs.get("date", "2025-01-01"), at("clock_h"),
                                       clean.attrs.get("timezone"))
    speed_kmh = 3.6 * at("speed_mps")
    moving = speed_kmh > 0.36
    noisy = speed_kmh * (1.0 + rng.uniform(-0.015, 0.015)) + rng.normal(0.0, 0.3, n)
    log["speed_kmh"] = np.round(np.where(moving, np.maximum(noisy, 0.0), 0.0), 2)
    if all(c in clean.columns for c in BMS_COLUMNS):
        true_a = at("battery_current_a")
        sensed_a = true_a * (1.0 + rng.uniform(-0.01, 0.01)) + rng.uniform(-0.5, 0.5) \
            + rng.normal(0.0, 0.5, n)
        volts = at("battery_voltage_v") * (1.0 + rng.uniform(-0.003, 0.003)) \
            + rng.normal(0.0, 0.2, n)
        log["soc_pct"] = np.round(bms_soc_pct(
            at("soc_frac"), rng, sensed_a, true_a, float(clean.attrs["capacity_ah"]),
            clean.attrs.get("chemistry")), 1)
        if current_voltage:
            log["battery_current_a"] = np.round(sensed_a, 1)
            log["battery_voltage_v"] = np.round(volts, 1)
    else:
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
    frame = pd.DataFrame(log)
    # the BMS's columns after the others, as before
    return frame[[c for c in frame.columns if c not in BMS_COLUMNS]
                 + [c for c in BMS_COLUMNS if c in frame.columns]]


def effect_load_kw(time_s: np.ndarray, added_j: np.ndarray) -> np.ndarray:
    """The oracle column ``logged_load_kw`` on the rows of :func:`degrade`'s log: the mean power
    over each second [kW] of ``added_j``, the energy a hidden effect has added to what the
    pack supplies by ``time_s`` (the day with the effect against the same day without it).
    Not degraded: it stands for a perfect model of the effect."""
    t = np.arange(np.ceil(time_s[0]), np.floor(time_s[-1]) + 1.0)
    energy = np.interp(t, time_s, added_j)
    power = np.diff(energy) if len(t) > 1 else np.zeros(0)
    return np.round(np.append(power, power[-1:] if len(power) else 0.0) / 1e3, 4)
