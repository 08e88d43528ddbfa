"""What a BMS log's voltage says about the pack's resistance, window by window.

Within a window of a few minutes a pack's open-circuit voltage moves only with the charge it
gives, so its terminal voltage is, to first order (the internal-resistance equivalent circuit,
Plett, *Battery Management Systems* vol. 1, 2015, ch. 2)::

    V(t) = V_0 + k q(t) - R I(t),    q(t) = int_0^t I dt

and the least-squares R over the window's samples is the pack's apparent resistance there:
its ohmic part and what of its polarisation settles within a sample. The model's current and
voltage give its own the same way, so their ratio ``R_log / R_model`` keeps only what the
pack does that the model does not. A ratio that changes over the day says the pack's
resistance follows something the model does not (its temperature: a cold pack warming by its
own losses and the day's air, R growing about 3-4 % per kelvin below 25 degC, Waag et al.,
J. Power Sources 242 (2013) 548-559); a steady ratio far from one says the calibrated pack
resistance is off (a SoC log pins it only weakly). The diagnosis's missing power does not use
the voltage (see :mod:`ebus_env.diagnostics.residual`); the missing effect that reproduces the
change (:func:`explain_change`) is reported beside its verdict, and becomes the verdict where
the missing power names none. On several days of one bus, each day's ratio shows whether the
resistance rose from a day on and stayed (:func:`resistance_step`: a weak cell group), which
names the library's ageing from that day.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import t as t_dist

from ebus_env.diagnostics.candidates import shape_settings, strength_rows
from ebus_env.diagnostics.residual import (
    PACK_SIGNALS,
    Windows,
    anchored_run,
    channel,
    correlation_time,
)
from ebus_env.effects import registered_effects
from ebus_env.signals import SLOTS

MIN_ROWS = 30  # recorded rows a window needs for a resistance
MIN_SPREAD_A = 10.0  # standard deviation of the current that makes R observable
MIN_CHANGE = 0.05
"""A resistance that changes by less over the log (relative to its median) is not reported
as a change: the two packs' polarisation at different currents alone moves the ratio by a few
per cent from hour to hour."""
MIN_SIGNIFICANCE = 3.0  # standard deviations the periods' ratios must stand apart
MIN_EXPLAINED = 0.8
"""Share of the change an effect must reproduce to be named: in the finding, and as the
verdict where the missing power names none (stage08_voltage)."""
MIN_HALF = 3  # periods each half of the log needs for its own strength fit
PERIOD_H = 1.0  # the ratio is summarised per hour of log, or per quarter of a shorter one


def apparent_resistance(current_a: np.ndarray, voltage_v: np.ndarray,
                        dt_s: float) -> tuple[float, float]:
    """(R, its standard error) [ohm] of V = V_0 + k q - R I over one window's samples; NaN
    when the current does not move enough to show it. The standard error counts the
    residuals' correlation time."""
    ok = np.isfinite(current_a) & np.isfinite(voltage_v)
    i, v = current_a[ok], voltage_v[ok]
    if len(i) < MIN_ROWS or np.std(i) < MIN_SPREAD_A:
        return float("nan"), float("nan")
    q = np.concatenate([[0.0], np.cumsum(i[:-1])]) * dt_s
    a = np.column_stack([np.ones(len(i)), q, i])
    coef, *_ = np.linalg.lstsq(a, v, rcond=None)
    resid = v - a @ coef
    dof = max(len(i) - 3, 1)
    cov = np.linalg.pinv(a.T @ a) * float(resid @ resid) / dof
    se = float(np.sqrt(max(cov[2, 2], 0.0) * correlation_time(resid)))
    return float(-coef[2]), se


def window_resistances(runs, windows: Windows, usable: np.ndarray, logged=None) -> np.ndarray:
    """Apparent resistance [ohm] in each ``usable`` window of recorded runs (one per profile),
    on the rows off the charger; with ``logged`` (the profiles), of the logged current and
    voltage at the same rows instead. NaN where the current does not show it."""
    out = np.full(len(windows), np.nan)
    for w in np.flatnonzero(usable):
        k = windows.profile_index[w]
        r, every = runs[k], runs[k].record_every
        rows = windows.rows(w, every)
        off = channel(r, "charger_connected")[rows] < 0.5
        if logged is None:
            current, voltage = r.trace("battery_current_a"), r.trace("battery_voltage_v")
        else:
            current, voltage = (logged[k].measured[n][::every] for n in PACK_SIGNALS)
        out[w] = apparent_resistance(current[rows][off], voltage[rows][off],
                                     r.profile.dt_s * every)[0]
    return out


