"""The power a BMS log measures and the power the model draws, second by second.

A log of the pack's current and voltage measures the pack's terminal power every second,
``P_log = V I`` (> 0 discharging): the traction motor, the DC loads and what a charger puts in,
with no battery model in between. The model, driven along the log's speed with its SoC set to
the logged one every :data:`ANCHOR_S` (so that its charge acceptance and derating follow the
pack's, not an error it carried), gives its own terminal power ``battery_power_w``; their
difference is the power the model misses::

    P_missing(t) = P_log(t) - P_model(t)      (> 0: the bus drew more than the model says)

The current sensor's gain and offset scale the measured power and add a constant to it; they
are fitted beside the bus's parameters (:data:`~ebus_env.diagnostics.power_fit.SENSOR`).

Each logged second is compared with the model's mean over the steps it stands for, found
for the bus's logger (:func:`logger_lag`): loggers stamp the second before, the second after,
or in between.

Seconds are noisy where the model's driver is a second early or late, so the diagnosis
compares :data:`BIN_S` bins. Bins on a charger are left out of the fit of the bus, where the
pack's charge acceptance decides the power, except those in which the model's charger runs
at its rating the whole bin: there the loads show as they do standing (a load that runs while
charging). Each bin belongs to an operating mode, from per-second masks, and to a block of
:data:`BLOCK_S`, the unit the held-out tests leave out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ebus_env.diagnostics.residual import measured_soc_at

ANCHOR_S = 300.0
BIN_S = 10.0
BLOCK_S = 600.0
START_UP_S = 120.0
"""The first minutes of a day are left out: the log does not say when the driver switched the
heater and other systems on."""
HIGH_SOC = 0.9
MODES = ("standing", "accelerating", "cruising", "braking", "charging", "braking at high SoC")
"""Operating modes of a second, from the model's run along the log: standing (not on a
charger), accelerating (> 0.1 m/s^2 with traction), braking (a braking force, moving), cruising
(the rest of driving), on a charger, and braking above :data:`HIGH_SOC` (a subset of braking,
where a pack accepts less)."""
TRACE = ("battery_power_w", "speed_mps", "accel_mps2", "wheel_force_n", "soc_frac",
         "charger_power_w", "charge_power_max_w", "dc_load_w")


def logs_power(profile) -> bool:
    """Whether a profile carries the pack's current and voltage throughout (a BMS log)."""
    return all(name in profile.measured and np.isfinite(profile.measured[name]).all()
               for name in ("battery_current_a", "battery_voltage_v"))


def _steps(model, profile, rows: np.ndarray, sel: np.ndarray) -> np.ndarray:
    """``(N, n_steps + 2 every, len(sel))``: the model's every step along ``profile`` for each
    of ``rows``, with a second of zeros before and after (``every`` steps a second), the SoC
    set to the logged one every :data:`ANCHOR_S`. One batched call of the compiled core per
    anchor."""
    n = len(rows)
    every = max(1, int(round(1.0 / profile.dt_s)))
    soc_i = model.state_names.index("soc_frac")
    inputs = model.input_array(profile)
    first = dict(zip(model.input_names, inputs[:, 0], strict=True))
    measured = model.measured_states(profile)
    states = np.array([model.initial_state(r, first, measured_soc_at(profile, 0), **measured)
                       for r in rows])
    out = np.zeros((n, profile.n_steps + 2 * every, len(sel)), np.float32)
    per = max(every, int(round(ANCHOR_S / profile.dt_s / every)) * every)
    for a in range(0, profile.n_steps, per):
        b = min(a + per, profile.n_steps)
        states[:, soc_i] = measured_soc_at(profile, a)
        buf = np.zeros((n, b - a, len(sel)), np.float32)
        model.run(rows, states, inputs, step0=np.full(n, a), n_steps=b - a,
                  record_every=1, record_sel=sel, record_out=buf)
        out[:, every + a:every + b] = buf
    return out


