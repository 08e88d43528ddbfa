"""Where the model fails: the battery power it misses, window by window, and by condition.

The day is cut into windows of a few minutes. In each, the model starts from the measured SoC
(so an error made earlier does not change how it charges or derates later), and the power it
misses is::

    P_missing = P_measured - P_model   (> 0: the bus drew more than the model says)

Measured SoC is quantised (0.1 % steps are 200 Wh on a 200 kWh pack), so it is never
differentiated sample by sample: the least-squares slope of SoC over the window's samples,
with its standard error, becomes "SoC power" with the model's capacity and open-circuit
voltage, ``P = -Q 3600 OCV dSoC/dt``, and the model's SoC is treated the same way at the same
instants. When the log has the pack's current, the charge it counts is the measure instead,
through the same OCV: ``P = OCV I`` (charge going in at the coulombic efficiency), against the
model's own current. The logged voltage is left out: the model's terminal voltage (its OCV
curve and resistance) is a pack's only to a few per cent, and I (V_log - V_model) would show as
missing power in every window that draws current.

The missing power is then split by operating mode and by bins of speed, acceleration, SoC,
ambient temperature and time of day: a least-squares fit of each window's missing power to the
fractions of its time spent in each class (``decompose``) says how many kW the model misses
in each.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ebus_env.calibration.problem import coulombic_efficiency
from ebus_env.model.results import SimulationResult, battery_energy_j

MODES = ("accelerating", "cruising", "braking/regen", "idle", "CC charging", "CV charging")
SOC_BASIS = "SoC slope"
CURRENT_BASIS = "battery current"
MIN_SAMPLES = 4  # SoC samples a window needs for a slope
MODEL_ERROR_FRAC = 0.02
"""The calibrated model's own uncertainty on a window's battery power, as a share of it: a
pack's capacity and OCV curve and a drivetrain's efficiencies are known to a few per cent, so
a 300 kW charging window is uncertain by 6 kW however finely the log resolves SoC. Much more
would hide real effects in that uncertainty (the values tried: docs/diagnostics.md, "The
diagnosis's constants")."""


@dataclass
class Windows:
    """Consecutive windows of the profiles, in simulation steps."""

    profile_index: np.ndarray
    start_step: np.ndarray
    stop_step: np.ndarray
    start_h: np.ndarray  # from the start of the data (profiles one after another) [h]
    duration_h: np.ndarray

    def __len__(self) -> int:
        return len(self.start_step)

    def of(self, k: int) -> np.ndarray:
        """Windows of profile ``k``."""
        return np.flatnonzero(self.profile_index == k)

    def rows(self, w: int, record_every: int) -> slice:
        """Rows of window ``w`` in a trace recorded every ``record_every`` steps."""
        return slice(self.start_step[w] // record_every, -(-self.stop_step[w] // record_every))


def make_windows(profiles, window_s: float, record_every: int) -> Windows:
    """Windows of ``window_s`` (a multiple of ``record_every`` steps) covering each profile; a
    last piece shorter than half a window joins the window before it."""
    rows = {"profile_index": [], "start_step": [], "stop_step": [], "start_h": [],
            "duration_h": []}
    offset_h = 0.0
    for k, p in enumerate(profiles):
        per = max(record_every, int(round(window_s / p.dt_s / record_every)) * record_every)
        starts = list(range(0, p.n_steps, per))
        if len(starts) > 1 and p.n_steps - starts[-1] < per // 2:
            starts.pop()
        stops = starts[1:] + [p.n_steps]
        for a, b in zip(starts, stops, strict=True):
            rows["profile_index"].append(k)
            rows["start_step"].append(a)
            rows["stop_step"].append(b)
            rows["start_h"].append(offset_h + a * p.dt_s / 3600.0)
            rows["duration_h"].append((b - a) * p.dt_s / 3600.0)
        offset_h += p.duration_s / 3600.0
    return Windows(**{k: np.array(v) for k, v in rows.items()})


def measured_soc_at(profile, step: int) -> float:
    """Measured SoC at a step, interpolated between the log's samples."""
    rows = profile.sample_rows("soc_frac")
    return float(np.interp(step, rows, profile.measured["soc_frac"][rows]))


PACK_SIGNALS = ("battery_current_a", "battery_voltage_v")
"""The pack's logged signals (a BMS log); its current is the measure of :data:`CURRENT_BASIS`."""


def chemical_w(result, current_a: np.ndarray) -> np.ndarray:
    """Power out of the pack's chemical store [W] for a current at a run's recorded rows,
    through the model's OCV: OCV I, charge going in at the coulombic efficiency (the model's
    own count, as its SoC power ``-Q 3600 OCV dSoC/dt``)."""
    eta = coulombic_efficiency(result.model, result.params)[0]
    return result.trace("ocv_v") * current_a * np.where(current_a < 0.0, eta, 1.0)


def _segments(windows: Windows, k: int, n_steps: int):
    """(start, stop, anchored) pieces of profile ``k``: its windows and what lies between."""
    mine = windows.of(k)
    edges = sorted({0, n_steps, *windows.start_step[mine], *windows.stop_step[mine]})
    starts = set(windows.start_step[mine].tolist())
    return [(a, b, a in starts) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def anchored_run(model, profile, params: np.ndarray, windows: Windows, k: int,
                 record_every: int) -> SimulationResult:
    """Profile ``k`` recorded every ``record_every`` steps, the SoC set to the measured one
    at the start of every window."""
    inputs = model.input_array(profile)
    first = dict(zip(model.input_names, inputs[:, 0], strict=True))
    state0 = model.initial_state(params, first, measured_soc_at(profile, 0),
                                 **model.measured_states(profile))
    states = state0[None, :].copy()
    soc_i = model.state_names.index("soc_frac")
    n_trace = len(model.trace_names)
    trace = np.zeros((-(-profile.n_steps // record_every), n_trace), np.float32)
    acc = model.new_accumulators(1)
    for a, b, anchored in _segments(windows, k, profile.n_steps):
        if anchored:
            states[0, soc_i] = measured_soc_at(profile, a)
        buf = np.zeros((1, -(-(b - a) // record_every), n_trace), np.float32)
        model.run(params[None, :], states, inputs, step0=np.array([a]), n_steps=b - a,
                  record_every=record_every, record_out=buf, acc=acc)
        trace[a // record_every:a // record_every + buf.shape[1]] = buf[0]
    return SimulationResult(model, profile, params, state0, states[0], acc[0], trace,
                            record_every, 0.0)


def _slopes(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares slopes of the rows of y(t) and their standard errors (quantisation and
    noise count as scatter about the line)."""
    t = t - t.mean()
    sxx = float(np.sum(t * t))
    y = np.atleast_2d(y)
    if sxx <= 0:
        return np.zeros(len(y)), np.full(len(y), np.inf)
    slope = (y - y.mean(axis=1, keepdims=True)) @ t / sxx
    resid = y - y.mean(axis=1, keepdims=True) - slope[:, None] * t
    sigma2 = np.maximum(np.sum(resid**2, axis=1) / max(len(t) - 2, 1),
                        (0.001 / np.sqrt(12.0)) ** 2 / 100)
    return slope, np.sqrt(sigma2 / sxx)


def window_power(model, profiles, params: np.ndarray, windows: Windows, basis: str,
                 energy_j: np.ndarray, initial: dict | None = None) -> np.ndarray:
    """(N, n_windows) battery power of N parameter sets in each window, each window started
    from the measured SoC: SoC power ``-E dSoC/dt`` (``energy_j`` = E per window, J per unit
    SoC) or the mean power out of the chemical store (OCV I, :func:`chemical_w`), per
    ``basis``. One batched run of the compiled core."""
    params = np.atleast_2d(params)
    n = len(params)
    out = np.zeros((n, len(windows)))
    soc_i = model.state_names.index("soc_frac")
    for k, profile in enumerate(profiles):
        inputs = model.input_array(profile)
        first = dict(zip(model.input_names, inputs[:, 0], strict=True))
        soc0 = measured_soc_at(profile, 0)
        start = {**model.measured_states(profile), **(initial or {})}
        states = np.array([model.initial_state(row, first, soc0, **start) for row in params])
        rows = profile.sample_rows("soc_frac")
        mask = np.zeros(profile.n_steps, np.bool_)
        mask[rows] = True
        by_start = {int(windows.start_step[w]): w for w in windows.of(k)}
        for a, b, anchored in _segments(windows, k, profile.n_steps):
            if anchored:
                states[:, soc_i] = measured_soc_at(profile, a)
            w = by_start.get(a) if anchored else None
            step0 = np.full(n, a)
            if basis == SOC_BASIS:
                inside = rows[(rows >= a) & (rows < b)]
                buf = np.zeros((n, max(len(inside), 1), 1), np.float32)
                model.run(params, states, inputs, step0=step0, n_steps=b - a,
                          sample_mask=mask, record_out=buf)
                if w is not None and len(inside) >= MIN_SAMPLES:
                    slope, _ = _slopes(inside * profile.dt_s, buf[:, :len(inside), 0])
                    out[:, w] = -energy_j[w] * slope
            else:
                acc = model.new_accumulators(n)
                model.run(params, states, inputs, step0=step0, n_steps=b - a, acc=acc)
                if w is not None:
                    out[:, w] = battery_energy_j(model, acc)[1] / ((b - a) * profile.dt_s)
    return out


def correlation_time(x: np.ndarray, max_lag: int = 120) -> float:
    """Integrated autocorrelation time of a series, in samples: 1 + 2 sum rho_k over the lags
    before rho first falls below zero (so n samples hold about n / tau independent ones)."""
    x = x - np.mean(x)
    var = float(np.dot(x, x))
    if var <= 0 or len(x) < 3:
        return 1.0
    tau = 1.0
    for k in range(1, min(max_lag, len(x) - 1)):
        rho = float(np.dot(x[:-k], x[k:])) / var
        if rho <= 0:
            break
        tau += 2.0 * rho
    return tau


def measured_power(profiles, windows: Windows, basis: str, energy_j: np.ndarray,
                   anchored) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Measured battery power per window [W], the standard error of the missing power [W], and
    whether the window has enough samples. SoC: the slope's standard error. Current: OCV I of
    the logged current (:func:`chemical_w`), and the scatter of measured minus model power
    about its mean, with its correlation time."""
    power = np.zeros(len(windows))
    noise = np.full(len(windows), np.inf)
    ok = np.zeros(len(windows), bool)
    diffs = []
    if basis == CURRENT_BASIS:
        per_row = []
        for p, r in zip(profiles, anchored, strict=True):
            meas = chemical_w(r, p.measured["battery_current_a"][::r.record_every])
            per_row.append(meas)
            diffs.append(meas - chemical_w(r, r.trace("battery_current_a")))
        tau = correlation_time(np.concatenate(diffs))
    for w in range(len(windows)):
        p = profiles[windows.profile_index[w]]
        a, b = windows.start_step[w], windows.stop_step[w]
        if basis == SOC_BASIS:
            rows = p.sample_rows("soc_frac")
            rows = rows[(rows >= a) & (rows < b)]
            if len(rows) < MIN_SAMPLES:
                continue
            slope, se = _slopes(rows * p.dt_s, p.measured["soc_frac"][rows])
            power[w], noise[w] = -energy_j[w] * slope[0], energy_j[w] * se[0]
        else:
            k, rows = windows.profile_index[w], windows.rows(w, anchored[0].record_every)
            power[w] = float(np.mean(per_row[k][rows]))
            d = diffs[k][rows]
            noise[w] = float(np.std(d) * np.sqrt(tau / max(len(d), 1)))
        ok[w] = True
    return power, noise, ok


def uncertainty_w(noise_w: np.ndarray, model_power_w: np.ndarray) -> np.ndarray:
    """A window's uncertainty of the missing power [W]: the measurement's standard error and
    the model's own error, ``MODEL_ERROR_FRAC`` of its power, in quadrature."""
    return np.hypot(noise_w, MODEL_ERROR_FRAC * np.abs(model_power_w))


def soc_energy_j(results, windows: Windows) -> np.ndarray:
    """Energy per unit SoC, Q 3600 OCV [J], averaged over each window of recorded runs."""
    out = np.zeros(len(windows))
    for w in range(len(windows)):
        r = results[windows.profile_index[w]]
        rows = windows.rows(w, r.record_every)
        out[w] = float(np.mean(r.trace("capacity_ah")[rows] * 3600.0 * r.trace("ocv_v")[rows]))
    return out


def channel(result, name: str) -> np.ndarray:
    """An input channel of a run's profile at the run's recorded rows."""
    return result.profile.channel(name)[::result.record_every]


def operating_modes(result) -> np.ndarray:
    """Index into MODES of each recorded row of a run."""
    speed = result.trace("speed_mps")
    accel = result.trace("accel_mps2")
    wheel = result.trace("wheel_force_n")
    names = result.model.trace_names
    plugged = channel(result, "charger_connected") > 0.5
    taper = result.trace("cv_taper") if "cv_taper" in names else np.ones(len(speed))
    mode = np.full(len(speed), 1)
    mode[(accel > 0.1) & (wheel > 0)] = 0
    mode[(wheel < 0) & (speed > 0.1)] = 2
    mode[speed <= 0.1] = 3
    mode[plugged] = 4
    mode[plugged & (taper < 0.999)] = 5
    return mode


def fractions(labels: list[np.ndarray], windows: Windows, record_every: int,
              n_classes: int) -> np.ndarray:
    """(n_windows, n_classes) share of each window's recorded rows in each class."""
    out = np.zeros((len(windows), n_classes))
    for w in range(len(windows)):
        lab = labels[windows.profile_index[w]][windows.rows(w, record_every)]
        counts = np.bincount(lab[lab >= 0], minlength=n_classes)[:n_classes]
        out[w] = counts / max(len(lab), 1)
    return out


def decompose(missing_w: np.ndarray, noise_w: np.ndarray, share: np.ndarray,
              covariance: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Missing power in each class [W] and its standard error (or, with ``covariance``, the
    covariance matrix of the classes [W^2]): the weighted least-squares fit of
    missing_w = share @ p; classes never visited get NaN."""
    n = share.shape[1]
    seen = share.sum(axis=0) > 1e-6
    p = np.full(n, np.nan)
    se = np.full((n, n) if covariance else n, np.nan)
    if not seen.any() or len(missing_w) == 0:
        return p, se
    weight = 1.0 / np.maximum(noise_w, 1e-3 * (np.median(noise_w) + 1.0))
    a = share[:, seen] * weight[:, None]
    y = missing_w * weight
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    resid = y - a @ coef
    dof = max(len(y) - int(seen.sum()), 1)
    cov = np.linalg.pinv(a.T @ a) * float(resid @ resid) / dof
    p[seen] = coef
    if covariance:
        se[np.ix_(seen, seen)] = cov
    else:
        se[seen] = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return p, se


BINS = {
    "speed_kmh": (np.array([-np.inf, 0.5, 10, 30, 50, np.inf]),
                  ["standing", "0.5-10", "10-30", "30-50", "> 50"]),
    "accel_mps2": (np.array([-np.inf, -0.5, -0.1, 0.1, 0.5, np.inf]),
                   ["< -0.5", "-0.5 to -0.1", "-0.1 to 0.1", "0.1 to 0.5", "> 0.5"]),
    "soc_pct": (np.array([-np.inf, 20, 40, 60, 80, 90, np.inf]),
                ["< 20", "20-40", "40-60", "60-80", "80-90", "> 90"]),
    "ambient_degc": (np.array([-np.inf, -10, 0, 10, 20, 30, np.inf]),
                     ["< -10", "-10 to 0", "0-10", "10-20", "20-30", "> 30"]),
    "time_of_day_h": (np.array([0, 6, 9, 12, 15, 18, 21, 24.01]),
                      ["0-6", "6-9", "9-12", "12-15", "15-18", "18-21", "21-24"]),
}


def binned_signals(result) -> dict[str, np.ndarray]:
    """The signals the error is broken down by, per recorded row of a run."""
    return {
        "speed_kmh": 3.6 * result.trace("speed_mps"),
        "accel_mps2": result.trace("accel_mps2"),
        "soc_pct": 100.0 * result.trace("soc_frac"),
        "ambient_degc": channel(result, "ambient_degc"),
        "time_of_day_h": channel(result, "time_of_day_h"),
    }
