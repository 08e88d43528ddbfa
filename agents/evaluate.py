"""One evaluator, one score sheet: every policy on the same held-out days of ``EBus-v0``.

Each policy drives ``episodes`` days seeded ``HELD_OUT_SEED + i`` (training uses seeds below
it), all days at once in the native vector env. Per day it scores::

    kWh/km        energy the bus used (from its pack or straight from the charger) per km
    battery_kwh   net energy out of the pack's chemical store;  grid_kwh: from the grid
    peak_grid_kw  highest grid power over a decision (60 s mean);  load_factor = mean / peak
    comfort_kh    cabin outside the comfort band [K h];  late_min: delay at departures [min]
    reward        the env's reward, summed

and reports each as a mean with a 95 % confidence interval over the days (Student t), the
savings of each ECO feature against the baseline, and a day of SoC, grid load and setpoint
per policy.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from gymnasium.vector import AutoresetMode
from scipy import stats

from agents.policy import Policy
from agents.rules import RULES, RulePolicy
from ebus_env.envs.env_config import EnvSource
from ebus_env.envs.vector import EBusVectorEnv

if TYPE_CHECKING:
    from rich.console import Console

HELD_OUT_SEED = 10_000
METRICS = (  # key, unit, what
    ("kwh_per_km", "kWh/km", "energy used per km"),
    ("traction_kwh_per_km", "kWh/km", "traction energy per km"),
    ("hvac_kwh", "kWh", "cabin HVAC energy"),
    ("battery_kwh", "kWh", "net energy out of the battery"),
    ("grid_kwh", "kWh", "energy from the grid"),
    ("peak_grid_kw", "kW", "peak grid power (60 s mean)"),
    ("load_factor", "1", "mean / peak grid power"),
    ("comfort_kh", "K h", "comfort violation"),
    ("late_min", "min", "delay at departures"),
    ("distance_km", "km", "distance driven"),
    ("depleted", "1", "days ended with an empty battery (share)"),
    ("reward", "1", "episode reward"),
)
KEYS = [m[0] for m in METRICS]
FEATURES = ("eco_driving", "eco_comfort", "eco_charging")
OUTPUTS = ("scores.json", "scores_per_day.csv", "day.png")
"""The files :meth:`ScoreSheet.write` writes into its folder."""


@dataclass
class PolicyScores:
    """Per-day metrics of one policy (rows: days, columns: ``METRICS``) and its first day."""

    name: str
    days: np.ndarray
    day: dict[str, np.ndarray] = field(default_factory=dict)

    def mean(self, key: str) -> float:
        x = self.days[:, KEYS.index(key)]
        return float(np.mean(x[np.isfinite(x)])) if np.isfinite(x).any() else float("nan")

    def ci95(self, key: str) -> float:
        """Half-width of the 95 % confidence interval of the mean (Student t)."""
        return ci95_half_width(self.days[:, KEYS.index(key)])


def ci95_half_width(x: np.ndarray) -> float:
    """Half-width of the 95 % CI of the mean of the finite values of ``x`` (Student t)."""
    x = x[np.isfinite(x)]
    if len(x) < 2:
        return float("nan")
    return float(stats.t.ppf(0.975, len(x) - 1) * x.std(ddof=1) / np.sqrt(len(x)))


def paired_difference(a: PolicyScores, b: PolicyScores, key: str) -> tuple[float, float]:
    """Mean of ``a - b`` over the same days and the half-width of its 95 % CI (paired t):
    day-to-day variation common to both policies cancels."""
    d = a.days[:, KEYS.index(key)] - b.days[:, KEYS.index(key)]
    finite = d[np.isfinite(d)]
    return (float(finite.mean()) if len(finite) else float("nan")), ci95_half_width(d)


def run_days(policy: Policy, config: EnvSource, seeds: list[int], **overrides: Any
             ) -> PolicyScores:
    """Drive the days ``seeds`` with ``policy`` (``predict(obs)``), all at once."""
    venv = EBusVectorEnv(num_envs=len(seeds), config=config,
                         autoreset_mode=AutoresetMode.SAME_STEP, **overrides)
    n = len(seeds)
    if isinstance(policy, RulePolicy):  # a rule: for this env's bus
        policy = policy.for_env(venv)
    obs, _ = venv.reset(seed=list(seeds))
    total = {k: np.zeros(n) for k in ("distance_km", "traction", "hvac", "consumed",
                                       "battery_kwh", "grid_kwh", "comfort_kh", "late_min",
                                       "reward")}
    peak = np.zeros(n)
    depleted = np.zeros(n, bool)
    running = np.ones(n, bool)
    day: dict[str, list] = {"time_h": [], "soc": [], "grid_kw": [], "setpoint_degc": [],
                            "cabin_degc": []}
    soc, cabin = venv.observation_names.index("soc"), venv.observation_names.index(
        "cabin_temp_degc")
    elapsed_h = 0.0
    while running.any():
        actions, _ = policy.predict(obs, deterministic=True)
        obs, reward, terminated, truncated, info = venv.step(actions)
        kwh = info["breakdown_kwh"]
        add = {"distance_km": info["distance_km"], "traction": kwh["traction"],
               "hvac": kwh.get("cabin_hvac", np.zeros(n)),
               "consumed": info["battery_kwh"] + kwh["charger"],
               "battery_kwh": info["battery_kwh"], "grid_kwh": info["grid_kwh"],
               "comfort_kh": info["comfort_kh"], "late_min": info["late_min"], "reward": reward}
        for k, v in add.items():
            total[k] += np.where(running, v, 0.0)
        peak = np.where(running, np.maximum(peak, info["grid_kw"]), peak)
        depleted |= running & info["depleted"]
        if running[0]:
            last = info["final_obs"][0] if "final_obs" in info and info["_final_obs"][0] else obs[0]
            elapsed_h += info["duration_s"][0] / 3600.0
            day["time_h"].append(elapsed_h)
            day["soc"].append(float(last[soc]))
            day["grid_kw"].append(float(info["grid_kw"][0]))
            day["setpoint_degc"].append(float(info["actions"]["setpoint_degc"][0]))
            day["cabin_degc"].append(float(last[cabin]))
        running &= ~(terminated | truncated)
    distance = np.maximum(total["distance_km"], 1e-9)
    service_h = venv.config.service_h
    with np.errstate(invalid="ignore", divide="ignore"):
        load_factor = np.where(peak > 0, total["grid_kwh"] / service_h / peak, np.nan)
    columns = {"kwh_per_km": total["consumed"] / distance,
               "traction_kwh_per_km": total["traction"] / distance, "hvac_kwh": total["hvac"],
               "battery_kwh": total["battery_kwh"], "grid_kwh": total["grid_kwh"],
               "peak_grid_kw": peak, "load_factor": load_factor,
               "comfort_kh": total["comfort_kh"], "late_min": total["late_min"],
               "distance_km": total["distance_km"], "depleted": depleted.astype(float),
               "reward": total["reward"]}
    venv.close()
    return PolicyScores(getattr(policy, "name", type(policy).__name__),
                        np.column_stack([columns[k] for k in KEYS]),
                        {k: np.array(v) for k, v in day.items()})


@dataclass
class ScoreSheet:
    """Scores of several policies on the same days."""

    env: str
    seeds: list[int]
    policies: list[PolicyScores]
    service_h: float = float("nan")

    def by_name(self) -> dict[str, PolicyScores]:
        return {p.name: p for p in self.policies}

    def savings(self) -> dict[str, dict[str, float]]:
        """Per ECO feature (and all together) against the baseline: kWh/km saved, its share of
        the single features' savings, peak grid kW lowered, HVAC kWh saved."""
        p = self.by_name()
        if "baseline" not in p:
            return {}
        base = p["baseline"]
        out = {}
        for name in (*FEATURES, "eco_all"):
            if name in p:
                out[name] = {
                    "kwh_per_km_saved": base.mean("kwh_per_km") - p[name].mean("kwh_per_km"),
                    "saving_pct": 100.0 * (1.0 - p[name].mean("kwh_per_km")
                                           / base.mean("kwh_per_km")),
                    "peak_kw_lowered": base.mean("peak_grid_kw") - p[name].mean("peak_grid_kw"),
                    "hvac_kwh_saved": base.mean("hvac_kwh") - p[name].mean("hvac_kwh")}
        single = sum(max(out[f]["kwh_per_km_saved"], 0.0) for f in FEATURES if f in out)
        for f in FEATURES:
            if f in out:
                out[f]["share_of_saving_pct"] = (100.0 * max(out[f]["kwh_per_km_saved"], 0.0)
                                                 / single if single > 0 else float("nan"))
        return out

    def best_rule(self) -> PolicyScores | None:
        """The rule-based policy with the highest mean reward (None without rules)."""
        rules = [p for p in self.policies if p.name in RULES]
        return max(rules, key=lambda p: p.mean("reward")) if rules else None

    def versus_best_rule(self) -> dict[str, dict[str, str | tuple[float, float]]]:
        """Each other (learned) policy minus the best rule (its name under ``versus``) on the
        same days: (mean, 95 % CI half-width) of the paired difference, per metric (reward:
        > 0 is better)."""
        best = self.best_rule()
        if best is None:
            return {}
        return {p.name: {"versus": best.name, **{k: paired_difference(p, best, k) for k in KEYS}}
                for p in self.policies if p.name not in RULES}

    def to_dict(self) -> dict:
        versus = {name: {"versus": d["versus"], **{k: {"mean": d[k][0], "ci95": d[k][1]}
                                                   for k in KEYS}}
                  for name, d in self.versus_best_rule().items()}
        return {"env": self.env, "seeds": self.seeds,
                "metrics": {k: {"unit": u, "meaning": w} for k, u, w in METRICS},
                "policies": {p.name: {k: {"mean": p.mean(k), "ci95": p.ci95(k)} for k in KEYS}
                             for p in self.policies},
                "savings_vs_baseline": self.savings(), "versus_best_rule": versus}

    def write(self, out_dir: Path) -> list[Path]:
        """``scores.json``, ``scores_per_day.csv`` and ``day.png`` into ``out_dir``, each
        through a temporary file renamed over its target. A number that is not finite (the
        CI of one day, the load factor of a day without grid energy) is ``null`` in the JSON
        (strict JSON has no NaN) and an empty cell in the CSV."""
        import pandas as pd

        from ebus_env.outputs import atomic, write_text

        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        written = [out_dir / name for name in OUTPUTS]
        write_text(written[0], json.dumps(finite_or_null(self.to_dict()), indent=2,
                                          allow_nan=False))
        frames = [pd.DataFrame(np.where(np.isfinite(p.days), p.days, np.nan), columns=KEYS)
                  .assign(policy=p.name, seed=self.seeds) for p in self.policies]
        with atomic(written[1]) as tmp:
            pd.concat(frames).to_csv(tmp, index=False, na_rep="")
        with atomic(written[2]) as tmp:
            plot_days(self, tmp)
        return written


