"""The main job on bundled data: ``ebus demo``.

Simulates the 12 m and 18 m buses through a SORT 2 service day, replays measured BMW i3 trips
against their logged SoC, calibrates the car on trip B16 and validates it on B03, diagnoses the
car without its cabin heating and a bus day with a hidden effect (adding it, the error falls),
and writes a self-contained HTML report with the figures, plots and a JSON of every number.
"""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path

from ebus_env.config import ROOT, load_bus
from ebus_env.cycles import service_day
from ebus_env.io.measured import load_log
from ebus_env.report import FIGURES, breakdown_label, write_json
from ebus_env.simulate import run_profiles

BMW_DIR = ROOT / "data" / "measured" / "bmw_i3_tum"
TRIPS = ("B16", "B03", "B02")


def _png(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def _table(summary: dict) -> str:
    rows = "".join(f"<tr><td>{label}</td><td>{summary[key]:.{d}f}</td><td>{unit}</td></tr>"
                   for key, label, unit, d in FIGURES if key in summary
                   and isinstance(summary[key], float))
    energy = "".join(f"<tr><td>{breakdown_label(k)}</td><td>{v:.2f}</td></tr>"
                     for k, v in summary["breakdown_kwh"].items())
    return (f"<table><tr><th>figure</th><th>value</th><th>unit</th></tr>{rows}</table>"
            f"<table><tr><th>energy</th><th>kWh</th></tr>{energy}</table>")


def _calibration_section(model, numbers: dict, say) -> tuple[str, str, str]:
    """Calibrate the BMW i3 on trip B16 with iSOPT, validate on B03."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ebus_env.calibration import ISOPTSettings, calibrate

    cal = load_log(BMW_DIR / "TripB16_1hz.csv", model.dt_s, columns="bmw_i3_tum").profiles
    val = load_log(BMW_DIR / "TripB03_1hz.csv", model.dt_s, columns="bmw_i3_tum").profiles
    result = calibrate(model, cal, settings=ISOPTSettings(seed=0), validate=val)
    numbers["bmw_i3_calibration"] = result.to_json()
    say(f"BMW i3 calibrated on B16 (NRMSE {result.fit['nrmse']:.4f}), validated on B03 "
        f"(NRMSE {result.validation['nrmse']:.4f}) in {result.wall_time_s:.1f} s")
    rows = "".join(
        f"<tr><td>{html.escape(p)}</td><td>{result.values[p]:.4g} {result.units[p]}</td>"
        f"<td>{html.escape(result.determinacy[p].status)}</td></tr>" for p in result.free)
    fits = "".join(
        f"<tr><td>{k}</td><td>{result.fit[k]:.4f}</td><td>{result.validation[k]:.4f}</td></tr>"
        for k in ("nrmse", "rmse_pct", "max_abs_error_pct", "correlation", "energy_error_pct"))
    table = (f"<table><tr><th>parameter</th><th>value</th><th>determined?</th></tr>{rows}"
             "</table><table><tr><th>fit</th><th>B16 (calibration)</th><th>B03 (validation)"
             f"</th></tr>{fits}</table>")
    buf = io.BytesIO()
    result.plot(buf)
    plt.close("all")
    return ("BMW i3: calibrated with iSOPT on trip B16, validated on B03", table,
            base64.b64encode(buf.getvalue()).decode())


def _diagnosis_sections(out: Path, numbers: dict, say) -> list[tuple[str, str, str]]:
    """Diagnose the BMW i3 without its cabin heating on B16 + B03, and a service day with a
    hidden effect, adding it (the error ladder); each writes its own HTML and JSON report."""
    from ebus_env.diagnostics import diagnose, hidden, plots

    cases = [("bmw_i3_without_heating", "BMW i3 trips B16 + B03, model without cabin heating",
              load_bus("bmw_i3", without=["cabin_hvac"]),
              [p for t in ("B16", "B03") for p in load_log(
                  BMW_DIR / f"Trip{t}_1hz.csv", columns="bmw_i3_tum").profiles], ())]
    case = hidden.case("cabin_heating")
    cases.append(("hidden_cabin_heating", "a 12 m bus on a cold day, its cabin heating hidden; "
                  "then added and re-calibrated", hidden.baseline_bus(case),
                  load_log(hidden.OUT_DIR / "cabin_heating.csv.gz").profiles, [case.effect]))
    sections = []
    for name, title, bus, profiles, add in cases:
        d = diagnose(bus, profiles, add=add)
        d.write_html(out / f"{name}.html")
        numbers[f"diagnosis_{name}"] = d.to_json()
        say(f"Diagnosis, {title}: {d.sentence}")
        rows = "".join(f"<tr><td>{html.escape(r.label)}</td><td>{r.calibration['nrmse']:.4f}"
                       f"</td><td>{r.held_out['nrmse']:.4f}</td></tr>" for r in d.ladder)
        table = (f"<p>{html.escape(d.sentence)} <a href='{name}.html'>Full report</a>.</p>"
                 + (f"<table><tr><th>model</th><th>NRMSE calibration blocks</th><th>NRMSE "
                    f"held-out blocks</th></tr>{rows}</table>" if rows else ""))
        sections.append((f"Diagnosis: {title}", table, _png(plots.missing_power(d))))
    return sections


def run_demo(out: Path, console=None) -> Path:
    """Run the demo and write ``out/index.html`` and ``out/summary.json``."""
    from ebus_env.plotting import plot_trace

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    say = console.print if console else print
    sections, numbers = [], {}
    for name in ("12m", "18m"):
        bus = load_bus(name)
        model = bus.build()
        profile = service_day("sort2", 13.5, model.dt_s, bus.service)
        run = run_profiles(model, [profile], soc_start=bus.service.soc_start_pct / 100.0)
        s = run.summary
        numbers[f"{name}_sort2_day"] = s
        say(f"{name} on a 13.5 h SORT 2 day: {s['kwh_per_km']:.3f} kWh/km, "
            f"peak grid {s['peak_grid_kw']:.0f} kW, simulated in {1e3 * s['wall_time_s']:.0f} ms")
        sections.append((f"{name} bus, 13.5 h of SORT 2 with opportunity charging",
                         _table(s), _png(plot_trace(run.results[0]))))
    i3 = load_bus("bmw_i3")
    model = i3.build()
    for trip in TRIPS:
        log = load_log(BMW_DIR / f"Trip{trip}_1hz.csv", model.dt_s, columns="bmw_i3_tum")
        run = run_profiles(model, log.profiles)
        s = run.summary
        numbers[f"bmw_i3_{trip}"] = s
        say(f"BMW i3 trip {trip}: SoC RMSE {s['soc_rmse_pct']:.2f} %-pts, "
            f"end error {s['soc_end_error_pct']:+.2f} %-pts (uncalibrated)")
        sections.append((f"BMW i3 trip {trip}: model vs measured SoC (uncalibrated defaults)",
                         _table(s), _png(plot_trace(run.results[0]))))
    sections.append(_calibration_section(model, numbers, say))
    sections += _diagnosis_sections(out, numbers, say)
    body = "".join(f"<h2>{html.escape(title)}</h2><div class='t'>{table}</div>"
                   f"<img src='data:image/png;base64,{png}'/>" for title, table, png in sections)
    page = ("<!doctype html><html><head><meta charset='utf-8'><title>ebus-env demo</title>"
            "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}"
            "table{border-collapse:collapse;margin:4px 16px 4px 0;display:inline-table;"
            "vertical-align:top}td,th{border:1px solid #ccc;padding:2px 6px;font-size:13px}"
            "img{max-width:100%}</style></head><body><h1>ebus-env demo report</h1>"
            f"{body}</body></html>")
    path = out / "index.html"
    path.write_text(page)
    write_json(numbers, out / "summary.json")
    return path
