"""A study's summary: one row per scenario (means over the days), the Pareto front of cost per
km against site peak power, the figures and the HTML report."""

from __future__ import annotations

import base64
from pathlib import Path

import numpy as np
import pandas as pd

from ebus_env.html_report import Figure, Section, Table, write_report
from ebus_env.outputs import atomic

COST_PARTS = ("energy", "demand", "chargers", "battery_wear")
MEANS = ("cost_per_km", *(f"cost_{p}_per_km" for p in COST_PARTS), "kwh_per_km", "grid_kwh",
         "site_peak_kw", "site_peak_15min_kw", "service_hours_lost", "charger_utilisation",
         "charger_wait_bus_h", "depot_utilisation", "distance_km")
COLUMNS = (  # column, heading, digits
    ("scenario", "scenario", None), ("cost_per_km", "cost/km", 3),
    ("cost_energy_per_km", "energy", 3), ("cost_demand_per_km", "demand", 3),
    ("cost_chargers_per_km", "chargers", 3), ("cost_battery_wear_per_km", "battery wear", 3),
    ("kwh_per_km", "grid kWh/km", 3), ("site_peak_kw", "site peak kW", 0),
    ("site_peak_15min_kw", "15-min peak kW", 0), ("lowest_soc_pct", "lowest SoC %", 1),
    ("buses_short", "buses short", 0), ("service_hours_lost", "service h lost", 2),
    ("charger_utilisation", "charger use", 2), ("charger_wait_bus_h", "wait bus-h", 2),
    ("feasible", "feasible", None), ("pareto", "Pareto", None))


def summarise(rows: pd.DataFrame) -> pd.DataFrame:
    """One row per scenario: the days' means (the worst day for SoC and feasibility), whether
    every day was feasible (no bus ran short, every bus recharged at the depot), and whether the
    scenario is on the Pareto front of mean cost per km against mean site peak kW among the
    feasible ones; sorted by cost per km."""
    group = rows.groupby("scenario", sort=False)
    out = group[list(MEANS)].mean()
    out["lowest_soc_pct"] = group["lowest_soc_pct"].min()
    out["buses_short"] = group["buses_short"].max()
    out["buses_not_recharged"] = group["buses_not_recharged"].max()
    out["days"] = group.size()
    for key in ("infrastructure", "strategy", "terminal_chargers", "terminal_charger_kw",
                "depot_chargers", "depot_charger_kw", "site_limit_kw"):
        out[key] = group[key].first()
    out["feasible"] = (out["buses_short"] == 0) & (out["buses_not_recharged"] == 0)
    out["pareto"] = pareto_front(out["cost_per_km"].to_numpy(), out["site_peak_kw"].to_numpy(),
                                 out["feasible"].to_numpy())
    return out.reset_index().sort_values("cost_per_km", ignore_index=True)


def pareto_front(cost: np.ndarray, peak: np.ndarray, eligible: np.ndarray) -> np.ndarray:
    """True where an eligible point has no other eligible point at most as costly and as
    peaky and better in one of the two."""
    front = np.zeros(len(cost), bool)
    for i in np.flatnonzero(eligible):
        others = eligible & (np.arange(len(cost)) != i)
        dominated = others & (cost <= cost[i]) & (peak <= peak[i]) & (
            (cost < cost[i]) | (peak < peak[i]))
        front[i] = not dominated.any()
    return front


def table_rows(summary: pd.DataFrame) -> list[list[str]]:
    """The summary as formatted cells (COLUMNS)."""
    def cell(value, digits):
        if digits is None:
            return "yes" if value is True or value is np.True_ else \
                "no" if value is False or value is np.False_ else str(value)
        return f"{value:.{digits}f}"
    return [[cell(r[c], d) for c, _, d in COLUMNS] for _, r in summary.iterrows()]


