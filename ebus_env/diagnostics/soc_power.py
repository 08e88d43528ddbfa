"""A SoC-only log read as a coarse power log: the charge its SoC counts in each window.

A BMS's SoC counts the pack's charge, so the logged SoC's change over a window gives the
charge the pack delivered there. The model, set to the logged SoC at each window's start
(every :data:`~ebus_env.diagnostics.power.ANCHOR_S`, as for a BMS log), counts its own; the
two counts' difference at the window's end is the power the model misses there, on
average over the window::

    P_missing,w = (SoC_model(t_end) - SoC_log(t_end)) 3600 Q V_w / (t_end - t_start)

with ``Q`` the model's pack capacity [Ah] and ``V_w`` its mean terminal voltage over the
window (the charge times the voltage the pack delivers it at). The log's power is then the
model's, second by second, plus that window's missing power. Read in bins of one window, a
SoC-only log goes through the power path (:mod:`~ebus_env.diagnostics.power_path`) as a BMS
log does: the bus's parameters fitted across its days, each candidate's held-out test, and
on several days each candidate from each day on (a fault's start day).

What differs from a BMS log: the BMS's capacity error scales its count, as a current
sensor's gain does, and its estimate's slow drift adds a nearly constant current, as the
sensor's offset does; both are fitted per day
(:data:`~ebus_env.diagnostics.power_fit.SENSOR`). The SoC's steps (0.1 % of a 12 m bus's
pack is about 0.2 kWh, 2.4 kW over a 5-min window) and the BMS's recalibrations are noise,
weighed alike in every mode (:func:`~ebus_env.diagnostics.power_path.class_weights`).
A window is a mix of operating modes, so a load by mode is told apart by the modes' shares
only, and the steps of a load switching at stops do not show. The log has no voltage: the
voltage the power path uses is the model's, so the pack's resistance is not read from it.
"""

from __future__ import annotations

import numpy as np

from ebus_env.diagnostics.power import ANCHOR_S, _logged_seconds, _steps
from ebus_env.diagnostics.residual import measured_soc_at

WINDOW_S = ANCHOR_S
"""A SoC-only log's bin [s]: the window between two of the model's anchors to the logged SoC."""
SIGNALS = ("battery_power_w", "soc_frac", "battery_voltage_v", "capacity_ah")


def logs_soc(profile) -> bool:
    """Whether a profile's log carries the SoC (two samples at least)."""
    return len(profile.sample_rows("soc_frac")) >= 2


def window_missing_w(model, profile, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The model at ``params`` along ``profile``, anchored to the logged SoC every window:
    its power and voltage in each second's mean, ``(n_seconds, 2)``, and each second's
    window's missing power [W] (0 in a last window shorter than :data:`WINDOW_S`, which no
    bin reads)."""
    sel = np.array([model.trace_names.index(s) for s in SIGNALS])
    every = max(1, int(round(1.0 / profile.dt_s)))
    steps = _steps(model, profile, params[None, :], sel)[0]
    seconds = _logged_seconds(steps, every, 0)
    run = steps[every:every + profile.n_steps]
    per = int(round(WINDOW_S / profile.dt_s))  # model steps a window (its anchors')
    missing = np.zeros(len(seconds))
    for a in range(0, profile.n_steps - per + 1, per):
        b = a + per
        counted = run[b - 1, 1] - measured_soc_at(profile, min(b, profile.n_steps - 1))
        volts, amp_hours = run[a:b, 2].mean(), run[a:b, 3].mean()
        missing[a // every:b // every] = counted * 3600.0 * amp_hours * volts / (per * profile.dt_s)
    return seconds[:, [0, 2]], missing


def as_power_logs(model, profiles, params: np.ndarray) -> list:
    """Copies of SoC-only ``profiles`` that carry a pack current and voltage: the model's at
    ``params``, each second's power raised by its window's missing power
    (:func:`window_missing_w`). Read in bins of :data:`WINDOW_S`, their logged power is the
    SoC's count; within a window it follows the model at ``params``, which no bin sees."""
    out = []
    for p in profiles:
        every = max(1, int(round(1.0 / p.dt_s)))
        model_wv, missing_w = window_missing_w(model, p, params)
        power_w = np.repeat(model_wv[:, 0] + missing_w, every)[:p.n_steps]
        volts = np.repeat(np.maximum(model_wv[:, 1], 1.0), every)[:p.n_steps]
        out.append(p.with_measured(battery_current_a=power_w / volts, battery_voltage_v=volts))
    return out