def finite_or_null(value: object) -> object:
    """``value`` (nested dicts, lists, tuples of numbers) with every number that is not
    finite (NaN, +-inf) as None, and numpy scalars as Python ones: JSON without NaN."""
    if isinstance(value, dict):
        return {k: finite_or_null(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_null(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def print_sheet(sheet: ScoreSheet, console: Console) -> None:
    """The score sheet as tables: each metric's mean +- 95 % CI per policy (columns), then
    the savings by ECO feature."""
    from rich.table import Table

    table = Table(title=f"{sheet.env}: {len(sheet.seeds)} held-out days (seeds "
                        f"{sheet.seeds[0]}-{sheet.seeds[-1]}), mean +- 95 % CI")
    table.add_column("metric")
    for p in sheet.policies:
        table.add_column(p.name, justify="right")
    for key, unit, _ in METRICS:
        table.add_row(f"{key} ({unit})", *(f"{p.mean(key):.4g} +- {p.ci95(key):.2g}"
                                           for p in sheet.policies))
    console.print(table)
    savings = sheet.savings()
    if savings:
        table = Table(title="Against the baseline, by ECO feature")
        for column in ("feature", "kWh/km saved", "saved (%)", "share (%)",
                       "peak lowered (kW)", "HVAC saved (kWh)"):
            table.add_column(column, justify="right")
        for name, s in savings.items():
            table.add_row(name, f"{s['kwh_per_km_saved']:.4f}", f"{s['saving_pct']:.1f}",
                          f"{s.get('share_of_saving_pct', float('nan')):.0f}",
                          f"{s['peak_kw_lowered']:.0f}", f"{s['hvac_kwh_saved']:.1f}")
        console.print(table)
        console.print("share: of the saving of the single features together", style="dim")
    versus = sheet.versus_best_rule()
    if versus:
        table = Table(title="Learned policies minus the best rule, same days (paired 95 % CI)")
        table.add_column("metric")
        for name, d in versus.items():
            table.add_column(f"{name} - {d['versus']}", justify="right")
        for key, unit, _ in METRICS:
            table.add_row(f"{key} ({unit})", *(f"{d[key][0]:+.4g} +- {d[key][1]:.2g}"
                                               for d in versus.values()))
        console.print(table)


def plot_days(sheet: ScoreSheet, path: Path) -> None:
    """SoC, grid load and setpoint over the first held-out day, one line per policy."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True, constrained_layout=True)
    for p in sheet.policies:
        t = p.day["time_h"]
        axes[0].plot(t, 100 * p.day["soc"], label=p.name)
        axes[1].plot(t, p.day["grid_kw"], label=p.name, lw=0.8)
        axes[2].plot(t, p.day["setpoint_degc"], label=p.name)
    for ax, label in zip(axes, ("SoC [%]", "grid power [kW]\n(60 s means)", "setpoint [degC]"),
                         strict=True):
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, ncol=3)
    axes[2].set_xlabel("hours into service")
    axes[0].set_title(f"{sheet.env}: held-out day seed {sheet.seeds[0]}")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def evaluate(policies: list[Policy], config: EnvSource, episodes: int = 20,
             seed: int = HELD_OUT_SEED, **overrides: Any) -> ScoreSheet:
    """Every policy on the same ``episodes`` held-out days."""
    seeds = [seed + i for i in range(episodes)]
    scores = [run_days(p, config, seeds, **overrides) for p in policies]
    names = [s.name for s in scores]
    if len(set(names)) != len(names):
        raise ValueError(f"Two policies have the same name: {names}.")
    from ebus_env.envs.common import EnvConfig

    return ScoreSheet(str(config), seeds, scores, EnvConfig.load(config, **overrides).service_h)


def env_files(env: EnvSource, overrides: dict[str, Any]) -> list[Path | None]:
    """Files an env config reads that an output could overwrite: its YAML and a measured log
    (None where there is none)."""
    return [Path(str(env)) if Path(str(env)).suffix else None,
            overrides.get("log") if isinstance(overrides.get("log"), str | Path) else None]


@dataclass
class Evaluation:
    """What :func:`evaluate_policies` scored and wrote: the score sheet and its files."""

    sheet: ScoreSheet
    written: list[Path]


def evaluate_policies(policies: list[str], env: str | Path = "sort2_day", episodes: int = 20,
                      out: str | Path = "runs/evaluate", threads: int = 1,
                      **overrides: Any) -> Evaluation:
    """Score policies on the same held-out days and write the sheet (``ebus evaluate``).

    Parameters
    ----------
    policies
        ``rule:NAME`` (baseline, eco_driving, eco_comfort, eco_charging, eco_all),
        ``ppo:PATH`` or ``ppo:default`` (the shipped agent).
    env
        Env config: a name in ``configs/env`` or a YAML path.
    episodes
        Held-out days (seeds ``HELD_OUT_SEED``, ``HELD_OUT_SEED + 1``, ...).
    out
        Folder for ``scores.json``, ``scores_per_day.csv`` and ``day.png``; refused before
        the run when it is a file or a file there is an input.
    threads
        Torch threads for a PPO policy's network.
    **overrides
        Env config keys to override (``log="day.csv"``).

    Returns
    -------
    Evaluation
        The :class:`ScoreSheet` and the files written.
    """
    from agents.ppo import load_policy
    from ebus_env.errors import ConfigError
    from ebus_env.outputs import output_folder, refuse_overwriting

    if episodes < 1:
        raise ConfigError(f"--episodes {episodes}: needs at least 1 held-out day.")
    folder = output_folder(Path(out), "--out")
    policy_files = [Path(spec.partition(":")[2]) for spec in policies
                    if spec.startswith("ppo:") and spec != "ppo:default"]
    refuse_overwriting(folder, "--out", OUTPUTS, env_files(env, overrides) + policy_files)
    sheet = evaluate([load_policy(spec, threads) for spec in policies], env, episodes=episodes,
                     **overrides)
    return Evaluation(sheet, sheet.write(folder))
