"""What the bench's logs can hold, by a method that does not run through the diagnosis: each
day's hidden effect against the truth source's own signatures, every bus-to-bus parameter free.

    python -m benchmarks.ceiling [--source truthsim] [--per-effect N] [--controls M] [--smoke]
        [--cache DIR] [--rows FILE [--resume]] [--workers 2] [--effect E] [--charger-share]
    python -m benchmarks.ceiling --kind bus [--per-condition 5] [--control-buses 4] ...
    python -m benchmarks.ceiling --from-rows FILE [--from-rows FILE2 ...]   # report, run nothing

For a day of the bench the truth source itself is run again (its own simulator: the truth
simulator, the backward model or FASTSim):

* ``y_0``: the day without any hidden effect, at the day's true bus;
* a **signature** per candidate effect: the day with the effect less ``y_0`` (the hidden
  effect at its true values; every other effect the source can hide at values drawn for it
  on this day);
* a **sensitivity** per bus-to-bus parameter: the day with the parameter 5 % higher (an
  efficiency 5 % lower) less ``y_0`` (finite differences of the source itself: curb mass,
  rolling and air resistance, drivetrain losses, base auxiliaries, pack capacity and
  resistance); with ``--charger-share`` also the share of its stated rating a charger
  delivers (the plan's charger power 5 % lower), which the power-domain diagnosis fits (a
  log's rating may be the grid side's): a load that runs only while a charger gives its
  rating is then a charger short of it;
* the log's own nuisances: on a BMS log the current sensor's gain (``y_0`` itself) and
  offset (the terminal voltage: offset x V); on a SoC log the BMS's capacity error (``y_0``'s
  SoC change), the current offset's drift (a constant SoC change per window) and its count of
  charge without the cells' coulombic efficiency (the charge put in per window).

What is fitted is what the log shows: on a BMS log the pack power ``I x V`` from the logged
current and voltage, as 60 s means, and apart from it the logged voltage itself (``volt``: a
pack effect may move the voltage and hardly the power, where the drive asks for a power), with
the voltage sensor's gain and offset as its nuisances; on a SoC-only log the logged SoC's
change over each 5-min window (a difference: the BMS's slow drift becomes a constant per
window). The measured
signal less ``y_0`` is fitted by least squares with all sensitivities and nuisances free and
one candidate at a time; the standard errors are Newey-West's (heteroskedasticity and
autocorrelation consistent, Bartlett kernel, 4 lags: W. K. Newey, K. D. West, Econometrica
55 (1987) 703-708), so that what the model does not fit counts as noise.

Per day it reports the hidden effect's **SNR** (its coefficient over its standard error,
signed: an effect acts with a positive strength) and whether it is **separable**: SNR >= 3
and its fit better than every candidate's that stands for another library effect by more than
9 (3 sigma) in the residual sum of squares over the residual variance, inflated by the
autocorrelation (``SEPARATION``; the source's cabin heating and cooling are both the library's
cabin, its loads outside the library all "no library effect"), and
the **fall**: the share of the residual sum of squares the bus's parameters leave that the
hidden effect's own signature removes (the most an error can fall with the effect added in
its true form). On
a control day: the largest SNR of any candidate (what a diagnosis would have to refuse). Per
effect, log type and source, the share of days that are separable is the ceiling that the
diagnosis's bars are compared with; a BMS log holds an effect separable in its power or its
voltage.

A **multi-day bus** (``--kind bus``) is read over its six days together: its days' windows
stacked, each bus-to-bus parameter one column over all its days (a bus's own parameters hold
across its days), the log's nuisances one per day, and each candidate acting from each day on
(a fault's start is not known; a rival gets its best start). The hidden effect is read at its
true start; a fault that starts on a day is also **dated** where every start more than
``START_TOLERANCE_DAYS`` (1) from the true one fits worse by :data:`SEPARATION`: the ceiling
of the start-day figure. A control bus reports its largest candidate SNR at any start.
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from benchmarks.truth.cache import day_paths
from benchmarks.truth.scoring import START_TOLERANCE_DAYS
from ebus_env.outputs import write_text

SOURCES = ("truthsim", "backward", "fastsim")
WINDOW_S = {"bms": 60, "volt": 60, "soc": 300}
SIGNAL = {"bms": ("power_w", False), "volt": ("volts_v", False), "soc": ("soc", True)}
"""Each kind's column of a run and whether it is read as its change over a window."""
LAGS = 4
SNR_MIN = 3.0
SEPARATION = 9.0
STEP = 0.05  # the parameters' finite-difference step, relative
CANDIDATE_SEED = 99  # the stream of the candidates' values (not the hidden effect's)
SMOKE_HOURS = 3.0

