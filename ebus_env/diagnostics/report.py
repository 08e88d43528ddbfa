"""The diagnosis report: the same tables for the console and a self-contained HTML file (plots
embedded as PNG, opens offline)."""

from __future__ import annotations

from pathlib import Path

from ebus_env.calibration.calibrate import RANGE_END
from ebus_env.diagnostics.attribution import standing
from ebus_env.html_report import Figure, Section, Table, write_report
from ebus_env.units import shown_unit


def _f(value, digits: int = 2) -> str:
    return "" if value is None else f"{value:.{digits}f}"


def tables(d) -> list[tuple[str, list[str], list[list[str]]]]:
    """(title, header, rows) of every table of the report, in order."""
    out = []
    beyond = f" beyond the reference day ({', '.join(d.reference['logs'])})" \
        if d.reference else ""
    out.append(("Where it fails: missing power by operating mode" + beyond,
                ["mode", "hours", "missing kW", "+-", "missing kWh"],
                [[m["mode"], _f(m["hours"]), _f(m["missing_kw"]), _f(m["stderr_kw"]),
                  _f(m["missing_kwh"])] for m in d.modes]))
    for name, rows in d.bins.items():
        out.append((f"Missing power by {name}", [name, "hours", "missing kW", "+-"],
                    [[r["class"], _f(r["hours"]), _f(r["missing_kw"]), _f(r["stderr_kw"])]
                     for r in rows]))
    out.append(("Worst windows", ["from h", "to h", "time of day", "missing kW", "+-",
                                  "speed km/h", "ambient degC", "SoC %", "mostly"],
                [[_f(w["start_h"]), _f(w["end_h"]), _f(w["time_of_day_h"]),
                  _f(w["missing_kw"]), _f(w["stderr_kw"]), _f(w["mean_speed_kmh"], 1),
                  _f(w["ambient_degc"], 1), _f(w["soc_pct"], 1), w["main_mode"]]
                 for w in d.worst_windows]))
    if d.reference:
        ref = d.reference
        out.append((f"The reference day: what the model calibrated on it misses by mode "
                    f"(held-out NRMSE {ref['held_out_nrmse']:.4f}), taken off the breakdowns "
                    "by mode and bins above",
                    ["mode", "missing kW", "+-"],
                    [[m["mode"], _f(m["missing_kw"]), _f(m["stderr_kw"])]
                     for m in ref["missing_by_mode"]]))
        out.append(("The reference day's bus-to-bus values (the calibration searches within "
                    "a narrow range of them)", ["parameter", "value"],
                    [[name, f"{value:.4g}"] for name, value in ref["values"].items()]))
    if d.bus_fit:
        out.append(("The bus as its logs give it (fitted to the logged power, on a SoC-only "
                    "log the SoC's count in each window, where the current sensor's gain and "
                    "offset stand for the BMS count's capacity error and drift; the sensor's "
                    "terms per day where so)", ["parameter", "value", "range searched",
                                                "at an end"],
                    [[r["parameter"], f"{r['value']:.4g}",
                      "{:.4g} to {:.4g}".format(*r["range"]), RANGE_END.get(r["end"], "")]
                     for r in d.bus_fit]))
    out.append(("Which effect is missing (held-out share of the missing power, with its "
                "5-95 % band over bootstrap resamples of the windows)",
                ["effect", "kind", "explained %", "band %", "estimate (90 % interval)"],
                [[r.get("label", r["effect"]), r["kind"], _f(100 * r["explained_fraction"], 0),
                  "{:.0f} to {:.0f}".format(*(100 * b for b in r["explained_band"])),
                  ", ".join([f"{k} = {v:.4g} ({r['interval'][k][0]:.4g} to "
                             f"{r['interval'][k][1]:.4g})" for k, v in r["parameters"].items()]
                            + (["energy {:.3g} kWh ({:.3g} to {:.3g})".format(
                                r["energy_kwh"], *r["energy_interval_kwh"])]
                               if "energy_kwh" in r else []))]
                 for r in d.ranking]))
    out.append(("Parameters of the model's effects", ["parameter", "explained %",
                                                      "change that fits", "value then"],
                [[p["parameter"], _f(100 * p["explained_fraction"], 0),
                  f"{p['change_for_fit']:+.4g}", f"{p['value_for_fit']:.4g}" + (
                      "" if p["within_bounds"] else " (outside its bounds)")]
                 for p in d.parameters[:8]]))
    out.append(("Clues: what the missing power moves with", ["feature", "correlation",
                                                             "meaning"],
                [[c["feature"], _f(c["correlation"]), c["meaning"]] for c in d.clues[:8]]))
    if d.calibration:
        c, ends = d.calibration, d.range_ends
        out.append(("The calibrated bus (fitted on the calibration blocks; known values held: "
                    + (", ".join(c["fixed"]) or "none") + ")",
                    ["parameter", "value", "unit", "range searched", "at an end"],
                    [[name, f"{value:.4g}", shown_unit(c["units"][name]),
                      "{:.4g} to {:.4g}".format(*c["bounds"][name]),
                      RANGE_END.get(ends.get(name), "")] for name, value in c["params"].items()]))
    out.append(("Data problems (windows excluded from the attribution)",
                ["issue", "where / detail"],
                [[i["issue"], ", ".join(f"{k} {v}" for k, v in i.items() if k != "issue")]
                 for i in d.data_issues] or [["none found", ""]]))
    if d.resistance:
        out.append(("The pack's resistance from the logged voltage: the log's over the "
                    "model's, by hour of log or quarter of a shorter one (median of the "
                    "windows, off the charger)",
                    ["from h", "windows", "log / model", "+-"],
                    [[_f(h["start_h"], 2), h["windows"], _f(h["ratio"], 3), _f(h["stderr"], 3)]
                     for h in d.resistance["periods"]]))
    charge = "charge_held_out" in d.nrmse["before"]  # a log of the pack's current
    fit_rows = []
    for key in ("configured", "before", "after"):
        if key in d.nrmse:
            n = d.nrmse[key]
            label = "as configured (not calibrated)" if key == "configured" else key
            fit_rows.append([label, _f(n["calibration"], 4), _f(n["held_out"], 4),
                             *([_f(n["charge_held_out"], 4)] if charge else []),
                             _f(n["rmse_calibration_pct"], 3), _f(n["rmse_held_out_pct"], 3),
                             ""])
    for r in d.ladder:
        fit_rows.append([f"ladder: {r.label}", _f(r.calibration["nrmse"], 4),
                         _f(r.held_out["nrmse"], 4),
                         *([_f(r.held_out.get("charge_nrmse"), 4)] if charge else []),
                         _f(r.calibration["rmse_pct"], 3), _f(r.held_out["rmse_pct"], 3),
                         "; ".join(filter(None, [
                             ", ".join(f"{n} ({side})" for n, side in r.range_ends.items()),
                             # the fall of the next rung is measured against this search
                             f"searched again from the next rung's values (its own search "
                             f"ended at NRMSE {r.searched_nrmse:.4f})"
                             if r.searched_nrmse is not None else ""]))])
    out.append(("Error (" + d.nrmse["blocks"] + ")",
                ["model", "NRMSE cal", "NRMSE held-out",
                 *(["charge NRMSE held-out"] if charge else []), "RMSE cal %",
                 "RMSE held-out %", "calibrated at a range end; note"], fit_rows))
    return out


