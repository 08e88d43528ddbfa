"""Fit a model to measured SoC: offline iSOPT or windowed (online) tuning, then say how well
each parameter is determined, and how well the fit holds on calibration and validation data."""

from __future__ import annotations

import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING

import numpy as np

from ebus_env.calibration.isopt import History, ISOPTSettings, Progress, isopt
from ebus_env.calibration.local import distinct_starts, polish
from ebus_env.calibration.metrics import soc_fit
from ebus_env.calibration.problem import Blocks, CalibrationProblem, logs_current, require_soc
from ebus_env.profile import Profile
from ebus_env.units import shown_unit

if TYPE_CHECKING:
    from ebus_env.calibration.windowed import WindowSettings
    from ebus_env.model.model import Model

PlotTarget = str | os.PathLike[str] | IO[bytes]
"""Where a plot goes: a path, or a binary file object (PNG)."""

NEAR_REL = 0.10
"""Parameter values whose fit is within this fraction of the best NRMSE (plus ``NEAR_ABS``)
count as "as good": their spread is how well the data determines a parameter."""
NEAR_ABS = 5e-4
EDGE = 0.01
"""A fitted value within this fraction of its search range from an end of it sits at that end."""
RANGE_END = {"lower": "lower: the data want less", "upper": "upper: the data want more"}
"""How a value the data press against an end of its range reads in a report's table."""
NOISE_MULTIPLE = 2.0
"""A fit more than this many times the log's own noise floor is not at the truth: either a
better fit exists that no search found, or the model lacks an effect. No parameter is then
reported as well determined."""


@dataclass
class Determinacy:
    """How well the data pins a parameter down.

    From the Jacobian J of the SoC residuals at the optimum, the parameters whose NRMSE is
    within NEAR_REL of the best form the ellipsoid du' J'J du <= q; its extent along the
    parameter (all others free to follow) is ``half_width`` (normalised to the bounds).
    ``partners`` are the parameters it trades off against (correlation above 0.9).
    """

    status: str  # "well determined", "weakly determined", "not determined"
    low: float
    high: float
    half_width: float
    partners: list[str]
    grid: list[float]
    cost: list[float]

    def pressing(self, value: float) -> str | None:
        """"lower" or "upper" when ``value`` sits at that end of the range searched and the
        fit along the parameter (the others held) is worse one grid step inward than there by
        more than "as good" (NEAR_REL, NEAR_ABS). A flat profile (a CV threshold never
        reached) presses on nothing."""
        if len(self.grid) < 2 or not self.grid[-1] > self.grid[0]:
            return None
        u = (value - self.grid[0]) / (self.grid[-1] - self.grid[0])
        side = "lower" if u <= EDGE else "upper" if u >= 1.0 - EDGE else None
        if side is None:
            return None
        edge, inward = (self.cost[0], self.cost[1]) if side == "lower" else \
            (self.cost[-1], self.cost[-2])
        return side if inward > np.hypot(edge * (1.0 + NEAR_REL), NEAR_ABS) else None