def period_starts_h(windows: Windows) -> np.ndarray:
    """Start [h] of the period each window falls in: an hour of log, or a quarter of a log
    shorter than four hours (a 25-min trip still shows a change)."""
    total_h = float(windows.start_h[-1] + windows.duration_h[-1])
    period = min(PERIOD_H, total_h / 4.0)
    return np.floor(windows.start_h / period + 1e-9) * period


def by_period(ratio: np.ndarray, windows: Windows) -> list[dict]:
    """Median of a per-window ratio per period of log (:func:`period_starts_h`; those with 3
    windows or more), with its standard error from the windows' own scatter (1.4826 MAD;
    1.253 sd / sqrt(n) for the median of a normal sample)."""
    start = period_starts_h(windows)
    seen = np.isfinite(ratio)
    out = []
    for h in np.unique(start[seen]):
        x = ratio[seen & (start == h)]
        if len(x) < 3:
            continue
        sd = 1.4826 * float(np.median(np.abs(x - np.median(x))))
        out.append({"start_h": float(h), "windows": int(len(x)), "ratio": float(np.median(x)),
                    "stderr": max(1.253 * sd / np.sqrt(len(x)), 1e-3)})
    return out


@dataclass
class ResistanceCheck:
    """The pack's apparent resistance, the log's over the model's, per window and by period."""

    periods: list[dict]  # start_h, windows, ratio (median), stderr: per period_starts_h
    level: float  # median ratio over the log
    change: float  # last period's ratio minus the first's, relative to the level
    span: float  # largest minus smallest period's ratio, relative to the level
    significance: float  # of the periods' ratios' spread about the level, in sd
    model_ohm: np.ndarray  # the model's apparent resistance per window (the ratio's base)
    explained_by: list = field(default_factory=list)  # VoltageFit, best first
    ratio: np.ndarray | None = None  # the log's over the model's, per window (NaN: not seen)
    step: ResistanceStep | None = None  # a rise from a day on, on several days

    @property
    def changes(self) -> bool:
        return bool(self.span >= MIN_CHANGE and self.significance >= MIN_SIGNIFICANCE)

    @property
    def best(self):
        """The missing effect that reproduces the change, when one does (``MIN_EXPLAINED``)."""
        if self.changes and self.explained_by and self.explained_by[0].explained >= MIN_EXPLAINED:
            return self.explained_by[0]
        return None

    def finding(self) -> str:
        """One sentence for the report."""
        if self.step is not None:
            return (f"The logged voltage shows {self.step.rose()} from day "
                    f"{self.step.since_day} on (day 0 the first).")
        first, last = self.periods[0]["ratio"], self.periods[-1]["ratio"]
        if self.changes:
            best = self.best
            return (f"The logged voltage shows the pack's resistance changing over the log "
                    f"(from {first:.2f} to {last:.2f} times the model's, values per period "
                    f"{100 * self.span:.0f} % apart, {self.significance:.1f} sd): it follows "
                    "something the model does not, such as the pack's temperature" + (
                        f"; {best.effect} reproduces {100 * best.explained:.0f} % of the "
                        f"change ({best.parameter} = {best.value:.3g})." if best else
                        "; no library effect reproduces it."))
        return (f"The logged voltage shows the pack's resistance steady at {self.level:.2f} "
                f"times the model's (values per period {100 * self.span:.0f} % apart, "
                f"{self.significance:.1f} sd)" + (
                    ": the model's pack resistance is off by as much; a known value "
                    "(--set) would free the fit from it." if abs(self.level - 1.0) > 0.2
                    else "."))

    def to_json(self) -> dict:
        return {"level": self.level, "change": self.change, "span": self.span,
                "significance": self.significance, "changes": self.changes,
                "periods": self.periods, "explained_by": [f.to_json() for f in self.explained_by],
                "step": self.step.to_json() if self.step else None, "finding": self.finding()}