def text_report(d) -> str:
    """Plain-text report."""
    notes = (d.pack_note, d.unmet_note, d.decide_note, d.caution)
    lines = [d.sentence, *[note for note in notes if note], ""]
    for title, header, rows in tables(d):
        widths = [max(len(str(x)) for x in [h, *[r[i] for r in rows]])
                  for i, h in enumerate(header)]
        lines.append(title)
        lines.append("  " + "  ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)))
        for r in rows:
            lines.append("  " + "  ".join(str(x).ljust(w) for x, w in zip(r, widths,
                                                                          strict=True)))
        lines.append("")
    return "\n".join(lines)


def console_tables(d):
    """The tables as rich renderables, for the command line."""
    from rich.table import Table

    out = []
    for title, header, rows in tables(d):
        table = Table(title=title, header_style="bold", title_justify="left")
        for h in header:
            table.add_column(h)
        for r in rows:
            table.add_row(*[str(x) for x in r])
        out.append(table)
    return out


def write_html(d, path: str | Path) -> None:
    """One self-contained HTML file: verdict, plots (embedded PNG) and every table."""
    from ebus_env.diagnostics.plots import FIGURES

    images = {name: Figure.of(fn(d), name, _ALT[name]) for name, fn in FIGURES.items()}
    decide = [Section("What would decide it", text=d.to_decide[:1].upper() + d.to_decide[1:])]
    sections = [*(decide if d.to_decide else []),
                Section("Measured and simulated SoC", figures=[images["soc"]]),
                Section("Where it fails", figures=[images["missing_power"], images["modes"]]),
                Section("Which effect is missing", figures=[images["attribution"]]),
                Section("Error ladder", figures=[images["ladder"]])]
    sections += [Section(title, tables=[Table(header, rows)]) for title, header, rows in tables(d)]
    if d.set_aside:
        sections.append(Section("Candidates set aside", tables=[Table(
            ["effect", "why"], [[a["effect"], a["why"]] for a in d.set_aside])]))
    write_report(
        path, f"Diagnosis of {d.bus} on {', '.join(d.logs)}", sections,
        verdict=d.sentence, verdict_found=bool(d.verdict),
        ran=f"ebus diagnose: the {d.bus} model replayed on {', '.join(d.logs)}",
        settings={"missing power from": d.basis,
                  **({"relative to the reference day": ", ".join(d.reference["logs"])}
                     if d.reference else {}), "window": f"{d.window_s:g} s",
                  "significance": f"{standing(d.significance)} noise",
                  "windows excluded for data problems": d.excluded_windows,
                  **({"calibrated at an end of the range searched": ", ".join(
                      f"{n} ({side})" for n, side in d.range_ends.items())}
                     if d.range_ends else {}),
                  **({"the pack's resistance (logged voltage)": d.pack_note}
                     if d.pack_note else {}),
                  **({"the logged speed unmet": d.unmet_note} if d.unmet_note else {}),
                  **({"a logged second, as the logger took it": f"the model's second from "
                      f"{d.logger_lag_s:+.1f} s of its time stamp"}
                     if d.logger_lag_s is not None else {}),
                  "run time": f"{d.timings.get('total_s', 0):.1f} s"},
        how_to_read="missing power is the battery power the measured SoC implies minus the "
                    "model's; the ranking gives the share of it each candidate effect explains "
                    "on held-out windows, the ladder the error as effects are added and "
                    "re-calibrated")


_ALT = {"soc": "SoC overlay", "missing_power": "missing power over time",
        "modes": "missing power by operating mode", "attribution": "attribution",
        "ladder": "error ladder"}
