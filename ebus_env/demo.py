"""The main job on bundled data: ``ebus demo``.

Simulates the 12 m and 18 m buses through a SORT 2 service day, replays measured BMW i3 trips
against their logged SoC, calibrates the car on trip B16 and validates it on B03, diagnoses the
car without its cabin heating and a bus day with a hidden effect (adding it, the error falls),
and writes a self-contained HTML report with the figures, plots and a JSON of every number.
"""

from __future__ import annotations

import base64
import io
import time
from pathlib import Path

from ebus_env import paths
from ebus_env.config import load_bus
from ebus_env.console import FIGURES, breakdown_label
from ebus_env.cycles import service_day
from ebus_env.html_report import Figure, Section, Table, write_report
from ebus_env.io.measured import load_log
from ebus_env.outputs import write_json
from ebus_env.simulate import run_profiles
from ebus_env.units import shown_unit, with_unit

BMW_DIR = paths.data("measured", "bmw_i3_tum")
TRIPS = ("B16", "B03", "B02")


def _tables(summary: dict) -> list[Table]:
    rows = [[label, f"{summary[key]:.{d}f}", shown_unit(unit)] for key, label, unit, d in FIGURES
            if key in summary and isinstance(summary[key], float)]
    energy = [[breakdown_label(k), f"{v:.2f}"] for k, v in summary["breakdown_kwh"].items()]
    return [Table(["figure", "value", "unit"], rows), Table(["energy", "kWh"], energy)]


def _calibration_section(model, numbers: dict, say) -> Section:
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
    rows = [[p, with_unit(f"{result.values[p]:.4g}", result.units[p]), result.determinacy[p].status]
            for p in result.free]
    fits = [[k, f"{result.fit[k]:.4f}", f"{result.validation[k]:.4f}"]
            for k in ("nrmse", "rmse_pct", "max_abs_error_pct", "correlation", "energy_error_pct")]
    tables = [Table(["parameter", "value", "determined?"], rows),
              Table(["fit", "B16 (calibration)", "B03 (validation)"], fits)]
    buf = io.BytesIO()
    result.plot(buf)
    plt.close("all")
    figure = Figure("bmw_i3_calibration", "calibrated SoC on B16 and B03",
                    base64.b64encode(buf.getvalue()).decode("ascii"))
    return Section("BMW i3: calibrated with iSOPT on trip B16, validated on B03", tables=tables,
                   figures=[figure])


def _diagnosis_sections(out: Path, numbers: dict, say) -> list[Section]:
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
        rows = [[r.label, f"{r.calibration['nrmse']:.4f}", f"{r.held_out['nrmse']:.4f}"]
                for r in d.ladder]
        tables = [Table(["model", "NRMSE calibration blocks", "NRMSE held-out blocks"],
                        rows)] if rows else []
        sections.append(Section(f"Diagnosis: {title}", d.sentence, tables, [Figure.of(
            plots.missing_power(d), f"diagnosis_{name}", "missing power over time", dpi=90)],
            link=(f"{name}.html", "Full report")))
    return sections


def run_demo(out: str | Path = "report", console=None) -> Path:
    """Run the demo (``ebus demo``) and write ``out/index.html`` and ``out/summary.json``.

    Parameters
    ----------
    out
        The report's folder: made if needed, refused when it holds a log the demo reads.
    console
        A rich Console told what each part found (None: ``print``).

    Returns
    -------
    Path
        The HTML report.
    """
    from ebus_env.diagnostics.hidden import OUT_DIR
    from ebus_env.outputs import check_folder
    from ebus_env.plotting import plot_trace

    # not into the folders of the logs it reads: a report is no shipped data
    out = check_folder(Path(out), "--out", inputs=[*BMW_DIR.glob("*.csv"),
                                                  *OUT_DIR.glob("*.csv.gz")])
    say = console.print if console else print
    sections, numbers = [], {}
    for name in ("12m", "18m"):
        bus = load_bus(name)
        t0 = time.perf_counter()
        model = bus.build()
        model.compile(record=True)
        model.compile(record=False)
        build_s = time.perf_counter() - t0  # apart from the simulation's own time
        profile = service_day("sort2", 13.5, model.dt_s, bus.service)
        soc_start = bus.service.soc_start_pct / 100.0
        run = run_profiles(model, [profile], soc_start=soc_start)
        s = run.summary
        s["wall_time_no_trace_s"] = model.simulate(profile, soc_start=soc_start,
                                                   record=False).wall_time_s
        s["build_s"] = build_s
        numbers[f"{name}_sort2_day"] = s
        say(f"{name} on a 13.5 h SORT 2 day: {s['kwh_per_km']:.3f} kWh/km, "
            f"peak grid {s['peak_grid_kw']:.0f} kW; simulated in "
            f"{1e3 * s['wall_time_no_trace_s']:.0f} ms ({1e3 * s['wall_time_s']:.0f} ms "
            f"recording the 10 Hz trace); model built and compiled in {build_s:.2f} s")
        sections.append(Section(f"{name} bus, 13.5 h of SORT 2 with opportunity charging",
                                tables=_tables(s), figures=[Figure.of(
                                    plot_trace(run.results[0]), f"{name}_sort2", dpi=90)]))
    i3 = load_bus("bmw_i3")
    model = i3.build()
    for trip in TRIPS:
        log = load_log(BMW_DIR / f"Trip{trip}_1hz.csv", model.dt_s, columns="bmw_i3_tum")
        run = run_profiles(model, log.profiles)
        s = run.summary
        numbers[f"bmw_i3_{trip}"] = s
        say(f"BMW i3 trip {trip}: SoC RMSE {s['soc_rmse_pct']:.2f} %-pts, "
            f"end error {s['soc_end_error_pct']:+.2f} %-pts (uncalibrated)")
        sections.append(Section(f"BMW i3 trip {trip}: model vs measured SoC (uncalibrated "
                                "defaults)", tables=_tables(s), figures=[Figure.of(
                                    plot_trace(run.results[0]), f"bmw_i3_{trip}", dpi=90)]))
    sections.append(_calibration_section(model, numbers, say))
    sections += _diagnosis_sections(out, numbers, say)
    path = write_report(
        out / "index.html", "ebus-env demo report", sections,
        ran="the 12 m and 18 m buses on a 13.5 h SORT 2 day; BMW i3 trips "
            f"{', '.join(TRIPS)} replayed on their measured speed; iSOPT calibration of the "
            "BMW i3 on B16, validated on B03; two diagnoses",
        settings={"bus configs": "configs/bus/12m.yaml, 18m.yaml, bmw_i3.yaml (defaults)",
                  "time step": f"{model.dt_s:g} s", "iSOPT seed": 0},
        how_to_read="each section gives the figures of one run and its trace (a service "
                    "day's speed and power over its first 20 min, shaded below); grid energy "
                    "includes charger losses; SoC errors are in percentage points; "
                    "simulation wall times leave out building and compiling the model, "
                    "given apart; the diagnosis sections link to their full reports")
    write_json(numbers, out / "summary.json")
    return path
