"""What the bench's logs can hold, by a method that does not run through the diagnosis: each
day's hidden effect against the truth source's own signatures, every bus-to-bus parameter free.

    python -m benchmarks.ceiling [--source truthsim] [--per-effect N] [--controls M] [--smoke]
        [--cache DIR] [--rows FILE] [--workers 2] [--effect E] [--charger-share]
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
voltage. Single days only: the multi-day buses are not read here.
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
    ``outside_library`` for a load or force outside it."""
    from benchmarks.truth.cases import EFFECTS

    return EFFECTS[effect][0] if effect in EFFECTS else effect


def ceiling_day(job) -> dict:
    """A day's SNR of its hidden effect and its separability, on both log types. ``job``:
    (source name, case, cache folder or None[, the charger's delivered share free])."""
    name, case, cache, charger_share = (*job, False)[:4]
    t0 = time.perf_counter()
    source = Source(name)
    plan, base, ph, day, _ = source.module.day_trace(case)
    chemistry = base.get("chemistry") or "LFP"
    log = measured_log(source, case, Path(cache) if cache else None)
    y0 = source.run(plan, base, None, {}, day)
    n = min(len(log), len(y0))
    candidates = {}
    for effect in source.effects:
        values = ph if effect == case.hidden else source.draw(effect, plan, chemistry, case.seed)
        candidates[effect] = source.run(plan, base, effect, values, day)
    sensitivities = {}
    for param in PARAMS[name]:
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
    row = {"source": name, "case": case.case_id, "hidden": case.hidden,
           "hours": case.hours, "time_s": 0.0}
    for kind, width in WINDOW_S.items():
        column, difference = SIGNAL[kind]

        def signal(run, column=column, width=width, difference=difference):
            return windows(run[column].to_numpy()[:n], width, difference)

        base_signal = signal(y0)
        y = windows(measured[kind][:n], width, difference) - base_signal
        nuisance = [base_signal, np.ones_like(base_signal)]
        if kind == "bms":  # a current offset shows as offset x V
            nuisance[1] = windows(y0["volts_v"].to_numpy()[:n], width, False)
        elif kind == "soc":  # the BMS counts charge without the cells' coulombic efficiency
            nuisance.append(windows(y0["charged_as"].to_numpy()[:n], width, True))
        floor = 1e-9 * max(np.abs(base_signal).max(), 1.0)  # a run's rounding, not a change
        moved = [signal(r) - base_signal for r in sensitivities.values()]
        basis = np.column_stack([m for m in moved if np.abs(m).max() > floor] + nuisance)
        rss_bus = float(np.sum(basis_residual(y, basis) ** 2))  # the bus's parameters alone
        fits = {}
        for effect, run in candidates.items():
            sig = signal(run) - base_signal
            if np.abs(sig).max() > floor:
                fits[effect] = fit(y, basis, sig)
        own = fits.get(case.hidden)
        # a rival is another library effect: the source's cabin heating and cooling are one
        # (the library's cabin), its loads outside the library all "no library effect"
        others = {e: f for e, f in fits.items() if library(e) != library(case.hidden)}
        # one-sided: an effect acts with a positive strength (a load draws, a force resists)
        result = {"windows": len(y), "max_other_snr": max(
            (f["snr"] for e, f in fits.items() if e != case.hidden and np.isfinite(f["snr"])),
            default=0.0)}
        if own is not None and np.isfinite(own["snr"]):
            margin = min(((f["rss"] - own["rss"]) / (own["sigma2"] * own["inflation"])
                          for f in others.values()), default=np.inf)
            result.update(snr=own["snr"], margin=float(margin),
                          fall=float(1.0 - own["rss"] / rss_bus) if rss_bus > 0 else 0.0,
                          separable=bool(own["snr"] >= SNR_MIN and margin >= SEPARATION))
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
            if smoke:
                start = case.start_clock_h + max(case.hours - SMOKE_HOURS, 0.0)
                case = replace(case, start_clock_h=round(start, 3),
                               hours=min(case.hours, SMOKE_HOURS))
            out.append(case)
    return out


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
    return {**row, EITHER: either}


def report(rows: list[dict]) -> None:
    rows = [with_either(r) for r in rows]
    print("\nThe ceiling: the hidden effect's SNR with every bus-to-bus parameter free, and the "
          "days where it is separable (SNR >= 3 and better than every candidate of another "
          "library effect)")
    print(f"  {'source':9s} {'log':8s} {'hidden effect':18s} {'days':>5s} {'separable':>10s} "
          f"{'SNR median':>11s} {'(range)':>17s}")
    for name in SOURCES:
        for kind in (*WINDOW_S, EITHER):
            part = [r for r in rows if r["source"] == name and kind in r]
            for hidden in sorted({r["hidden"] or "control" for r in part}):
                group = [r for r in part if (r["hidden"] or "control") == hidden]
                if hidden == "control":
                    alarms = sum(r[kind]["max_other_snr"] >= SNR_MIN for r in group)
                    snrs = [r[kind]["max_other_snr"] for r in group]
                    print(f"  {name:9s} {kind:8s} {'control':18s} {len(group):5d} "
                          f"{alarms:>4d} >= 3 {np.median(snrs):11.1f} "
                          f"({min(snrs):6.1f}, {max(snrs):6.1f})  (the largest candidate SNR)")
                    continue
                scored = [r[kind] for r in group if "snr" in r[kind]]
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


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", choices=SOURCES, action="append")
    parser.add_argument("--per-effect", type=int, default=None)
    parser.add_argument("--controls", type=int, default=None)
    parser.add_argument("--smoke", action="store_true",
                        help="1 day per effect and 1 control per source, the last 3 h")
    parser.add_argument("--cache", type=Path, default=None,
                        help="the bench's folder of generated days (read where there)")
    parser.add_argument("--rows", type=Path, default=None, help="write each day's row (JSON)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--charger-share", action="store_true",
                        help="free the share of its rating a charger delivers, as the "
                             "power-domain diagnosis does")
    parser.add_argument("--effect", action="append", default=[],
                        help="only the days hiding this effect (and --controls control days)")
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
        jobs += [(name, c, str(args.cache) if args.cache else None, args.charger_share)
                 for c in cases_of(source, args.smoke, per_effect, controls, tuple(args.effect))]
    rows = []
    with ProcessPoolExecutor(args.workers) as pool:
        for row in pool.map(ceiling_day, jobs):
            rows.append(row)
            print(f"  {row['source']}/{row['case']}: " + "; ".join(
                (f"{k} SNR {row[k]['snr']:.1f}" if "snr" in row[k] else f"{k} (nothing hidden)")
                + (" separable" if row[k].get("separable") else "")
                + f" (others up to {row[k]['max_other_snr']:.1f})" for k in WINDOW_S)
                + f"; {row['time_s']:.0f} s", flush=True)
            if args.rows:  # a temporary file, then renamed: a run cut short keeps its rows
                write_text(args.rows, json.dumps(rows, indent=1, default=float))
    report(rows)


if __name__ == "__main__":
    main()