@dataclass
class CalibrationResult:
    """Fitted values, how well determined each is, and the fit on calibration and validation."""

    model_name: str
    free: list[str]
    values: dict[str, float]
    bounds: dict[str, tuple[float, float]]
    units: dict[str, str]
    cost: float
    fit: dict
    validation: dict | None
    determinacy: dict[str, Determinacy]
    history: History
    evaluations: int
    simulated_steps: int
    wall_time_s: float
    interrupted: bool = False
    method: str = "iSOPT"
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    windows: list[dict] = field(default_factory=list)
    curves: dict = field(default_factory=dict)  # for plotting: label -> (t_h, sim, meas)
    timings: dict = field(default_factory=dict)  # search_s, polish_s, determinacy_s
    admissible: dict = field(default_factory=dict)  # name -> the effect's declared bounds
    fixed: dict = field(default_factory=dict)  # name -> a known value held in the fit

    def pressing(self) -> dict[str, str]:
        """The free parameters the data press against an end of the range searched ("lower"
        or "upper", see :meth:`Determinacy.pressing`) where that end is narrower than the
        parameter's admissible range (a bus config's bounds, a bus-to-bus search range, a
        user's range): the data want a value the search did not allow. Such a value stands in
        for more than its own parameter: the bus lies outside the range (widen it, a
        calibration config's ``ranges``), or the model lacks an effect whose power this
        parameter takes up. An end that is the admissible one (a bus without RC dynamics at
        ``rcd_frac`` = 0) is where the value may well be."""
        out = {}
        for name, d in self.determinacy.items():
            side = d.pressing(self.values[name])
            if side is None:
                continue
            end = int(side == "upper")
            if self.bounds[name][end] != self.admissible.get(name, (None, None))[end]:
                out[name] = side
        return out

    def overlay(self) -> dict:
        """A bus-config overlay with the fitted values and the known values held in the fit
        (``ebus simulate --overlay``): with it, the bus is the one calibrated."""
        params: dict[str, dict[str, float]] = {}
        for name, value in {**self.fixed, **self.values}.items():
            effect, param = name.split(".", 1)
            params.setdefault(effect, {})[param] = round(float(value), 6)
        note = {"method": self.method, "nrmse": round(self.fit["nrmse"], 5),
                "evaluations": self.evaluations,
                "not_determined": [p for p, d in self.determinacy.items()
                                   if d.status == "not determined"]}
        if self.validation:
            note["validation_nrmse"] = round(self.validation["nrmse"], 5)
        return {"params": params, "calibration": note}

    def write_overlay(self, path: str | Path, command: str | None = None) -> None:
        """Write :meth:`overlay` as YAML, headed by ``command``, the one that simulates the
        calibrated bus (the bus, its added and removed effects, this file)."""
        import yaml

        command = command or f"ebus simulate --bus <bus> --overlay {Path(path).name}"
        text = (f"# Calibrated on {self.model_name} by ebus calibrate ({self.method}). Merge with\n"
                f"#   {command}\n")
        Path(path).write_text(text + yaml.safe_dump(self.overlay(), sort_keys=False))

    def to_json(self) -> dict:
        out = {
            "params": self.values,
            "units": self.units,
            "bounds": {k: list(v) for k, v in self.bounds.items()},
            "determinacy": {k: {"status": d.status, "low": d.low, "high": d.high,
                                "half_width": d.half_width, "trades_off_with": d.partners}
                            for k, d in self.determinacy.items()},
            "at_range_end": self.pressing(),
            "cost": self.cost,
            **{k: v for k, v in self.fit.items()},
            "validation": self.validation,
            "wall_time_s": self.wall_time_s,
            "timings_s": self.timings,
            "evaluations": self.evaluations,
            "simulated_steps": self.simulated_steps,
            "method": self.method,
            "interrupted": self.interrupted,
            "history": {"best_cost": self.history.best_cost,
                        "evaluations": self.history.evaluations,
                        "escapes": self.history.escapes},
            "notes": self.notes,
            "warnings": self.warnings,
        }
        if self.windows:
            out["windows"] = self.windows
        return out

    def plot(self, path: PlotTarget) -> None:
        """Simulated vs measured SoC with the residual, calibration and validation (to a path
        or a binary file object, PNG)."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        labels = list(self.curves)
        fig, axes = plt.subplots(2, len(labels), figsize=(6.5 * len(labels), 6), sharex="col",
                                 squeeze=False, constrained_layout=True)
        for j, label in enumerate(labels):
            t_h, sim, meas = self.curves[label]
            axes[0, j].plot(t_h, 100 * meas, "k.", ms=1.5, label="measured")
            axes[0, j].plot(t_h, 100 * sim, color="C0", lw=1.0, label="calibrated model")
            axes[0, j].set_title(label)
            axes[0, j].set_ylabel("SoC [%]")
            axes[0, j].legend(fontsize=8)
            axes[1, j].plot(t_h, 100 * (sim - meas), color="C3", lw=0.8)
            axes[1, j].axhline(0, color="0.5", lw=0.5)
            axes[1, j].set_ylabel("model - measured [%-pts]")
            axes[1, j].set_xlabel("time [h]")
            for ax in axes[:, j]:
                ax.grid(alpha=0.3)
        fig.savefig(path, dpi=110, format="png")
        plt.close(fig)

    def plot_determinacy(self, path: PlotTarget) -> None:
        """Cost along each parameter through the optimum, with the range that fits within
        10 % of the best shaded: a flat curve is a parameter the data does not determine."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        names = [n for n in self.free if n in self.determinacy]
        cols = min(4, len(names))
        rows = -(-len(names) // cols)
        fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 2.8 * rows), squeeze=False,
                                 constrained_layout=True)
        for ax, name in zip(axes.ravel(), names, strict=False):
            d = self.determinacy[name]
            ax.axvspan(d.low, d.high, color="C2", alpha=0.2)
            ax.plot(d.grid, d.cost, "-o", ms=3)
            ax.axvline(self.values[name], color="k", lw=0.8)
            ax.set_yscale("log")
            ax.set_title(f"{name}\n{d.status}", fontsize=8)
            ax.set_xlabel(shown_unit(self.units[name]), fontsize=8)
        for ax in axes.ravel()[len(names):]:
            ax.axis("off")
        fig.savefig(path, dpi=100, format="png")
        plt.close(fig)

    def plot_history(self, path: str | Path) -> None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 3.5), constrained_layout=True)
        ax.semilogy(self.history.evaluations, self.history.best_cost, "-o", ms=2)
        for it in self.history.escapes:
            ax.axvline(self.history.evaluations[it], color="0.7", lw=0.5)
        ax.set_xlabel("evaluations")
        ax.set_ylabel("best cost")
        ax.set_title(f"{self.method} convergence (grey: escapes)")
        ax.grid(alpha=0.3, which="both")
        fig.savefig(path, dpi=110)
        plt.close(fig)