def resistance_check(profiles, anchored, windows: Windows,
                     usable: np.ndarray | None = None) -> ResistanceCheck | None:
    """The log's apparent resistance over the model's in each (``usable``) window, on its
    rows off the charger and the same rows of the window-anchored runs, summarised by hour of
    log (a quarter of a shorter log); None when the log has no current and voltage, or fewer
    than two periods show them."""
    if not all(n in p.measured for p in profiles for n in PACK_SIGNALS):
        return None
    usable = np.ones(len(windows), bool) if usable is None else usable
    model = window_resistances(anchored, windows, usable)
    ratio = window_resistances(anchored, windows, usable, logged=profiles) / np.where(
        model > 0, model, np.nan)
    periods = by_period(ratio, windows)
    if len(periods) < 2:
        return None
    value = np.array([h["ratio"] for h in periods])
    se = np.array([h["stderr"] for h in periods])
    level = float(np.nanmedian(ratio))
    mean = float(np.sum(value / se**2) / np.sum(1.0 / se**2))
    chi2, dof = float(np.sum(((value - mean) / se) ** 2)), len(periods) - 1
    return ResistanceCheck(periods, level, float((value[-1] - value[0]) / level),
                           float((value.max() - value.min()) / level),
                           float((chi2 - dof) / np.sqrt(2.0 * dof)), model, ratio=ratio)


@dataclass
class VoltageFit:
    """How one missing effect reproduces the log's change of resistance (explain_change)."""

    effect: str
    explained: float  # share of the log's variation between periods it takes away, at its best
    parameter: str  # its strength parameter
    index: int  # of the best among the candidate's strengths (its signatures)
    value: float  # the best strength
    interval: tuple[float, float]  # the strengths that fit as well within a 90 % band
    settings: dict = field(default_factory=dict)  # shape parameters it was run at, if not the bus's

    def to_json(self) -> dict:
        return {"effect": self.effect, "explained": self.explained,
                "parameters": {self.parameter: self.value, **self.settings},
                "interval": {self.parameter: list(self.interval)}}


def predicted_ln_ratios(check: ResistanceCheck, model, row: np.ndarray, profiles, anchored,
                        windows: Windows, usable: np.ndarray) -> np.ndarray:
    """ln of the resistance ``model`` at parameter ``row`` shows over the checked model's, per
    period of ``check`` (windows anchored as the check's were)."""
    every = anchored[0].record_every
    base = check.model_ohm
    periods = [h["start_h"] for h in check.periods]
    runs = [anchored_run(model, p, row, windows, k, every) for k, p in enumerate(profiles)]
    ratio = window_resistances(runs, windows, usable) / np.where(base > 0, base, np.nan)
    ratio[~np.isin(period_starts_h(windows), periods)] = np.nan
    mine = {h["start_h"]: h["ratio"] for h in by_period(ratio, windows)}
    return np.log([mine.get(h, np.nan) for h in periods])


def explain_change(check: ResistanceCheck, profiles, anchored, windows: Windows,
                   usable: np.ndarray, candidates, shapes: bool = False) -> list[VoltageFit]:
    """Which missing effects reproduce the log's change of resistance over the day, best
    first: each candidate effect that moves the model's resistance at all (an anchored run at
    either end of its strengths) is run at each of its strengths, its resistance over the
    model's per period compared with the log's (:func:`strength_fit`). ``shapes``: also at
    each value of the effect's shape parameters (a pack's thermal time constant, which sets
    how fast a cold pack warms by its losses), the setting that explains most kept."""
    logged = np.log([h["ratio"] for h in check.periods])
    weight = (np.array([h["ratio"] / h["stderr"] for h in check.periods])) ** 2

    def predicted(c, row):
        return predicted_ln_ratios(check, c.model, row, profiles, anchored, windows, usable)

    out = []
    for c in candidates:
        if c.kind == "parameter" or c.strengths is None:
            continue
        rows, values = strength_rows(c.model, c.params, c.strength_param, c.strengths)
        settings = [{}] + (shape_settings(c.model, c.effect) if shapes and c.effect else [])
        fits = []
        for setting in settings:
            at = rows.copy()
            for name, v in setting.items():
                at[:, c.model.param_index(name)] = v
            ends = {int(i): predicted(c, at[i]) for i in (np.argmin(values), np.argmax(values))}
            if max(np.nanmax(np.abs(x - np.nanmean(x))) for x in ends.values()) < MIN_CHANGE / 4:
                continue  # it does not move the pack's resistance
            ln_ratios = np.array([ends[i] if i in ends else predicted(c, at[i])
                                  for i in range(len(at))])
            fit = strength_fit(values, ln_ratios, logged, weight)
            if fit is not None:
                j, explained, interval = fit
                fits.append(VoltageFit(c.name, explained, c.strength_param, j,
                                       float(values[j]), interval, setting))
        if fits:
            out.append(max(fits, key=lambda f: f.explained))
    return sorted(out, key=lambda f: -f.explained)