def _figures(rows: pd.DataFrame, summary: pd.DataFrame, currency: str) -> list[Figure]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figures = []
    fig, ax = plt.subplots(figsize=(8, 5), constrained_layout=True)
    for strategy, part in summary.groupby("strategy", sort=False):
        ok = part["feasible"]
        line = ax.scatter(part.loc[ok, "site_peak_kw"], part.loc[ok, "cost_per_km"], label=strategy)
        ax.scatter(part.loc[~ok, "site_peak_kw"], part.loc[~ok, "cost_per_km"], marker="x",
                   color=line.get_facecolor()[0], label=f"{strategy} (infeasible)" if (~ok).any()
                   else None)
    front = summary[summary["pareto"]].sort_values("site_peak_kw")
    ax.plot(front["site_peak_kw"], front["cost_per_km"], "k--", lw=1, label="Pareto front")
    for _, r in front.iterrows():
        ax.annotate(r["infrastructure"], (r["site_peak_kw"], r["cost_per_km"]), fontsize=7,
                    xytext=(4, 4), textcoords="offset points")
    ax.set(xlabel="site peak power [kW] (mean over days)", ylabel=f"cost [{currency}/km]",
           title="Cost per km against site peak power")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    figures.append(Figure.of(fig, "pareto", "Pareto front of cost per km against site peak kW"))

    fig, ax = plt.subplots(figsize=(9, 0.35 * len(summary) + 1.5), constrained_layout=True)
    left = np.zeros(len(summary))
    for part in COST_PARTS:
        values = summary[f"cost_{part}_per_km"].to_numpy()
        ax.barh(summary["scenario"], values, left=left, label=part.replace("_", " "))
        left += values
    ax.invert_yaxis()
    ax.set(xlabel=f"cost [{currency}/km]", title="Cost per km by part")
    ax.tick_params(axis="y", labelsize=7)
    ax.legend(fontsize=8)
    figures.append(Figure.of(fig, "cost_split", "cost per km split by part"))

    fig, ax = plt.subplots(figsize=(9, 4.5), constrained_layout=True)
    shown = list(front["scenario"]) or list(summary["scenario"][:3])
    for name in shown:
        curves = rows.loc[rows["scenario"] == name, "site_load_kw"]
        mean = np.mean(np.stack(curves.to_numpy()), axis=0)
        step_h = rows.loc[rows["scenario"] == name, "load_step_s"].iloc[0] / 3600.0
        ax.plot(np.arange(len(mean)) * step_h, mean, lw=0.8, label=name)
    ax.set(xlabel="hours from the start of service", ylabel="site grid power [kW]",
           title="Site load (mean over days): the Pareto scenarios")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    figures.append(Figure.of(fig, "site_load", "site load curves"))

    fig, ax = plt.subplots(figsize=(9, 0.35 * len(summary) + 1.5), constrained_layout=True)
    ax.barh(summary["scenario"], summary["charger_utilisation"], label="terminal chargers")
    ax.barh(summary["scenario"], summary["depot_utilisation"], height=0.4, label="depot chargers")
    ax.invert_yaxis()
    ax.set(xlabel="share of the time a plug is in use", xlim=(0, 1),
           title="Charger utilisation")
    ax.tick_params(axis="y", labelsize=7)
    ax.legend(fontsize=8)
    figures.append(Figure.of(fig, "utilisation", "charger utilisation"))
    return figures


def write_summary(spec, rows: pd.DataFrame, out: str | Path) -> pd.DataFrame:
    """Write ``summary.csv``, ``report.html`` and its figures (``pareto.png``,
    ``cost_split.png``, ``site_load.png``, ``utilisation.png``) into ``out``; return the
    summary."""
    out = Path(out)
    summary = summarise(rows)
    with atomic(out / "summary.csv") as tmp:
        summary.to_csv(tmp, index=False, float_format="%.6g")
    currency = spec.costs.currency
    figures = _figures(rows, summary, currency)
    for figure in figures:  # also as files, for slides and docs
        with atomic(out / f"{figure.name}.png") as tmp:
            tmp.write_bytes(base64.b64decode(figure.png))
    pareto, cost, load, use = figures
    best = summary[summary["feasible"]]
    verdict = (f"Cheapest feasible: {best.iloc[0]['scenario']} at "
               f"{best.iloc[0]['cost_per_km']:.3f} {currency}/km, site peak "
               f"{best.iloc[0]['site_peak_kw']:.0f} kW." if len(best) else
               "No scenario is feasible on every day: see buses short and recharging.")
    header = [h for _, h, _ in COLUMNS]
    sections = [
        Section("Scenarios, cheapest first", f"Costs in {currency} per km, means over "
                f"{spec.days.count} day(s); lowest SoC and buses short are the worst day's.",
                [Table(header, table_rows(summary))]),
        Section("Pareto front: cost per km against site peak power", "Feasible scenarios that "
                "no other feasible scenario beats on both cost and peak.", figures=[pareto]),
        Section("Cost split", figures=[cost]),
        Section("Site load curves", figures=[load]),
        Section("Charger utilisation", figures=[use])]
    if spec.gtfs is not None:
        sections += timetable_sections(spec, rows, summary, currency)
    lines = "; ".join(f"{ln.name}: {ln.buses} buses" for ln in spec.lines) or \
        f"GTFS {Path(spec.gtfs.feed).name} on {spec.gtfs.date}"
    write_report(
        out / "report.html", f"Fleet study: {spec.name}", sections, verdict=verdict,
        verdict_found=bool(len(best)),
        ran=f"ebus study {spec.source}: {len(summary)} scenario(s) x {spec.days.count} day(s); "
            f"{lines}",
        settings={"climate": f"{spec.climate['place']}, month {spec.climate['month']}"
                  if spec.climate else "the lines' own ambient",
                  "days": f"{spec.days.count} from seed {spec.days.seed}",
                  "options": len(spec.infrastructure), "strategies": len(spec.strategies),
                  "currency": currency},
        how_to_read="each scenario is one charging option (T: terminal chargers, D: depot "
                    "chargers, count x kW; L: the site's grid limit) run with one strategy; "
                    "cost per km adds energy (hourly prices), the demand charge on the 15-min "
                    "peak, annuitised charger capex and battery wear (throughput over cycle "
                    "life); a scenario is feasible when no bus ran empty and the depot "
                    "recharged every bus overnight; per-day rows are in rows/*.parquet")
    return summary