def determinacy(problem: CalibrationProblem, u_best: np.ndarray, cost_best: float,
                jacobian: np.ndarray, others: np.ndarray | None = None,
                points: int = 9) -> dict[str, Determinacy]:
    """How well each free parameter is determined (see :class:`Determinacy`), with the cost
    along each parameter through the optimum for the report (one batched evaluation).
    ``others`` are other local optima as good as the best (within NEAR_REL): the spread to
    them counts too, so a second valley that fits as well is not hidden."""
    grid = np.linspace(0.0, 1.0, points)
    u = np.tile(u_best, (len(problem.free) * points, 1))
    for i in range(len(problem.free)):
        u[i * points:(i + 1) * points, i] = grid
    costs = problem.cost(u).reshape(len(problem.free), points)
    q = cost_best**2 * ((1 + NEAR_REL) ** 2 - 1) + NEAR_ABS**2
    info = jacobian.T @ jacobian
    eigval, eigvec = np.linalg.eigh(info)
    floor = max(eigval.max(), 1e-300) * 1e-12
    cov = (eigvec / np.maximum(eigval, floor)) @ eigvec.T  # pseudo-inverse of J'J
    widths = np.sqrt(np.maximum(q * np.diag(cov), 0.0))
    if others is not None and len(others):
        widths = np.maximum(widths, np.max(np.abs(others - u_best), axis=0))
    sd = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    corr = cov / np.outer(sd, sd)
    best = problem.values(u_best[None])[0]
    out = {}
    for i, name in enumerate(problem.free):
        span = problem.high[i] - problem.low[i]
        half = float(widths[i])
        if half > 0.35:
            status = "not determined"
        elif half > 0.10:
            status = "weakly determined"
        else:
            status = "well determined"
        partners = [problem.free[j] for j in np.argsort(-np.abs(corr[i]))
                    if j != i and abs(corr[i, j]) > 0.9]
        out[name] = Determinacy(
            status, float(max(problem.low[i], best[i] - half * span)),
            float(min(problem.high[i], best[i] + half * span)), half, partners,
            (problem.low[i] + grid * span).tolist(), costs[i].tolist())
    return out


