"""Stage 4, residual: the battery power the model misses, window by window.

The model, as given or calibrated (rung 0), is restarted from the measured SoC at each
window (:mod:`ebus_env.diagnostics.residual`); what the log measures less what the model
draws is the missing power, with its uncertainty. Windows with data problems
(:mod:`ebus_env.diagnostics.quality`) and the start-up are left out. On a log with the pack's
voltage, the resistance it shows is read too (:func:`~ebus_env.diagnostics.voltage.resistance_check`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ebus_env.calibration.problem import logs_current
from ebus_env.diagnostics import quality, residual
from ebus_env.diagnostics.log_days import service_days
from ebus_env.diagnostics.normal_day import Reference, mode_shares
from ebus_env.diagnostics.voltage import day_step, resistance_check
from ebus_env.errors import LogError

if TYPE_CHECKING:
    from ebus_env.diagnostics.diagnosis_run import DiagnosisRun

WINDOW_S = 300.0
"""Default window: SoC needs minutes to rise above its quantisation. A log of the pack's
current resolves power in seconds, but within a minute two models' drivetrains, regenerative
braking and packs differ by more than the sensors' noise, and minutes average that out: such a
log gets 5-min windows too, or shorter ones, down to :data:`MIN_CURRENT_WINDOW_S`, where that
leaves fewer than :data:`MIN_WINDOWS` (a short trip). The windows' effect on the verdicts is
measured in docs/validation.md ("On logs with the pack's current and voltage")."""
MIN_CURRENT_WINDOW_S = 60.0
MIN_WINDOWS = 50
START_UP_S = 120.0
"""Windows that start this soon after the start of a log are left out of the attribution:
the log does not say when the driver switched the heater or other systems on."""


@dataclass
class Residual:
    """The missing power per window of the model as given (or calibrated)."""

    model: object
    values: dict  # calibrated values (empty when not calibrated)
    params: np.ndarray
    every: int  # record every this many steps (a 1 s grid)
    basis: str
    window_s: float
    windows: residual.Windows
    anchored: list
    energy_j: np.ndarray
    base_power_w: np.ndarray
    missing_w: np.ndarray
    noise_w: np.ndarray  # the measurement's and the model's error, residual.uncertainty_w
    measurement_w: np.ndarray  # the measurement's standard error alone
    usable: np.ndarray
    issues: list[dict]
    excluded: int
    normal_w: tuple[np.ndarray, np.ndarray] | None = None  # what a normal day misses, +-

    def resolution_kwh(self) -> float:
        """The standard error of the energy the log measures over its usable windows,
        sqrt(sum (sigma_w t_w)^2) with each window's measurement error sigma_w: an effect
        that adds less than this is below what the log can show (about one SoC step of the
        pack on a 0.1 %-quantised SoC log)."""
        e_kwh = self.measurement_w[self.usable] * self.windows.duration_h[self.usable] / 1e3
        return float(np.sqrt(np.sum(e_kwh**2)))

    def beyond_normal(self) -> tuple[np.ndarray, np.ndarray]:
        """The missing power beyond what the reference day misses, and its uncertainty (the
        missing power itself without a reference)."""
        if self.normal_w is None:
            return self.missing_w, self.noise_w
        gap_w, gap_se_w = self.normal_w
        return self.missing_w - gap_w, np.hypot(self.noise_w, gap_se_w)


def residual_stage(model, profiles, values: dict, window_s: float | None,
                   loader_notes: Sequence[str] = (), reference: Reference | None = None
                   ) -> Residual:
    """Windows, the window-anchored runs and the missing power, with data problems and the
    start-up left out; with a ``reference``, what a normal day of the bus misses in each
    window too (:meth:`Residual.beyond_normal`)."""
    params = model.param_vector(values)
    dt_s = profiles[0].dt_s
    every = max(1, int(round(1.0 / dt_s)))  # diagnose on a 1 s grid
    basis = residual.CURRENT_BASIS if all(map(logs_current, profiles)) \
        else residual.SOC_BASIS
    if not window_s:
        total_s = sum(p.duration_s for p in profiles)
        window_s = WINDOW_S if basis == residual.SOC_BASIS else float(
            np.clip(round(total_s / MIN_WINDOWS, -1), MIN_CURRENT_WINDOW_S, WINDOW_S))
    windows = residual.make_windows(profiles, window_s, every)
    anchored = [residual.anchored_run(model, p, params, windows, k, every)
                for k, p in enumerate(profiles)]
    energy = residual.soc_energy_j(anchored, windows)
    base_power = residual.window_power(model, profiles, params, windows, basis, energy)[0]
    measured, noise, enough = residual.measured_power(profiles, windows, basis, energy,
                                                      anchored)
    missing = measured - base_power
    issues, usable = quality.data_issues(anchored, windows, model, params, measured, base_power,
                                         loader_notes)
    normal = reference.expected_w(mode_shares(anchored, windows)) if reference else None
    usable &= enough
    excluded = int(np.sum(enough & ~usable))
    usable &= ~(windows.start_step * dt_s < START_UP_S)
    if not usable.any():
        total_s = sum(p.duration_s for p in profiles)
        length = f"{total_s:.0f} s" if total_s < 600 else f"{total_s / 60:.0f} min"
        raise LogError(
            f"No window of the log can be diagnosed: {len(windows)} window(s) of "
            f"{window_s:.0f} s in {length}, none past the first {START_UP_S:.0f} s with "
            + (f"{residual.MIN_SAMPLES} SoC samples" if basis == residual.SOC_BASIS
               else "battery current") + " and free of data problems",
            path=", ".join(p.name for p in profiles),
            fix=(f"a shorter window (--window-s; the default is 300 s) for a log of {length}"
                 if window_s > max(total_s - START_UP_S, 0.0) / 4 and total_s >= 3600.0 else
                 "give a longer log (an hour or more: the diagnosis compares many windows)"))
    return Residual(model, dict(values), params, every, basis, window_s, windows, anchored,
                    energy, base_power, missing, residual.uncertainty_w(noise, base_power),
                    noise, usable, issues, excluded, normal)


def run(ctx: DiagnosisRun) -> None:
    """Fill ``ctx.res`` (the missing power of the model at rung 0's values, or the values it
    holds uncalibrated) and ``ctx.check`` (the resistance the logged voltage shows, or None;
    on several days, with its rise from a day on, and ``ctx.days``)."""
    values = ctx.first_rung.values if ctx.first_rung else dict(ctx.known)
    ctx.res = res = residual_stage(ctx.model, ctx.profiles, values, ctx.window_s,
                                   ctx.loader_notes, ctx.normal)
    ctx.check = resistance_check(ctx.profiles, res.anchored, res.windows, res.usable)
    if ctx.check is not None and ctx.domain == "soc":
        day_of, days = service_days(ctx.profiles)
        if len(days) > 1:
            ctx.days = days
            ctx.check.step = day_step(ctx.check, res.windows, ctx.profiles, day_of)