PARAMS = {
    # the bus-to-bus parameters of each source's bus (their names in its base draw)
    "truthsim": ("curb_mass_kg", "c_rr0", "cda_m2", "drive_efficiency", "aux_base_w",
                 "capacity_ah", "r0_ohm", "regen_max_decel_mps2"),
    "backward": ("curb_mass_kg", "rrc_n_per_kn", "cda_m2", "axle_loss_frac",
                 "motor_loss_scale", "aux_base_w", "capacity_ah", "r0_ohm"),
    "fastsim": ("curb_mass_kg", "rolling_coef", "drag_coef", "drivetrain_efficiency",
                "aux_base_w", "capacity_kwh", "pack_r_ohm"),
}
COUPLED = {"r0_ohm": ("r1_ohm", "r2_ohm")}  # resistances that move together


class Source:
    """One truth source's simulator behind one interface: its module's day, a run of a plan
    with an effect, and the values of an effect drawn for a day."""

    def __init__(self, name: str):
        self.name = name
        if name == "truthsim":
            from benchmarks.truth import cases, sim

            self.module, self._sim, self._draw = cases, sim.simulate, cases._physical
            self.effects = tuple(cases.EFFECTS)
        elif name == "backward":
            from benchmarks.truth import backward_source as bw

            self.module, self._sim, self._draw = bw, bw.simulate, bw.draw_effect
            self.effects = tuple(e for e in bw.HIDDEN if e in _single_day_effects())
        else:
            from benchmarks.truth import fastsim_source as fs

            self.module, self._sim = fs, fs.simulate
            self._draw = lambda effect, rng, plan, chemistry: fs._draw_effect(effect, rng, plan)
            self.effects = fs.HIDDEN
        # a bus's candidates: the single days' and the source's multi-day conditions
        self.bus_effects = (*self.effects,
                            *(c for c in self.module.MULTI_DAY if c not in self.effects))

    def run(self, plan, base, effect, physical, day) -> pd.DataFrame:
        """A run's pack power [W] and SoC [1], 1 Hz."""
        trace = self._sim(plan, base, effect, physical, **day)
        power = trace["battery_current_a"] * trace["battery_voltage_v"]
        charged = np.cumsum(np.maximum(-trace["battery_current_a"].to_numpy(float), 0.0))
        return pd.DataFrame({"power_w": power.to_numpy(float),
                             "volts_v": trace["battery_voltage_v"].to_numpy(float),
                             "soc": trace["soc_frac"].to_numpy(float),
                             "charged_as": charged})

    def draw(self, effect, plan, chemistry, seed) -> dict:
        return self._draw(effect, np.random.default_rng([seed, CANDIDATE_SEED]), plan,
                          chemistry)[0]


def _single_day_effects():
    from benchmarks.truth.cases import EFFECTS

    return EFFECTS


def measured_log(source: Source, case, cache: Path | None) -> pd.DataFrame:
    """The day's BMS log: read from the bench's cache where it was generated, else made."""
    if cache is not None:
        log_path, truth_path = day_paths(cache, source.name, case)
        if truth_path.exists():
            return pd.read_csv(log_path)
    return source.module.generate(case, current_voltage=True)[0]