def strength_fit(values: np.ndarray, predicted: np.ndarray, logged: np.ndarray,
                 weight: np.ndarray) -> tuple[int, float, tuple[float, float]] | None:
    """The strength at which an effect's ln resistance ratio per period, ``predicted[i]`` at
    ``values[i]``, best reproduces the log's, ``logged`` (weights 1/se^2): (its index, the
    share of the log's variation it takes away, its 90 % interval); None where the log's
    ratio does not vary.

    The log's variation is the chi-square of ln r about a constant: a constant factor is
    free (the level is the calibrated pack resistance's, the change is the effect's). The
    interval holds the strengths whose chi-square lies within 2.71 (90 %, one parameter) of
    the best, scaled by the best's chi-square per degree of freedom where that exceeds one
    (a form that differs from the pack's; Press et al., Numerical Recipes, 3rd ed., 2007,
    sec. 15.6), widened to take in the best strength of the same fit on the log's first and
    on its second half of periods, each where that half's own band closes on both sides (a
    pack that has warmed up by the afternoon says nothing of its starting offset): where an
    effect's form differs from the pack's (a pack warming with its own time constant, not
    the air's), the two halves ask for different strengths, and that sets the doubt."""
    n = len(logged)

    def chi2(x, keep):  # weighted squares about the weighted mean
        x, w = x[keep], weight[keep]
        return float(np.sum(w * (x - np.sum(w * x) / np.sum(w)) ** 2))

    def fit(keep):
        left = np.array([chi2(logged - x, keep) for x in predicted])
        left[~np.isfinite(left)] = np.inf
        j = int(np.argmin(left))
        scale = max(1.0, left[j] / max(int(keep.sum()) - 2, 1))
        return j, left[j], band(values, left, left[j] + 2.71 * scale)

    everywhere = np.ones(n, bool)
    total = chi2(logged, everywhere)
    if not total > 0:
        return None
    j, left, interval = fit(everywhere)
    first = np.arange(n) < n // 2
    for half in ((first, ~first) if n >= 2 * MIN_HALF else ()):
        k, _, (low, high) = fit(half)
        if values.min() < low and high < values.max():  # the half pins the strength
            interval = (min(interval[0], float(values[k])), max(interval[1], float(values[k])))
    return j, 1.0 - left / total, interval


def band(x: np.ndarray, cost: np.ndarray, level: float) -> tuple[float, float]:
    """Where ``cost`` over the grid ``x`` (any order) crosses ``level`` on either side of its
    minimum, by linear interpolation between grid points; a grid end where it never does."""
    order = np.argsort(x)
    x, cost = x[order], cost[order]
    j = int(np.argmin(cost))

    def crossing(step):
        k = j
        while 0 <= k + step < len(x) and cost[k + step] <= level:
            k += step
        if not 0 <= k + step < len(x):
            return float(x[k])
        a, b = cost[k], cost[k + step]
        return float(x[k] + (x[k + step] - x[k]) * (level - a) / (b - a))

    return crossing(-1), crossing(1)


# -- several days of one bus: a rise from a day on ---------------------------------------
STEP_ALPHA = 0.01
"""The chance, on a bus whose pack did not change, that a rise from some day passes, over all
the start days tried together (Bonferroni)."""
WEATHER_SPREAD_K = 2.0
"""Days whose mean ambient spreads by this much or more get a weather term beside the rise:
an unmanaged pack's resistance follows its temperature (about 3-4 % per kelvin, Waag et al.
2013), and a cold spell from a day on is no weak cell."""