def evaluate_fit(model: Model, profiles: Sequence[Profile], params: np.ndarray,
                 blocks: Blocks | None = None, charge: bool = False) -> tuple[dict, dict]:
    """Fit statistics of a parameter vector on profiles (each from its measured first SoC, or
    scored on ``blocks``), and the curves for plotting; with ``charge``, also the NRMSE of the
    charge the logged current counts and the fit's cost on the same terms (:func:`with_charge`)."""
    if blocks is not None:
        return _evaluate_blocks(model, profiles, params, blocks, charge)
    sims, meas, times = [], [], []
    sim_energy = meas_energy = limited_s = 0.0
    have_power = True
    offset = 0.0
    for p in profiles:
        soc = p.measured["soc_frac"]
        rows = p.sample_rows("soc_frac")
        rows = rows[np.isfinite(soc[rows])]
        result = model.simulate(p, params, soc_start=float(soc[rows[0]]))
        limited_s += result.summary()["battery_limited_s"]
        sims.append(result.trace("soc_frac")[rows])
        meas.append(soc[rows])
        times.append((offset + rows * p.dt_s) / 3600.0)
        offset += p.duration_s
        current, voltage = p.measured.get("battery_current_a"), p.measured.get("battery_voltage_v")
        if current is not None and voltage is not None and np.all(np.isfinite(current * voltage)):
            # energy drawn from the pack (discharge only), so charging does not cancel it
            meas_energy += float(np.sum(np.maximum(current * voltage, 0.0))) * p.dt_s
            sim_energy += float(np.sum(np.maximum(result.trace("battery_power_w"), 0.0))) * p.dt_s
        else:
            have_power = False
    sim, mea = np.concatenate(sims), np.concatenate(meas)
    fit = soc_fit(sim, mea)
    # the log's speed replayed: seconds in which the model's pack could not give the power
    # the logged speed needs (its voltage floor, an empty pack), so the model fell behind
    fit["battery_limited_s"] = limited_s
    if have_power and abs(meas_energy) > 0:
        fit["energy_error_pct"] = 100.0 * (sim_energy - meas_energy) / abs(meas_energy)
        fit["energy_error_basis"] = "energy drawn, from battery current x voltage"
    else:
        used_sim = sum(s[0] - s[-1] for s in sims)
        used_meas = sum(m[0] - m[-1] for m in meas)
        fit["energy_error_pct"] = 100.0 * (used_sim - used_meas) / abs(used_meas) \
            if used_meas else float("nan")
        fit["energy_error_basis"] = "SoC used (no current/voltage in the log)"
    if charge:
        with_charge(fit, CalibrationProblem(model, profiles, [model.param_names[0]], chunks=1,
                                            charge=True), sims, params)
    return fit, {"t_h": np.concatenate(times), "sim": sim, "meas": mea}


def with_charge(fit: dict, problem: CalibrationProblem, sims: list[np.ndarray],
                params: np.ndarray) -> None:
    """Add to SoC ``fit`` statistics the NRMSE of the counted charge (``charge_nrmse``) and
    ``cost``, sqrt((NRMSE^2 + NRMSE_Q^2) / 2): the error a calibration that fits the charge
    minimises, and the one to compare two such fits by (:meth:`CalibrationProblem.fit_cost`)."""
    fit["charge_nrmse"] = problem.charge_nrmse(sims, params)
    fit["cost"] = float(np.hypot(fit["nrmse"], fit["charge_nrmse"]) / np.sqrt(2.0))