BLOCK_COLUMNS = (("block", "block"), ("trips", "trips"), ("km", "km"), ("kwh", "pack kWh"),
                 ("lowest_soc_pct", "lowest SoC %"), ("lowest_at", "at"),
                 ("lowest_where", "where"), ("empty_at", "empty at"),
                 ("not_served", "trips not served"), ("depot_need_kwh", "depot need kWh"),
                 ("depot_got_kwh", "depot gave kWh"), ("needs", "needs"))


def timetable_sections(spec, rows: pd.DataFrame, summary: pd.DataFrame, currency: str
                       ) -> list[Section]:
    """A timetable study's own sections: what was read (and repaired), every block of the
    chosen scenario (the cheapest feasible, else the cheapest), what the failing blocks need,
    and the depot's load over the day under each depot plan of that option."""
    import json

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ebus_env.study.network import network_study

    network = network_study(spec).network
    ok = summary[summary["feasible"]]
    chosen = (ok if len(ok) else summary).iloc[0]
    mine = rows[(rows["scenario"] == chosen["scenario"]) & (rows["day"] == rows["day"].min())]
    blocks = json.loads(mine["block_results"].iloc[0])
    needs: dict[str, list[str]] = {}
    for b in blocks:
        if b["needs"]:
            needs.setdefault(b["needs"], []).append(b["block"])
    table = [[", ".join(b[c]) if isinstance(b[c], list) else str(b[c]) for c, _ in
              BLOCK_COLUMNS] for b in blocks]
    read = [f"{len(network.blocks)} blocks, {network.trips} trips on {network.date}; blocks from "
            f"{network.scheduled}."] + network.notes
    if network.not_driven:
        read.append("Not driven: " + "; ".join(f"{k}: {v}" for k, v in
                                                 network.not_driven.items()))
    if network.trips_not_served:
        read.append(f"{len(network.trips_not_served)} trip(s) of the feed not served: "
                    + ", ".join(list(network.trips_not_served)[:10]))
    advice = "; ".join(f"{k}: {len(v)} block(s) ({', '.join(v[:8])}"
                       f"{' ...' if len(v) > 8 else ''})" for k, v in needs.items()) or \
        "every block keeps its reserve and is recharged."
    fig, ax = plt.subplots(figsize=(9, 4), constrained_layout=True)
    option = rows[(rows["infrastructure"] == chosen["infrastructure"])
                  & (rows["day"] == rows["day"].min())]
    hours = np.arange(96) * 0.25
    for _, r in option.iterrows():
        ax.step(hours, np.asarray(r["depot_load_kw"]), where="post",
                label=f"{r['strategy']} (cost {r['cost_per_km']:.3f} {currency}/km)")
    ax.set(xlabel="hour of day (a block past midnight loads the next morning)",
           ylabel="depot load [kW] (15-min means)", xlim=(0, 24),
           title=f"Depot load over the day: {chosen['infrastructure']}")
    ax.set_xticks(range(0, 25, 2))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    timeline = Figure.of(fig, "depot_timeline", "depot load over the day per depot plan")
    header = [h for _, h in BLOCK_COLUMNS]
    return [
        Section("Timetable read", " ".join(read)),
        Section("What the blocks need", f"Scenario {chosen['scenario']}, day "
                f"{int(mine['day'].iloc[0])}: {advice} A block needs something when it falls "
                "below the reserve or runs empty: 'a charger' when it meets none and a 300 kW "
                "plug on its layovers would cover the energy it lacks, 'a bigger pack' when a "
                "pack of at most 1.5 x today's would, else 'a swap'.",
                [Table(header, table)]),
        Section("Depot load timeline", "The depot's overnight charging under each plan of "
                "the chosen option, in 15-min steps (the plans' cost and peak are in the "
                "scenarios' table).", figures=[timeline])]