@dataclass
class ResistanceStep:
    """The pack's resistance risen from a day on: each day's apparent resistance over the
    model's (:func:`daily_ratios`), fitted by :func:`resistance_step`."""

    since_day: int
    since_days: tuple[int, int]  # the start days that pass as well
    rise: float  # R from since_day on over R before, less one
    interval: tuple[float, float]  # of ``rise``, 90 %
    t: float  # ln(1 + rise) over its standard error
    needed: float  # the t it needed (the start days tried counted)
    days: list[float]  # each day's ratio (NaN: no window showed it)
    weather: bool  # whether the days' ambient was fitted beside it

    def rose(self) -> str:
        """How much the resistance rose, and how surely."""
        low, high = self.interval
        return (f"the pack's resistance {100 * self.rise:.0f} % higher (90 %: {100 * low:.0f} "
                f"to {100 * high:.0f} %; {self.t:.1f} standard errors of the days' scatter, "
                f"{self.needed:.1f} needed"
                + (", the days' weather fitted beside it" if self.weather else "") + ")")

    def why(self, since: str) -> str:
        """What the rise says, from ``since`` (a date, "this day") on."""
        return (f"the logged voltage shows {self.rose()} from {since} on: a weak cell group "
                "limiting its string, or a worn connection, as ageing does to the pack (its "
                "capacity fading with it)")

    def to_json(self) -> dict:
        return {"since_day": self.since_day, "since_days": list(self.since_days),
                "rise": self.rise, "interval": list(self.interval), "t": self.t,
                "needed": self.needed, "days": self.days, "weather": self.weather}


def daily_ratios(ratio: np.ndarray, windows: Windows, day_of: list[int]) -> np.ndarray:
    """Each day's median of the per-window ratio (NaN for a day no window shows)."""
    day = np.asarray(day_of)[windows.profile_index]
    out = np.full(int(max(day_of)) + 1, np.nan)
    for d in range(len(out)):
        x = ratio[(day == d) & np.isfinite(ratio)]
        if len(x):
            out[d] = float(np.median(x))
    return out


def resistance_step(ratio_by_day: np.ndarray, ambient_by_day: np.ndarray | None = None,
                    alpha: float = STEP_ALPHA) -> ResistanceStep | None:
    """A rise of the pack's resistance from a day on, or None.

    A weak cell group (a cell's capacity and resistance gone in a string it limits) or a
    worn connection raises the pack's resistance from the day it happens and keeps it there.
    For each start day N, each day's ratio is fitted as::

        ln r_d = a + b T_d + c [d >= N] + e_d,      b <= 0

    with T_d the day's mean ambient where the days' weather spreads by
    :data:`WEATHER_SPREAD_K` (an unmanaged pack is more resistive when cold, never less), and
    the days' own scatter ``e_d`` (the pack's polarisation at each day's currents) as the
    noise: its standard deviation from the fit's residuals. A start day passes where the
    rise is at least :data:`MIN_CHANGE`, its t (``c`` over its standard error) passes the
    one-sided t test at ``alpha`` over the start days tried, and the days split there: each
    day from N, its weather taken off, above every day before. The best t is the start."""
    y_all = np.log(np.asarray(ratio_by_day, float))
    seen = np.isfinite(y_all)
    days = np.flatnonzero(seen)
    if len(days) < 4:
        return None
    starts = [n for n in range(1, len(y_all)) if days.min() < n <= days.max()]
    y = y_all[seen]
    temp = None if ambient_by_day is None else np.asarray(ambient_by_day, float)[seen]
    weather = temp is not None and bool(np.all(np.isfinite(temp))) \
        and float(np.ptp(temp)) >= WEATHER_SPREAD_K
    found = []
    for n in starts:
        step = (days >= n).astype(float)
        fit = _step_fit(y, step, temp if weather else None)
        if fit is None:
            continue
        c, se, dof, b = fit
        needed = float(t_dist.isf(alpha / len(starts), dof))
        level = y - b * (temp if weather and temp is not None else 0.0)
        split = level[step > 0].min() > level[step == 0].max()
        if c >= np.log1p(MIN_CHANGE) and c / se >= needed and split:
            half = float(t_dist.isf(0.05, dof)) * se
            found.append((c / se, n, c, half, needed, b != 0.0))
    if not found:
        return None
    t, n, c, half, needed, with_weather = max(found)
    passing = [f[1] for f in found]
    return ResistanceStep(n, (min(passing), max(passing)), float(np.expm1(c)),
                          (float(np.expm1(c - half)), float(np.expm1(c + half))), float(t),
                          needed, [float(r) for r in ratio_by_day], with_weather)