def _evaluate_blocks(model: Model, profiles: Sequence[Profile], params: np.ndarray, blocks: Blocks,
                     charge: bool = False) -> tuple[dict, dict]:
    """SoC fit statistics on the scored blocks (the SoC restarting at each block)."""
    problem = CalibrationProblem(model, profiles, [model.param_names[0]], chunks=1,
                                 blocks=blocks, charge=charge)
    sims, meas, times = [], [], []
    offset = 0.0
    for d in problem.data:
        sims.append(problem.simulate(d, params[None, :])[0])
        meas.append(d.measured)
        times.append((offset + d.rows * d.profile.dt_s) / 3600.0)
        offset += d.profile.duration_s
    fit = soc_fit(np.concatenate(sims), np.concatenate(meas))
    if charge:
        with_charge(fit, problem, sims, params)
    return fit, {"t_h": np.concatenate(times), "sim": np.concatenate(sims),
                 "meas": np.concatenate(meas)}


def calibrate(model: Model, profiles: Sequence[Profile], free: Sequence[str] | None = None,
              bounds: Mapping[str, Sequence[float]] | None = None,
              fixed: Mapping[str, float] | None = None, settings: ISOPTSettings | None = None,
              validate: Sequence[Profile] | None = None, windowed: bool = False,
              categorical_load: bool = False, chunks: int = 8,
              progress: Progress | None = None,
              window_settings: WindowSettings | None = None, polish_starts: int | None = None,
              start: Sequence[Mapping[str, float]] = (), blocks: Blocks | None = None,
              validate_blocks: Blocks | None = None, charge: bool = False) -> CalibrationResult:
    """Fit the free parameters of ``model`` to the measured SoC of ``profiles``.

    Offline: one iSOPT run over the whole data (the population evaluated in one batched call of
    the compiled core per phase), then a Levenberg-Marquardt polish from the ``polish_starts``
    best distinct points it found (default 4; 0 for none); the points in ``start`` (values by
    name, the model's own for the free parameters one omits) join the initial population
    (windowed, the first of them warm-starts the tuning: no global search).
    ``blocks`` and ``validate_blocks`` score only some blocks of the profiles (see
    :class:`~ebus_env.calibration.problem.Blocks`); ``charge`` fits the charge counted from
    the logged pack current too (see :class:`~ebus_env.calibration.problem.CalibrationProblem`).
    Windowed: see :mod:`ebus_env.calibration.windowed` (no polish by default: it would cost
    full-day runs).
    Then the Jacobian and the other local optima tell how well the data determines each
    parameter, and the fitted model is scored on the calibration and ``validate`` profiles.
    """
    t0 = time.perf_counter()
    for profile in validate or ():  # before the search, not after it
        require_soc(profile, "a validation log is scored on it")
    settings = settings or ISOPTSettings()
    problem = CalibrationProblem(model, profiles, free, bounds, fixed, categorical_load, chunks,
                                 blocks=blocks, charge=charge)
    windows: list[dict] = []
    # the starting values (the model's own, clipped to the box) are a candidate like any
    # other: the search starts from them and the result never ends worse than they do
    start_u = problem.points([{}])[0]
    start_cost = float(problem.cost(start_u[None])[0])
    if windowed:
        from ebus_env.calibration.windowed import tune_windowed

        # windowed: the first point of ``start`` warm-starts every window (a bus's last fit)
        best_u, best_cost, history, evaluations, interrupted, windows = tune_windowed(
            problem, settings, window_settings, progress,
            start_u=problem.points([start[0]])[0] if start else None)
        method = "iSOPT, windowed"
    else:
        seeds = problem.points([{}, *start])
        run = isopt(problem.cost, len(problem.free), settings, callback=progress,
                    population=seeds)
        best_u, best_cost, history = run.x, run.cost, run.history
        evaluations, interrupted = run.evaluations, run.interrupted
        method = "iSOPT"
    timings = {"search_s": time.perf_counter() - t0}
    search_evaluations = evaluations
    if polish_starts is None:
        polish_starts = 0 if windowed else 4
    det = {}
    kept_start = False
    evaluations_before_polish = problem.evaluations
    if windowed:
        best_cost = float(problem.cost(best_u[None])[0])  # the windows scored part of the data
    if not interrupted:
        x_all, c_all = history.all_evaluated()
        starts = distinct_starts(np.vstack([best_u, x_all]), np.concatenate([[best_cost], c_all]),
                                 k=max(1, polish_starts))
        # the starting values are polished too: a local step from them may be all it takes
        points, _, jacobians = polish(problem, np.vstack([starts, start_u]),
                                      iterations=12 if polish_starts else 0)
        costs = problem.cost(points)  # with penalties
        i = int(np.argmin(costs))
        if costs[i] < best_cost:
            best_u, best_cost = points[i], float(costs[i])
            method += " + least-squares polish"
        if start_cost <= best_cost:
            kept_start = True
            points = np.vstack([points, start_u])
            costs = np.append(costs, start_cost)
            jacobians = np.concatenate([jacobians, polish(problem, start_u[None], 0)[2]])
            i, best_u, best_cost = len(points) - 1, start_u, start_cost
            method += ", starting values kept"
        evaluations = search_evaluations + problem.evaluations - evaluations_before_polish
        timings["polish_s"] = time.perf_counter() - t0 - timings["search_s"]
        near = (costs <= best_cost * (1 + NEAR_REL) + NEAR_ABS) & (np.arange(len(costs)) != i)
        det = determinacy(problem, best_u, best_cost, jacobians[i], points[near])
        floor = problem.noise_nrmse()
        if best_cost > NOISE_MULTIPLE * floor:
            for d in det.values():
                if d.status == "well determined":
                    d.status = "weakly determined"
            problem.warnings.append(
                f"the best fit (NRMSE {best_cost:.4f}) is {best_cost / max(floor, 1e-12):.0f} "
                f"times the log's noise floor ({floor:.4f}): a better fit may exist, or the "
                "model lacks an effect, so no parameter is reported as well determined")
    elif start_cost < best_cost:
        kept_start, best_u, best_cost = True, start_u, start_cost
    tuning_s = time.perf_counter() - t0
    timings["determinacy_s"] = tuning_s - sum(timings.values())
    tuning_s -= timings["determinacy_s"]  # the report's extra runs are not tuning
    params = problem.params(best_u)[0]
    fit, curve = evaluate_fit(model, profiles, params, blocks, charge)
    curves = {"calibration": (curve["t_h"], curve["sim"], curve["meas"])}
    validation = None
    if validate:
        validation, vcurve = evaluate_fit(model, validate, params, validate_blocks,
                                          charge and all(map(logs_current, validate)))
        curves["validation"] = (vcurve["t_h"], vcurve["sim"], vcurve["meas"])
    notes = list(problem.notes)
    if interrupted:
        notes.append("interrupted: this is the best point found before the interruption")
    if kept_start:
        notes.append(f"no candidate fitted better than the starting values (NRMSE "
                     f"{start_cost:.4f}): they are kept")
    return CalibrationResult(
        model_name=model.name, free=problem.free, values=problem.named(best_u),
        bounds={p: (float(lo), float(hi)) for p, lo, hi in zip(problem.free, problem.low,
                                                                problem.high, strict=True)},
        units={p: model.param_info(p).unit for p in problem.free}, cost=float(best_cost),
        fit=fit, validation=validation, determinacy=det, history=history,
        evaluations=evaluations, simulated_steps=problem.simulated_steps,
        wall_time_s=tuning_s, interrupted=interrupted, method=method, notes=notes,
        warnings=list(problem.warnings), windows=windows, curves=curves, timings=timings,
        admissible={p: tuple(map(float, model.param_info(p).bounds)) for p in problem.free},
        fixed={p: float(v) for p, v in (fixed or {}).items() if p not in problem.free})