def windows(values: np.ndarray, width: int, difference: bool) -> np.ndarray:
    """Means over consecutive windows of ``width`` rows, or (``difference``) the change
    over each window."""
    n = len(values) // width * width
    blocks = values[:n].reshape(-1, width)
    return blocks[:, -1] - blocks[:, 0] if difference else blocks.mean(axis=1)


def newey_west(x: np.ndarray, resid: np.ndarray, lags: int = LAGS) -> np.ndarray:
    """Newey-West covariance of OLS coefficients (Bartlett weights ``1 - l / (L + 1)``)."""
    xe = x * resid[:, None]
    s = xe.T @ xe
    for lag in range(1, lags + 1):
        w = 1.0 - lag / (lags + 1.0)
        g = xe[lag:].T @ xe[:-lag]
        s += w * (g + g.T)
    bread = np.linalg.pinv(x.T @ x)
    return bread @ s @ bread


MIN_DOF = 10
"""A fit with fewer windows than its regressors and this many more says nothing (SNR NaN)."""
IDENTIFIABLE = 1e-3
"""A signature whose part outside the basis's span is below this share of it (a constant load
beside the base auxiliaries on a day, say) cannot be told from the bus's own parameters: its
SNR is 0."""


def basis_residual(y: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """What of ``y`` the basis (its columns scaled to 1 for the conditioning) leaves."""
    scaled = basis / np.maximum(np.abs(basis).max(axis=0), 1e-12)
    coef, *_ = np.linalg.lstsq(scaled, y, rcond=None)
    return y - scaled @ coef


def fit(y: np.ndarray, basis: np.ndarray, signature: np.ndarray) -> dict:
    """Least squares of ``y`` on the basis (sensitivities and nuisances) and one signature:
    the signature's coefficient, its Newey-West standard error, the residual sum of squares,
    and the autocorrelation's inflation of the variance (HAC over OLS); SNR 0 where the
    signature is (nearly) in the basis's span (``IDENTIFIABLE``)."""
    if len(y) - basis.shape[1] - 1 < MIN_DOF:
        return {"snr": float("nan"), "rss": float("nan"), "sigma2": float("nan"),
                "inflation": 1.0}
    b_scale = np.maximum(np.abs(basis).max(axis=0), 1e-12)
    inside, *_ = np.linalg.lstsq(basis / b_scale, signature, rcond=None)
    outside = signature - (basis / b_scale) @ inside
    if np.linalg.norm(outside) < IDENTIFIABLE * np.linalg.norm(signature):
        resid = basis_residual(y, basis)
        dof = max(len(y) - basis.shape[1], 1)
        return {"snr": 0.0, "rss": float(resid @ resid), "sigma2": float(resid @ resid / dof),
                "inflation": 1.0}
    x = np.column_stack((basis, signature))
    scale = np.maximum(np.abs(x).max(axis=0), 1e-12)  # conditioning only
    xs = x / scale
    coef, *_ = np.linalg.lstsq(xs, y, rcond=None)
    resid = y - xs @ coef
    dof = max(len(y) - xs.shape[1], 1)
    sigma2 = resid @ resid / dof
    hac = newey_west(xs, resid)
    ols = np.linalg.pinv(xs.T @ xs) * sigma2
    se = float(np.sqrt(max(hac[-1, -1], 0.0)))
    return {"snr": float(coef[-1] / se) if se > 0 else 0.0, "rss": float(resid @ resid),
            "sigma2": float(sigma2),
            "inflation": float(max(hac[-1, -1] / ols[-1, -1], 1.0)) if ols[-1, -1] > 0 else 1.0}


def library(effect: str | None) -> str | None:
    """The library effect a source's hidden effect stands for (the diagnosis's right answer),
    ``outside_library`` for a load or force outside it (a source's own, such as FASTSim's
    soft tyres, too); None for nothing hidden."""
    from benchmarks.truth.cases import VERDICTS

    return None if effect is None else VERDICTS.get(effect, "outside_library")


def day_signals(source: Source, case, cache: Path | None, charger_share: bool,
                effects: tuple[str, ...], candidate_seed: int) -> dict:
    """A day's signals per log kind (:data:`WINDOW_S`): ``y``, the measured signal less
    ``y_0``; ``moved``, each bus-to-bus parameter's sensitivity (those above a run's rounding);
    ``nuisance``, the log's own nuisance columns; ``signatures``, each candidate's (the hidden
    effect at the day's true values, every other one at values drawn from
    ``candidate_seed``)."""
    plan, base, ph, day, _ = source.module.day_trace(case)
    chemistry = base.get("chemistry") or "LFP"
    log = measured_log(source, case, cache)
    y0 = source.run(plan, base, None, {}, day)
    n = min(len(log), len(y0))
    candidates = {}
    for effect in effects:
        if effect == case.hidden:
            candidates[effect] = source.run(plan, base, effect, ph, day)
            continue
        try:
            candidates[effect] = source.run(plan, base, effect, source.draw(
                effect, plan, chemistry, candidate_seed), day)
        except RuntimeError:  # the bus cannot run this day with it (a pack run below its
            continue  # cells' voltage window): not a rival on this day
    sensitivities = {}
    for param in PARAMS[source.name]:
        if param not in base:
            continue
        moved = dict(base)
        # an efficiency moves down (up could pass 1); every other parameter up
        step = -STEP if "efficiency" in param else STEP
        for key in (param, *COUPLED.get(param, ())):
            if key in moved:
                moved[key] = moved[key] * (1.0 + step)
        sensitivities[param] = source.run(plan, moved, None, {}, day)
    if charger_share and plan["charger_kw"].max() > 0:  # a charger short of its rating
        short = plan.copy()
        short["charger_kw"] = plan["charger_kw"] * (1.0 - STEP)
        sensitivities["charger_share"] = source.run(short, base, None, {}, day)
    measured = {"bms": (log["battery_current_a"] * log["battery_voltage_v"]).to_numpy(float),
                "volt": log["battery_voltage_v"].to_numpy(float),
                "soc": log["soc_pct"].to_numpy(float) / 100.0}
    out = {}
    for kind, width in WINDOW_S.items():
        column, difference = SIGNAL[kind]

        def signal(run, column=column, width=width, difference=difference):
            return windows(run[column].to_numpy()[:n], width, difference)

        base_signal = signal(y0)
        nuisance = [base_signal, np.ones_like(base_signal)]
        if kind == "bms":  # a current offset shows as offset x V
            nuisance[1] = windows(y0["volts_v"].to_numpy()[:n], width, False)
        elif kind == "soc":  # the BMS counts charge without the cells' coulombic efficiency
            nuisance.append(windows(y0["charged_as"].to_numpy()[:n], width, True))
        floor = 1e-9 * max(np.abs(base_signal).max(), 1.0)  # a run's rounding, not a change
        moved = {p: signal(r) - base_signal for p, r in sensitivities.items()}
        signatures = {e: signal(r) - base_signal for e, r in candidates.items()}
        out[kind] = {
            "y": windows(measured[kind][:n], width, difference) - base_signal,
            "moved": {p: m for p, m in moved.items() if np.abs(m).max() > floor},
            "nuisance": nuisance,
            "signatures": {e: s for e, s in signatures.items() if np.abs(s).max() > floor}}
    return out


def separation(y: np.ndarray, basis: np.ndarray, signatures: dict,
               hidden: str | tuple[str, int] | None) -> tuple[dict, dict]:
    """One log kind's reading of a hidden effect: its SNR, its margin over every candidate
    that stands for another library effect, its fall and whether it is separable; the largest
    SNR of any other candidate (a control's alarm); and each candidate's fit. ``signatures``:
    candidate -> column, or (candidate, start day) -> column on a bus (``hidden`` then
    (effect, its true start))."""
    rss_bus = float(np.sum(basis_residual(y, basis) ** 2))  # the bus's parameters alone
    fits = {key: fit(y, basis, sig) for key, sig in signatures.items()}

    def effect_of(key):
        return key[0] if isinstance(key, tuple) else key

    own = fits.get(hidden) if hidden is not None else None
    # a rival is another library effect: the source's cabin heating and cooling are one
    # (the library's cabin), its loads outside the library all "no library effect"
    others = {k: f for k, f in fits.items()
              if library(effect_of(k)) != library(effect_of(hidden))}
    # one-sided: an effect acts with a positive strength (a load draws, a force resists)
    result = {"windows": len(y), "max_other_snr": max(
        (f["snr"] for k, f in fits.items()
         if (hidden is None or effect_of(k) != effect_of(hidden)) and np.isfinite(f["snr"])),
        default=0.0)}
    if own is not None and np.isfinite(own["snr"]):
        margin = min((excess(f, own) for f in others.values()), default=np.inf)
        result.update(snr=own["snr"], margin=float(margin),
                      fall=float(1.0 - own["rss"] / rss_bus) if rss_bus > 0 else 0.0,
                      separable=bool(own["snr"] >= SNR_MIN and margin >= SEPARATION))
    return result, fits


def excess(other: dict, own: dict) -> float:
    """How much worse ``other`` fits than ``own``: the residual sum of squares' excess over
    own's residual variance, inflated by the autocorrelation (a chi-square's scale)."""
    return (other["rss"] - own["rss"]) / (own["sigma2"] * own["inflation"])


def ceiling_day(job) -> dict:
    """A day's SNR of its hidden effect and its separability, on both log types. ``job``:
    (source name, case, cache folder or None[, the charger's delivered share free])."""
    name, case, cache, charger_share = (*job, False)[:4]
    t0 = time.perf_counter()
    source = Source(name)
    signals = day_signals(source, case, Path(cache) if cache else None, charger_share,
                          source.effects, case.seed)
    row = {"source": name, "case": case.case_id, "hidden": case.hidden,
           "hours": case.hours, "time_s": 0.0}
    for kind, s in signals.items():
        basis = np.column_stack([*s["moved"].values(), *s["nuisance"]])
        row[kind] = separation(s["y"], basis, s["signatures"], case.hidden)[0]
    row["time_s"] = time.perf_counter() - t0
    return row


def ceiling_bus(job) -> dict:
    """A multi-day bus's reading: its days' signals stacked, the bus-to-bus parameters one
    per bus (each a column over all its days), the log's nuisances one per day, and each
    candidate acting from each day on (a fault's start is free; a rival gets its best start).
    The hidden effect is read at its true start; a fault that starts on a day is **dated**
    where every start more than ``START_TOLERANCE_DAYS`` from the true one fits worse by
    :data:`SEPARATION`. ``job``: (source name, bus, cache folder or None[, charger share[,
    smoke: each day's last :data:`SMOKE_HOURS`]])."""
    name, bus, cache, charger_share, smoke = (*job, False, False)[:5]
    t0 = time.perf_counter()
    source = Source(name)
    days = [last_hours(c) if smoke else c for c in source.module.bus_days(bus)]
    how = source.module.MULTI_DAY[bus.condition][1] if bus.condition else None
    true_start = bus.start_day or 0
    signals = [day_signals(source, case, Path(cache) if cache else None, charger_share,
                           source.bus_effects, bus.seed) for case in days]
    row = {"source": name, "case": bus.bus_id, "hidden": bus.condition, "condition_kind": how,
           "start_day": bus.start_day, "days": len(days),
           "hours": float(sum(c.hours for c in days)), "time_s": 0.0}
    for kind in WINDOW_S:
        parts = [s[kind] for s in signals]
        sizes = [len(p["y"]) for p in parts]

        def stacked(columns, parts=parts, sizes=sizes):
            return np.concatenate([c if c is not None else np.zeros(k)
                                   for c, k in zip(columns, sizes, strict=True)])

        params = sorted({p for part in parts for p in part["moved"]})
        shared = [stacked([part["moved"].get(p) for part in parts]) for p in params]
        per_day = [stacked([column if i == d else None for i in range(len(parts))])
                   for d, part in enumerate(parts) for column in part["nuisance"]]
        effects = sorted({e for part in parts for e in part["signatures"]})
        signatures = {(e, k): stacked([part["signatures"].get(e) if d >= k else None
                                       for d, part in enumerate(parts)])
                      for e in effects for k in range(len(parts))}
        signatures = {key: s for key, s in signatures.items() if np.abs(s).max() > 0}
        y = stacked([part["y"] for part in parts])
        hidden = (bus.condition, true_start) if bus.condition else None
        result, fits = separation(y, np.column_stack(shared + per_day), signatures, hidden)
        if how == "from_day" and hidden in fits:
            own = fits[hidden]
            starts = {k: f for (e, k), f in fits.items() if e == bus.condition}
            far = [excess(f, own) for k, f in starts.items()
                   if abs(k - true_start) > START_TOLERANCE_DAYS]
            result.update(best_start=min(starts, key=lambda k: starts[k]["rss"]),
                          start_margin=float(min(far, default=np.inf)),
                          dated=bool(min(far, default=np.inf) >= SEPARATION))
        row[kind] = result
    row["time_s"] = time.perf_counter() - t0
    return row


def cases_of(source: Source, smoke: bool, per_effect: int | None,
             controls: int | None, effects: tuple[str, ...] = ()) -> list:
    listed = [c for c in source.module.cases()
              if not effects or c.hidden is None or c.hidden in effects]
    taken: dict = {}
    out = []
    for case in listed:
        limit = controls if case.hidden is None else per_effect
        taken[case.hidden] = taken.get(case.hidden, 0) + 1
        if limit is None or taken[case.hidden] <= limit:
            out.append(last_hours(case) if smoke else case)
    return out


def last_hours(case):
    """A smoke run's day: the case's last :data:`SMOKE_HOURS`."""
    start = case.start_clock_h + max(case.hours - SMOKE_HOURS, 0.0)
    return replace(case, start_clock_h=round(start, 3), hours=min(case.hours, SMOKE_HOURS))


EITHER = "bms|volt"
"""A BMS log's reading: the power or the voltage (the better of the two per day)."""


def with_either(row: dict) -> dict:
    """``row`` with its BMS log's :data:`EITHER` reading: separable in the power or in the
    voltage, at the larger SNR; on a control day the larger of the two largest SNRs."""
    if "bms" not in row or "volt" not in row:
        return row
    power, volt = row["bms"], row["volt"]
    either = {"windows": power["windows"],
              "max_other_snr": max(power["max_other_snr"], volt["max_other_snr"])}
    scored = [k for k in (power, volt) if "snr" in k]
    if scored:
        best = max(scored, key=lambda k: (k["separable"], k["snr"]))
        either.update(snr=best["snr"], margin=best["margin"], fall=best["fall"],
                      separable=any(k["separable"] for k in scored))
        if any("dated" in k for k in scored):  # a bus's fault: its start dated in either
            either["dated"] = any(k.get("dated", False) for k in scored)
    return {**row, EITHER: either}


def grouped(rows: list[dict]):
    """Per source and log kind: its rows and their readings by hidden effect ("control")."""
    for name in SOURCES:
        for kind in (*WINDOW_S, EITHER):
            part = [r for r in rows if r["source"] == name and kind in r]
            groups = {h: [r[kind] for r in part if (r["hidden"] or "control") == h]
                      for h in sorted({r["hidden"] or "control" for r in part})}
            yield name, kind, part, groups


def print_controls(name: str, kind: str, snrs: list[float], width: int, note: str) -> None:
    """A report's line of control days or buses: how many have a candidate at SNR >= 3."""
    alarms = sum(snr >= SNR_MIN for snr in snrs)
    print(f"  {name:9s} {kind:8s} {'control':{width}s} {len(snrs):5d} {alarms:>4d} >= 3 {note}")


def report(rows: list[dict]) -> None:
    rows = [with_either(r) for r in rows]
    buses = [r for r in rows if "days" in r]
    rows = [r for r in rows if "days" not in r]
    if buses:
        report_buses(buses)
    if not rows:
        return
    print("\nThe ceiling: the hidden effect's SNR with every bus-to-bus parameter free, and the "
          "days where it is separable (SNR >= 3 and better than every candidate of another "
          "library effect)")
    print(f"  {'source':9s} {'log':8s} {'hidden effect':18s} {'days':>5s} {'separable':>10s} "
          f"{'SNR median':>11s} {'(range)':>17s}")
    for name, kind, part, groups in grouped(rows):
        for hidden, group in groups.items():
            if hidden == "control":
                snrs = [g["max_other_snr"] for g in group]
                print_controls(name, kind, snrs, 18, f"{np.median(snrs):11.1f} ({min(snrs):6.1f}, "
                               f"{max(snrs):6.1f})  (the largest candidate SNR)")
                continue
            scored = [g for g in group if "snr" in g]
            if not scored:
                continue
            snrs = [s["snr"] for s in scored]
            separable = sum(s["separable"] for s in scored)
            falls = [s["fall"] for s in scored if "fall" in s]
            print(f"  {name:9s} {kind:8s} {hidden:18s} {len(scored):5d} "
                  f"{100 * separable / len(scored):9.0f} % {np.median(snrs):11.1f} "
                  f"({min(snrs):6.1f}, {max(snrs):6.1f})"
                  + (f"  fall {100 * np.median(falls):.0f} %" if falls else ""))
        hidden_days = [r[kind] for r in part if r["hidden"] and "snr" in r[kind]]
        if hidden_days:
            share = sum(s["separable"] for s in hidden_days) / len(hidden_days)
            print(f"  {name:9s} {kind:8s} {'all hidden effects':18s} {len(hidden_days):5d} "
                  f"{100 * share:9.0f} %")
    times = [r["time_s"] * 10.0 / r["hours"] for r in rows]
    if times:
        print(f"  per 10 h day: {np.median(times):.0f} s (median, one core)")


def report_buses(rows: list[dict]) -> None:
    """Per source, log kind and condition: the buses whose hidden effect is separable over
    their days together, and of the faults that start on a day those whose start is dated."""
    print("\nThe ceiling on multi-day buses: the bus's parameters shared by its days, each "
          "candidate from each day on; separable as for a day; a fault's start dated where "
          f"every start more than {START_TOLERANCE_DAYS} day from it fits worse by "
          f"{SEPARATION:g}")
    print(f"  {'source':9s} {'log':8s} {'condition':20s} {'buses':>5s} {'separable':>10s} "
          f"{'dated':>7s} {'SNR median':>11s}")
    for name, kind, part, groups in grouped(rows):
        for hidden, group in groups.items():
            if hidden == "control":
                print_controls(name, kind, [g["max_other_snr"] for g in group], 20,
                               "(the largest candidate SNR, any start)")
                continue
            scored = [g for g in group if "snr" in g]
            if not scored:
                continue
            faults = [g for g in scored if "dated" in g]
            dated = f"{sum(g['dated'] for g in faults)}/{len(faults)}" if faults else "-"
            print(f"  {name:9s} {kind:8s} {hidden:20s} {len(scored):5d} "
                  f"{100 * np.mean([g['separable'] for g in scored]):9.0f} % {dated:>7s} "
                  f"{np.median([g['snr'] for g in scored]):11.1f}")
        library_buses = [r[kind] for r in part if "snr" in r[kind]
                         and library(r["hidden"]) not in (None, "outside_library")]
        if library_buses:
            print(f"  {name:9s} {kind:8s} {'library conditions':20s} {len(library_buses):5d} "
                  f"{100 * np.mean([g['separable'] for g in library_buses]):9.0f} %")
    times = [r["time_s"] for r in rows]
    print(f"  per bus: {np.median(times):.0f} s (median, one core)")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", choices=SOURCES, action="append")
    parser.add_argument("--per-effect", type=int, default=None)
    parser.add_argument("--controls", type=int, default=None)
    parser.add_argument("--smoke", action="store_true",
                        help="1 day per effect and 1 control per source (--kind bus: 1 bus "
                             "per condition and 1 control bus), each day's last 3 h")
    parser.add_argument("--cache", type=Path, default=None,
                        help="the bench's folder of generated days (read where there)")
    parser.add_argument("--rows", type=Path, default=None, help="write each day's row (JSON)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--charger-share", action="store_true",
                        help="free the share of its rating a charger delivers, as the "
                             "power-domain diagnosis does")
    parser.add_argument("--effect", action="append", default=[],
                        help="only the days hiding this effect (and --controls control days)")
    parser.add_argument("--kind", choices=("day", "bus"), default="day",
                        help="single days, or the multi-day buses (six days of one bus)")
    parser.add_argument("--per-condition", type=int, default=5,
                        help="buses per condition (with --kind bus)")
    parser.add_argument("--control-buses", type=int, default=4,
                        help="control buses per source (with --kind bus)")
    parser.add_argument("--resume", action="store_true",
                        help="keep the rows already in --rows and run only the others")
    parser.add_argument("--from-rows", type=Path, action="append", default=[],
                        help="report the rows of these files (from --rows), running nothing")
    args = parser.parse_args(argv)
    if args.from_rows:
        report([r for path in args.from_rows for r in json.loads(path.read_text())])
        return
    per_effect, controls = (1, 1) if args.smoke else (args.per_effect, args.controls)
    jobs = []
    for name in args.source or SOURCES:
        try:
            source = Source(name)
        except ImportError as exc:
            print(f"  {name} not available ({exc}): skipped")
            continue
        cache = str(args.cache) if args.cache else None
        if args.kind == "bus":
            jobs += [(name, b, cache, args.charger_share, args.smoke)
                     for b in source.module.buses(*((1, 1) if args.smoke else (
                         args.per_condition, args.control_buses)))
                     if not args.effect or b.condition is None or b.condition in args.effect]
        else:
            jobs += [(name, c, cache, args.charger_share)
                     for c in cases_of(source, args.smoke, per_effect, controls,
                                       tuple(args.effect))]
    rows = []
    if args.resume and args.rows and args.rows.exists():  # a run stopped part-way
        rows = json.loads(args.rows.read_text())
        done = {(r["source"], r["case"]) for r in rows}
        jobs = [j for j in jobs if (j[0], j[1].bus_id if args.kind == "bus"
                                    else j[1].case_id) not in done]
    with ProcessPoolExecutor(args.workers) as pool:
        for row in pool.map(ceiling_bus if args.kind == "bus" else ceiling_day, jobs):
            rows.append(row)
            print(f"  {row['source']}/{row['case']}: " + "; ".join(
                (f"{k} SNR {row[k]['snr']:.1f}" if "snr" in row[k] else f"{k} (nothing hidden)")
                + (" separable" if row[k].get("separable") else "")
                + (f", start {'dated' if row[k]['dated'] else 'not dated'}"
                   if "dated" in row[k] else "")
                + f" (others up to {row[k]['max_other_snr']:.1f})" for k in WINDOW_S)
                + f"; {row['time_s']:.0f} s", flush=True)
            if args.rows:  # a temporary file, then renamed: a run cut short keeps its rows
                write_text(args.rows, json.dumps(rows, indent=1, default=float))
    report(rows)


if __name__ == "__main__":
    main()