def _step_fit(y: np.ndarray, step: np.ndarray, temp: np.ndarray | None):
    """(c, its standard error, the residual degrees of freedom, b) of ln r = a + b T + c
    step by least squares, b held at 0 where it would come out positive; None with fewer than
    two degrees of freedom left."""
    for columns in ([np.ones_like(y), step, temp], [np.ones_like(y), step]):
        if any(col is None for col in columns):
            continue
        a = np.column_stack(columns)
        dof = len(y) - a.shape[1]
        if dof < 2:
            return None
        coef, *_ = np.linalg.lstsq(a, y, rcond=None)
        if a.shape[1] == 3 and coef[2] > 0.0:
            continue  # warmer days more resistive: no weather term then
        resid = y - a @ coef
        cov = np.linalg.pinv(a.T @ a) * float(resid @ resid) / dof
        b = float(coef[2]) if a.shape[1] == 3 else 0.0
        return float(coef[1]), float(np.sqrt(max(cov[1, 1], 1e-300))), dof, b
    return None


AGEING = "static_rcd"
"""The library's ageing: capacity x (1 - RCD), resistance x (1 + k_R RCD)."""


def ages(bus) -> bool:
    """Whether the bus's ageing slot holds the library's ageing (a rise names it)."""
    return bus.slots.get("aging", SLOTS["aging"].default) == AGEING


def day_step(check: ResistanceCheck, windows: Windows, profiles,
             day_of: list[int]) -> ResistanceStep | None:
    """The rise of the resistance from a day on over several days (``day_of``: each
    profile's day), each day's weather its logged mean ambient."""
    if check.ratio is None or max(day_of) == 0:
        return None
    ambient = np.array([np.mean([np.mean(p.channel("ambient_degc"))
                                 for p, d in zip(profiles, day_of, strict=True) if d == day])
                        for day in range(max(day_of) + 1)])
    return resistance_step(daily_ratios(check.ratio, windows, day_of), ambient)


RESISTANCE_GROWTH = (1.0, 2.0)
"""The resistance's growth per unit of lost capacity, k_R, a pack may have: a resistance
rise of x is a capacity fade of x / k_R (docs/physics.md §5.5)."""


def step_strength(step: ResistanceStep, check: ResistanceCheck, model, profiles,
                  day_of: list[int], form_spread: float) -> dict:
    """The ageing a resistance rise says: the capacity fade RCD = rise / k_R (k_R: the
    model's, else the library's default), its 90 % interval from the rise's and
    :data:`RESISTANCE_GROWTH`; and the energy the pack loses to the added resistance from the
    rise's day on, ``rise R I^2`` over the logged current (R: the model's apparent pack
    resistance at the level of the days before), its interval from the rise's widened by a
    library form's spread against the bus's own (``form_spread``, one sd of ln)."""
    growth = model.equivalent(f"{AGEING}.resistance_growth")
    k_r = float(model.params[model.param_index(growth)] if growth is not None else next(
        p.default for p in registered_effects()[AGEING].params if p.name == "resistance_growth"))
    strength_param = f"{AGEING}.rcd_frac"
    before = [r for d, r in enumerate(step.days) if d < step.since_day and np.isfinite(r)]
    ohm = float(np.nanmedian(check.model_ohm)) * float(np.median(before))
    amp2_h = sum(float(np.nansum(p.measured["battery_current_a"] ** 2)) * p.dt_s / 3600.0
                 for p, d in zip(profiles, day_of, strict=True) if d >= step.since_day)
    per_rise = ohm * amp2_h / 1e3  # kWh per unit rise
    low, high = step.interval
    spread = math.exp(1.645 * form_spread)
    return {"parameters": {strength_param: step.rise / k_r},
            "interval": {strength_param: [low / RESISTANCE_GROWTH[1],
                                          high / RESISTANCE_GROWTH[0]]},
            "energy_kwh": step.rise * per_rise,
            "energy_interval_kwh": [low * per_rise / spread, high * per_rise * spread],
            "coefficient": step.rise}