def _logged_seconds(steps: np.ndarray, every: int, lag: int) -> np.ndarray:
    """Each logged second's mean of the model's steps (``steps``: :func:`_steps`'s, padded by
    ``every`` zero steps each side; ``|lag| <= every``): the second at row ``r`` stands for
    steps ``r every + lag`` to ``(r + 1) every + lag``, those within the run."""
    n_steps = steps.shape[-2] - 2 * every
    n_seconds = -(-n_steps // every)
    start = every + lag
    window = steps[..., start:start + n_seconds * every, :]
    if window.shape[-2] < n_seconds * every:  # the last second runs past the padding
        window = np.concatenate([window, np.zeros_like(
            steps[..., :n_seconds * every - window.shape[-2], :])], axis=-2)
    sums = window.reshape(*steps.shape[:-2], n_seconds, every, steps.shape[-1]).sum(
        axis=-2, dtype=float)
    index = np.arange(n_seconds * every) + lag
    inside = ((index >= 0) & (index < n_steps)).reshape(n_seconds, every).sum(axis=1)
    return sums / np.maximum(inside, 1)[:, None]


def anchored_runs(model, profiles, rows: np.ndarray, signals=("battery_power_w",),
                  lag: int = 0) -> list[np.ndarray]:
    """For each profile, ``(N, n_seconds, len(signals))``: N parameter rows driven along it, the
    SoC set to the logged one every :data:`ANCHOR_S`, each logged second the mean of the
    model's steps in it (``lag``: the logger's timing in model steps, :func:`logger_lag`;
    0: the second from its time stamp on).

    Means, not the instant at each second's start: a BMS logs its sensors' mean over each
    period (what its coulomb count integrates), and the power moves within a second as the
    driver's force follows the speed (about 2 kW on average over a city day of the 12 m bus
    at 0.1 s steps, as much as a small load; an instant would show it as one while
    accelerating and braking)."""
    rows = np.atleast_2d(rows)
    sel = np.array([model.trace_names.index(s) for s in signals])
    out = []
    for p in profiles:
        every = max(1, int(round(1.0 / p.dt_s)))
        out.append(_logged_seconds(_steps(model, p, rows, sel), every, lag))
    return out


LAG_S = 1.0
"""How far the period a logged current stands for may lie from its time stamp, either way
[s]. Loggers differ: one stamps the mean over the second that follows, another over the
second before (a backward-facing simulation's step, a BMS that sends when its count closes),
another an instant; CAN signals from different controllers reach the logger up to a few
hundred milliseconds apart. A period one second off shifts the power of every acceleration,
a few kW for a second: a spurious load while accelerating and braking."""


def logger_lag(model, profiles, params: np.ndarray) -> int:
    """The bus's logger's timing [model steps]: the shift within +-:data:`LAG_S` of the
    model's 1 s means that follows the logged power best, the model at ``params`` (least
    squares after each day's gain and offset, summed over the days). Only seconds in traction
    count, moving off a charger with both powers above zero: that is where the timing shows
    (every acceleration), and where the effects a log is diagnosed for do not move it (a
    regen limit, which would pull a timing fitted on braking its way; a load, which the
    offset takes)."""
    sel = np.array([model.trace_names.index(s) for s in ("battery_power_w", "speed_mps")])
    reach = int(round(LAG_S / profiles[0].dt_s))
    loss = np.zeros(2 * reach + 1)
    for p, logged in zip(profiles, log_power(profiles), strict=True):
        every = max(1, int(round(1.0 / p.dt_s)))
        steps = _steps(model, p, params[None, :], sel)[0]
        plugged = p.channel("charger_connected")[::every] > 0.5
        for j, lag in enumerate(range(-reach, reach + 1)):
            seconds = _logged_seconds(steps, every, lag)
            n = min(len(seconds), len(logged))
            model_w, logged_w = seconds[:n, 0], logged[:n]
            ok = ((seconds[:n, 1] > 0.1) & ~plugged[:n] & np.isfinite(logged_w)
                  & (model_w > 0) & (logged_w > 0))
            if ok.sum() < 60:  # a day parked: nothing to time
                continue
            x = np.column_stack([model_w[ok], np.ones(ok.sum())])
            _, res, *_ = np.linalg.lstsq(x, logged_w[ok], rcond=None)
            loss[j] += float(res[0]) if len(res) else 0.0
    return int(np.argmin(loss)) - reach if loss.any() else 0


@dataclass
class Bins:
    """The :data:`BIN_S` bins of a diagnosis's logs, one after the other."""

    profile: np.ndarray  # the profile each bin lies in
    first: np.ndarray  # its first second (row of the 1 s grid) in that profile
    day: np.ndarray  # the day it belongs to
    block: np.ndarray  # its block of BLOCK_S, numbered over all the logs
    hour: np.ndarray  # time of day at its middle [h]
    fit: np.ndarray  # used in the fits: past the start-up, off a charger or at its rating
    mode_share: np.ndarray  # (n_bins, len(MODES)) share of its seconds in each mode
    seconds: int  # a bin's length [s] (rows per bin): BIN_S, a SoC-only log's window
    lag: int = 0  # the logger's timing in model steps (:func:`logger_lag`)

    def __len__(self) -> int:
        return len(self.first)

    @property
    def by_window(self) -> bool:
        """Whether the bins are a SoC-only log's windows (:mod:`.soc_power`), longer than
        :data:`BIN_S`: each mixes the modes, and its power is a count without steps."""
        return self.seconds > BIN_S

    def means(self, per_second: list[np.ndarray]) -> np.ndarray:
        """Means over each bin of per-second series, one per profile (each ``(..., n)``):
        ``(..., n_bins)``."""
        k = self.seconds
        parts = []
        for i, x in enumerate(per_second):
            mine = self.first[self.profile == i]
            n = len(mine) * k
            x = np.asarray(x)[..., :n]
            parts.append(x.reshape(*x.shape[:-1], len(mine), k).mean(axis=-1))
        return np.concatenate(parts, axis=-1)


def mode_masks(run: np.ndarray, plugged: np.ndarray, logged_speed_mps: np.ndarray
               ) -> np.ndarray:
    """``(n_seconds, len(MODES))`` of a run along a log (``run`` recorded with
    :data:`TRACE`): which mode each second is in. A second is standing only where neither
    the log nor the model moves (the model's driver may start or stop a second late)."""
    speed, accel, wheel, soc = (run[:, TRACE.index(s)] for s in
                                ("speed_mps", "accel_mps2", "wheel_force_n", "soc_frac"))
    moving = (speed > 0.1) | (logged_speed_mps > 0.1)
    standing = ~moving & ~plugged
    accelerating = moving & (accel > 0.1) & (wheel > 0.0) & ~plugged
    braking = moving & (wheel < 0.0) & ~plugged
    cruising = moving & ~accelerating & ~braking & ~plugged
    return np.column_stack([standing, accelerating, cruising, braking, plugged,
                            braking & (soc > HIGH_SOC)]).astype(float)


STEADY_W = 3e3  # the spread of the logged power within a bin at a charger's rating, at most
RATED_LOADS_W = 30e3
DELIVERED_RANGE = (0.85, 1.02)
"""The share of its stated rating a charger delivers, as the power path searches it: from a
rating stated on the grid side at 85 % (a charger's 93-96 % efficiency, its cable and a
derating, docs/physics.md §6.1) to a DC rating 2 % short. On a charger, the log shows the
charger at its rating where the pack takes in no more than the least share less
``RATED_LOADS_W`` (the bus's loads at most): the pack is not the limit there."""


def make_bins(profiles, runs: list[np.ndarray], day_of: list[int], lag: int = 0,
              delivered_frac: float = 1.0, bin_s: float = BIN_S) -> Bins:
    """Bins of ``bin_s`` of every profile from the model's run along it (``runs``: one
    ``(n_seconds, len(TRACE))`` per profile, made with the logger's ``lag`` and a charger
    delivering ``delivered_frac`` of its rating): their modes, and whether each enters the
    fits. A bin on a charger enters only where both the model's charger and the logged power
    show the charger at its rating the whole bin (the loads then show as they do standing);
    a SoC-only log's window on a charger never does."""
    k = int(bin_s)
    cols = {name: [] for name in ("profile", "first", "day", "block", "hour", "fit")}
    shares = []
    block0 = 0
    for i, (p, run) in enumerate(zip(profiles, runs, strict=True)):
        n_bins = len(run) // k
        if n_bins == 0:
            continue
        every = max(1, int(round(1.0 / p.dt_s)))
        plugged = p.channel("charger_connected")[::every][:len(run)] > 0.5
        masks = mode_masks(run, plugged, p.channel("speed_ref_mps")[::every][:len(run)])
        first = np.arange(n_bins) * k
        share = masks[:n_bins * k].reshape(n_bins, k, len(MODES)).mean(axis=1)
        # on a charger, the model's charger at its rating all the bin: loads show as standing
        dc = run[:, TRACE.index("charger_power_w")]
        rated = np.nan_to_num(p.channel("charger_rating_w")[::every][:len(run)])
        logged = log_power([p])[0][:len(run)]
        at_rating = plugged & (rated > 0) & (dc >= 0.995 * delivered_frac * rated) & (
            logged <= -DELIVERED_RANGE[0] * rated + RATED_LOADS_W)
        on = plugged[:n_bins * k].reshape(n_bins, k)
        full = at_rating[:n_bins * k].reshape(n_bins, k).all(axis=1)
        # a charger at its rating gives a steady power; a pack in its CV phase takes less
        # and less
        full &= np.ptp(logged[:n_bins * k].reshape(n_bins, k), axis=1) < STEADY_W
        # a SoC-only log's window on a charger counts the BMS's capacity error on the
        # charger's whole power, and its recalibration at the top: left out
        fit = (~on.any(axis=1) | (full & (k <= BIN_S))) & (first >= START_UP_S)
        cols["profile"].append(np.full(n_bins, i))
        cols["first"].append(first)
        cols["day"].append(np.full(n_bins, day_of[i]))
        blocks = (first * 1.0 // BLOCK_S).astype(int)
        cols["block"].append(block0 + blocks)
        block0 += int(blocks.max()) + 1
        cols["hour"].append((p.start_time_h + (first + k / 2) / 3600.0) % 24.0)
        cols["fit"].append(fit)
        shares.append(share)
    return Bins(*(np.concatenate(cols[c]) for c in cols), np.concatenate(shares), k, lag)


def log_power(profiles) -> list[np.ndarray]:
    """The logged terminal power ``V I`` [W] of each profile, every second."""
    out = []
    for p in profiles:
        every = max(1, int(round(1.0 / p.dt_s)))
        out.append((p.measured["battery_current_a"] * p.measured["battery_voltage_v"])[::every])
    return out


def log_voltage(profiles) -> list[np.ndarray]:
    """The logged pack voltage [V] of each profile, every second."""
    return [p.measured["battery_voltage_v"][::max(1, int(round(1.0 / p.dt_s)))] for p in profiles]
