"""The bus as a BMS log shows it: its pack from the log, then the parameters that differ from
bus to bus fitted to the logged power.

**The pack.** A BMS counts the charge through the pack; over a day whose SoC moves by
:data:`MIN_SOC_SPAN` or more, the charge counted against the SoC's change is the pack's
usable capacity::

    q(t) = - int_0^t I dt / 3600 = Q (SoC(t) - SoC(0)) + c t      (least squares for Q, c)

where ``c t`` takes up a current sensor's offset, which a count accumulates. Its resistance
is the model's times the logged voltage's drop under load over the model's
(:func:`pack_resistance`).

It sets the model's cell capacity before anything else: the pack's capacity decides how the
SoC moves, so how the charger's CC/CV taper and the regen at high SoC go, and those decide
power the model must not mistake for a missing effect.

**The bus.** The bus-to-bus parameters (:data:`BUS_PARAMETERS`: mass, rolling resistance,
drag, auxiliary base load, drivetrain efficiency, brake blending) are fitted to the bins'
logged power by Gauss-Newton steps within their search box: each step runs the model along
the log with every parameter moved a little (one batched run), and solves the bounded
weighted least squares of the missing power on those changes. The same signatures, at the
fitted values, are the nuisance columns of the held-out tests
(:mod:`ebus_env.diagnostics.heldout`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ebus_env.calibration.problem import CHARGER_SHARE
from ebus_env.diagnostics.heldout import Nuisance, fit_all
from ebus_env.diagnostics.ladder import NUISANCE, RESOLVED_BY_CURRENT
from ebus_env.diagnostics.power import DELIVERED_RANGE, MODES, TRACE, Bins, anchored_runs
from ebus_env.diagnostics.residual import anchored_run, make_windows
from ebus_env.diagnostics.voltage import resistance_check

PACK = ("rint_battery.cell_capacity_ah", "rint_battery.cell_resistance_mohm")
BUS_PARAMETERS = {**{k: v for k, v in NUISANCE.items() if k not in PACK},
                  **RESOLVED_BY_CURRENT, "aero_drag.drag_coef": (0.7, 1.3),
                  "regen_cutoff.cutoff_speed_mps": (0.0, 3.0),
                  "efficiency_map.regen_power_kw": (0.5, 1.25), CHARGER_SHARE: DELIVERED_RANGE}
"""The parameters fitted to a BMS log's power, with their search range as factors of the
configured value (the diagnosis's bus-to-bus ranges, and four a log of the power resolves
and a SoC log does not: the drag, the motor's regenerative power limit, the speed below
which it stops regenerating, one of the paper's uncertain parameters: a motor whose regen
fades out between 1.5 and 4 m/s brakes as one that stops at about 2.7, and the share of its
stated rating a charger delivers: a log's charger rating may be the grid side's, which
delivers the charger's efficiency of it, and a charger at its rating shows the share to a
per cent, where a load while charging would otherwise take it)."""
SENSOR = {"current sensor gain": (-0.03, 0.03), "current sensor offset [A]": (-2.0, 2.0),
          "drivetrain loss while moving [kW]": (-2.0, 2.0)}
"""Terms of the logged power the bus's parameters do not give, each linear: the current
sensor's gain and offset (a Hall sensor's, within a few per cent and amperes),
``P_log = (1 + g) P + o V``, and the drivetrain's losses while the bus moves beyond what its
efficiency gives (an inverter's switching, a motor's iron and a gearbox's churning losses,
which come with turning, not with torque: kW whatever the load). A gain error shows most on
a fast charger (1 % of 450 kW is 4.5 kW, as much as the bus's loads); a loss while moving,
left out, would set the auxiliary load between the standing and the moving bins' and leave
a spurious standing load. They are fitted beside the bus's parameters and stay nuisances of
every test. On several days the sensor's gain and offset are each day's own
(:data:`PER_DAY`): a Hall sensor's offset moves with its temperature and a logger may be
swapped, and one gain for all the days would leave each day's difference as a missing power
that follows the day, as the weather's effects do."""
PER_DAY = ("current sensor gain", "current sensor offset [A]")
MIN_RATED_BINS = 6
"""The bins at a charger's rating (a minute) the log must hold for the share of its rating a
charger delivers to be fitted; with fewer it keeps its configured value (on the backward
model's weak-cell-group bus cut to an hour a day, one bin set it at its bound and moved the
bus's mass and regen power with it)."""
HELD_IN_TESTS = (CHARGER_SHARE,)
"""Fitted with the bus, then held at the fitted value in the held-out tests, as the pack's
values are: the share of its rating a charger delivers shows only in the bins at the
charger's rating, a few blocks of a day. Free in the tests, its column let a load while
standing pass on a control day of the project's own bus (chi-square 177, 89 needed; held,
1), and named a cabin on the backward model's weak-cell-group bus."""
STEP = 0.05  # a parameter's change for its signature, of its search range
ITERATIONS = 4
WAKE_AT = 2
"""The Gauss-Newton step before which :func:`_wake` looks for dead parameters: after the
others have had two steps, so that a dead threshold is not moved to take up what another
parameter, still at its start, misses (a regen cutoff speed too low looks like a lower
blending deceleration)."""
GRID = 8
"""Values across its range a parameter is tried at when its step moves no bin by a watt
(:func:`_wake`), evenly on a log scale (a threshold's scale is what is unknown)."""
MIN_SOC_SPAN = 0.05
END_TOL = 0.02  # a value within this share of its range from an end lies at that end


def search_box(model, fixed=()) -> dict[str, tuple[float, float]]:
    """The :data:`BUS_PARAMETERS` the model has (and the user does not hold), with their
    ranges inside the declared bounds."""
    out = {}
    for name, (low, high) in BUS_PARAMETERS.items():
        name = model.equivalent(name)
        if name is None or name in fixed:
            continue
        i = model.param_index(name)
        value = model.params[i]
        lo, hi = model.bounds[i]
        out[name] = (max(lo, min(low, high) * value), min(hi, max(low, high) * value))
    return out


def counted_capacity_ah(profiles) -> float | None:
    """The pack's capacity [Ah] from the charge the logged current counts against the logged
    SoC (None when the SoC moves too little to tell)."""
    charge, soc, hours = [], [], []
    for p in profiles:
        every = max(1, int(round(1.0 / p.dt_s)))
        current = p.measured["battery_current_a"][::every]
        level = p.measured["soc_frac"][::every]
        ok = np.isfinite(current) & np.isfinite(level)
        step_h = every * p.dt_s / 3600.0
        counted = -np.cumsum(np.where(ok, current, 0.0)) * step_h
        charge.append(counted[ok] - counted[ok][0])
        soc.append(level[ok] - level[ok][0])
        hours.append(np.flatnonzero(ok) * step_h)
    q, s = np.concatenate(charge), np.concatenate(soc)
    if np.ptp(s) < MIN_SOC_SPAN:
        return None
    (slope, _), *_ = np.linalg.lstsq(np.column_stack([s, np.concatenate(hours)]), q, rcond=None)
    return float(slope) if slope > 0 else None


def pack_values(model, profiles) -> dict[str, float]:
    """The cell capacity the log's counted charge gives (empty when it cannot)."""
    capacity_ah = counted_capacity_ah(profiles)
    if capacity_ah is None:
        return {}
    name = model.equivalent("rint_battery.cell_capacity_ah")
    parallel = model.equivalent("rint_battery.cells_parallel")
    if name is None or parallel is None:
        return {}
    strings = model.params[model.param_index(parallel)]
    lo, hi = model.bounds[model.param_index(name)]
    return {name: float(np.clip(capacity_ah / strings, lo, hi))}


def resistance_check_at(model, profiles, params):
    """The logged voltage's resistance check at ``params`` (:mod:`~ebus_env.diagnostics.voltage`),
    with the 5-min windows and the window-anchored runs it was made on."""
    every = max(1, int(round(1.0 / profiles[0].dt_s)))
    windows = make_windows(profiles, 300.0, every)
    anchored = [anchored_run(model, p, params, windows, k, every) for k, p in enumerate(profiles)]
    return resistance_check(profiles, anchored, windows), windows, anchored


def pack_resistance(model, profiles, params) -> dict[str, float]:
    """The cell resistance the logged voltage gives: the model's at ``params`` times the log's
    apparent resistance over the model's (the median over the 5-min windows off the charger,
    :func:`~ebus_env.diagnostics.voltage.resistance_check`), within the bus-to-bus range of
    :data:`~ebus_env.diagnostics.ladder.NUISANCE`; empty when the log does not show it.

    The power a pack delivers does not show its resistance, but where its charger's CV phase
    starts, and how much regen the cell voltage window lets in near full, follow it: a
    resistance left twice too high moves power out of the model's charging and high-SoC
    braking, which a missing-power test would take for a load or force there."""
    check, _, _ = resistance_check_at(model, profiles, params)
    name = model.equivalent("rint_battery.cell_resistance_mohm")
    if check is None or name is None or not np.isfinite(check.level) or check.level <= 0:
        return {}
    i = model.param_index(name)
    low, high = NUISANCE["rint_battery.cell_resistance_mohm"]
    configured = model.params[i]
    lo, hi = model.bounds[i]
    value = float(params[i] * check.level)
    return {name: float(np.clip(value, max(lo, low * configured), min(hi, high * configured)))}


@dataclass
class BusFit:
    """The fitted bus: its parameter row, runs along the log and its nuisance columns."""

    model: object
    names: list[str]  # the fitted parameters
    box: dict[str, tuple[float, float]]
    params: np.ndarray  # the model's full parameter row
    runs: list[np.ndarray]  # per profile (n_seconds, len(TRACE)) at params
    nuisance: Nuisance  # columns on every bin, the box about the fitted values
    power_w: np.ndarray  # the model's pack power per bin at params
    sensor_terms: int  # the first columns of ``nuisance``: the sensor's (per day where so)

    @property
    def values(self) -> dict[str, float]:
        """Every parameter of the model by name."""
        return {n: float(v) for n, v in zip(self.model.param_names, self.params, strict=True)}

    def tested_nuisance(self, use: np.ndarray) -> Nuisance:
        """The nuisance columns of the held-out tests on the ``use`` bins: all but those of
        :data:`HELD_IN_TESTS`."""
        keep = [c for c, n in enumerate(self.nuisance.names) if n not in HELD_IN_TESTS]
        return Nuisance([self.nuisance.names[c] for c in keep], self.nuisance.x[use][:, keep],
                        self.nuisance.low[keep], self.nuisance.high[keep])

    def sensor_fit(self, logged_w: np.ndarray, use: np.ndarray, weights=None) -> np.ndarray:
        """The :data:`SENSOR` terms' fitted values (gain [1], offset [A], loss while moving
        [kW]; per day where so), fitted on the ``use`` bins with ``weights``."""
        k = self.sensor_terms
        w = np.ones(len(logged_w)) if weights is None else weights
        local = Nuisance(self.nuisance.names[:k], self.nuisance.x[use, :k],
                         self.nuisance.low[:k], self.nuisance.high[:k])
        return fit_all(logged_w[use] - self.power_w[use], w[use], local)[2]

    def missing(self, logged_w: np.ndarray, use: np.ndarray, weights=None) -> np.ndarray:
        """The power the fitted bus misses per bin, the sensor's fitted gain and offset taken
        off (fitted on the ``use`` bins with ``weights``)."""
        coef = self.sensor_fit(logged_w, use, weights)
        return logged_w - self.power_w - self.nuisance.x[:, :self.sensor_terms] @ coef

    def table(self, logged_w: np.ndarray, use: np.ndarray, weights=None) -> list[dict]:
        """The bus as its logs give it: each fitted parameter and :data:`SENSOR` term with
        its value, the range searched and the end of it the value lies at, if any."""
        k = self.sensor_terms
        fitted = [(name, self.params[self.model.param_index(name)], *self.box[name])
                  for name in self.names]
        fitted += zip(self.nuisance.names[:k], self.sensor_fit(logged_w, use, weights),
                      self.nuisance.low[:k], self.nuisance.high[:k], strict=True)
        return [{"parameter": name, "value": float(value), "range": [float(lo), float(hi)],
                 "end": _end(value, lo, hi)} for name, value, lo, hi in fitted]

    def range_ends(self, tol: float = END_TOL) -> dict[str, str]:
        """The fitted parameters at an end of their search range ("lower" or "upper")."""
        ends = {name: _end(self.params[self.model.param_index(name)], *self.box[name], tol)
                for name in self.names}
        return {name: end for name, end in ends.items() if end}


def _end(value: float, lo: float, hi: float, tol: float = END_TOL) -> str | None:
    """"lower" or "upper" where ``value`` lies within ``tol`` of its range from that end."""
    if hi <= lo:
        return None
    if value <= lo + tol * (hi - lo):
        return "lower"
    return "upper" if value >= hi - tol * (hi - lo) else None


def _signatures(model, profiles, params, names, box, lag=0):
    """Runs at ``params`` and with each of ``names`` moved by :data:`STEP` of its range:
    (runs (per profile (n_seconds, len(TRACE))), columns (per profile (p, n_seconds)) [W per
    unit], the change made)."""
    rows = np.tile(params, (len(names) + 1, 1))
    change = np.zeros(len(names))
    for j, name in enumerate(names):
        i = model.param_index(name)
        lo, hi = box[name]
        step = STEP * (hi - lo)
        change[j] = step if params[i] + step <= hi else -step
        rows[j + 1, i] += change[j]
    # every signal of the run at params, the power alone of the others (a fifth of the steps
    # to keep)
    runs = [t[0] for t in anchored_runs(model, profiles, rows[:1], TRACE, lag)]
    moved = anchored_runs(model, profiles, rows[1:], ("battery_power_w",), lag)
    at = TRACE.index("battery_power_w")
    columns = [(m[:, :, 0] - r[:, at]) / change[:, None] for r, m in zip(runs, moved, strict=True)]
    return runs, columns, change


def fit_bus(model, profiles, bins: Bins, logged_w: np.ndarray, voltage_v: np.ndarray,
            weights: np.ndarray, start: dict[str, float] | None = None, fixed=(),
            iterations: int = ITERATIONS) -> BusFit:
    """Fit the bus-to-bus parameters and the :data:`SENSOR` terms to the logged power of the
    fitted bins (``logged_w``, ``voltage_v``: per bin) with ``weights``, from the model's
    values and ``start`` (the charger's share of its rating where the log holds
    :data:`MIN_RATED_BINS` at it). The fit's nuisance columns are the :data:`SENSOR` terms'
    first, then the parameters'."""
    rated = bins.fit & (bins.mode_share[:, MODES.index("charging")] > 0.5)
    if rated.sum() < MIN_RATED_BINS:
        fixed = (*fixed, model.equivalent(CHARGER_SHARE))
    box = search_box(model, fixed)
    names = list(box)
    params = model.param_vector(model.carry_over(start or {}))
    index = [model.param_index(n) for n in names]
    low = np.array([box[n][0] for n in names])
    high = np.array([box[n][1] for n in names])
    params[index] = np.clip(params[index], low, high)
    at = TRACE.index("battery_power_w")
    use = bins.fit

    def nuisance_at(runs, columns):
        power = bins.means([r[:, at] for r in runs])
        sensor = sensor_columns(bins, power, voltage_v)
        x = np.column_stack([sensor.x, bins.means(columns).T])
        return power, Nuisance([*sensor.names, *names], x,
                               np.append(sensor.low, low - params[index]),
                               np.append(sensor.high, high - params[index])), len(sensor.names)

    for it in range(iterations):
        runs, columns, change = _signatures(model, profiles, params, names, box, bins.lag)
        power, nuisance, k = nuisance_at(runs, columns)
        if it == WAKE_AT and (dead := _dead(nuisance.x[use, k:], change)):
            params = _wake(model, profiles, bins, logged_w, weights, params, names, box,
                           dead, power, nuisance, k)
            runs, columns, _ = _signatures(model, profiles, params, names, box, bins.lag)
            power, nuisance, k = nuisance_at(runs, columns)
        local = Nuisance(nuisance.names, nuisance.x[use], nuisance.low, nuisance.high)
        _, _, step, _, _ = fit_all(logged_w[use] - power[use], weights[use], local)
        params = params.copy()
        params[index] = np.clip(params[index] + step[k:], low, high)
    runs, columns, _ = _signatures(model, profiles, params, names, box, bins.lag)
    power, nuisance, k = nuisance_at(runs, columns)
    return BusFit(model, names, box, params, runs, nuisance, power, k)


def _dead(columns: np.ndarray, change: np.ndarray) -> list[int]:
    """The parameters whose step moves no fitted bin by a watt: a threshold the log never
    reaches where the parameter starts, such as a brake-blending deceleration of 5 m/s^2 on a
    bus that brakes at 1. A Gauss-Newton step sees no slope there and would leave them."""
    moved = np.abs(columns * change).max(axis=0) if len(columns) else np.zeros(len(change))
    return [j for j, m in enumerate(moved) if m < 1.0]


def _wake(model, profiles, bins: Bins, logged_w, weights, params, names, box, dead,
          power_w, nuisance: Nuisance, k: int) -> np.ndarray:
    """Each :func:`_dead` parameter moved to the best of :data:`GRID` values across its box:
    the one whose run leaves the least weighted missing power, with the sensor's terms and
    the other parameters' signatures (at the start) free. One batched run for them all."""
    use = bins.fit
    index = [model.param_index(n) for n in names]
    rows, tried = [], []
    for j in dead:
        lo, hi = box[names[j]]
        for value in (np.geomspace(lo, hi, GRID) if lo > 0 else np.linspace(lo, hi, GRID)):
            row = params.copy()
            row[index[j]] = value
            rows.append(row)
            tried.append((j, value))
    traces = anchored_runs(model, profiles, np.array(rows), ("battery_power_w",), bins.lag)
    out = params.copy()
    for j in dead:
        keep = [c for c in range(nuisance.x.shape[1]) if c != k + j]
        local = Nuisance([nuisance.names[c] for c in keep], nuisance.x[use][:, keep],
                         nuisance.low[keep], nuisance.high[keep])
        best = (fit_all(logged_w[use] - power_w[use], weights[use], local)[4], params[index[j]])
        for r, (jj, value) in enumerate(tried):
            if jj != j:
                continue
            p = bins.means([t[r, :, 0] for t in traces])
            loss = fit_all(logged_w[use] - p[use], weights[use], local)[4]
            if loss < best[0]:
                best = (loss, value)
        out[index[j]] = best[1]
    return out


def sensor_columns(bins: Bins, power_w: np.ndarray, voltage_v: np.ndarray) -> Nuisance:
    """The :data:`SENSOR` terms' columns on every bin (``power_w``: the model's pack power,
    ``voltage_v``: the logged voltage): the gain's is the power, the offset's the voltage, the
    loss while moving's 1 kW on the share of the bin the bus moves. On several days the
    :data:`PER_DAY` terms get one column per day, zero on the other days' bins."""
    moving = 1e3 * (1.0 - bins.mode_share[:, MODES.index("standing")]
                    - bins.mode_share[:, MODES.index("charging")])
    column = {"current sensor gain": power_w, "current sensor offset [A]": voltage_v,
              "drivetrain loss while moving [kW]": moving}
    days = int(bins.day.max()) + 1 if len(bins) else 1
    names, x, low, high = [], [], [], []
    for name, (lo, hi) in SENSOR.items():
        split = name in PER_DAY and days > 1
        for d in range(days if split else 1):
            names.append(f"{name}, day {d}" if split else name)
            x.append(np.where(bins.day == d, column[name], 0.0) if split else column[name])
            low.append(lo)
            high.append(hi)
    return Nuisance(names, np.column_stack(x), np.array(low), np.array(high))
