"""The diagnosis report: the same tables for the console and a self-contained HTML file (plots
embedded as PNG, opens offline)."""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path


def _f(value, digits: int = 2) -> str:
    return "" if value is None else f"{value:.{digits}f}"


def tables(d) -> list[tuple[str, list[str], list[list[str]]]]:
    """(title, header, rows) of every table of the report, in order."""
    out = []
    out.append(("Where it fails: missing power by operating mode",
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
    out.append(("Which effect is missing (held-out share of the missing power, with its "
                "5-95 % band over bootstrap resamples of the windows)",
                ["effect", "kind", "explained %", "band %", "estimate (90 % interval)"],
                [[r["effect"], r["kind"], _f(100 * r["explained_fraction"], 0),
                  "{:.0f} to {:.0f}".format(*(100 * b for b in r["explained_band"])),
                  ", ".join(f"{k} = {v:.4g} ({r['interval'][k][0]:.4g} to "
                            f"{r['interval'][k][1]:.4g})" for k, v in r["parameters"].items())]
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
    out.append(("Data problems (windows excluded from the attribution)",
                ["issue", "where / detail"],
                [[i["issue"], ", ".join(f"{k} {v}" for k, v in i.items() if k != "issue")]
                 for i in d.data_issues] or [["none found", ""]]))
    fit_rows = []
    for key in ("before", "after"):
        if key in d.nrmse:
            n = d.nrmse[key]
            fit_rows.append([key, _f(n["calibration"], 4), _f(n["held_out"], 4),
                             _f(n["rmse_calibration_pct"], 3), _f(n["rmse_held_out_pct"], 3)])
    for r in d.ladder:
        fit_rows.append([f"ladder: {r.label}", _f(r.calibration["nrmse"], 4),
                         _f(r.held_out["nrmse"], 4), _f(r.calibration["rmse_pct"], 3),
                         _f(r.held_out["rmse_pct"], 3)])
    out.append(("Error (" + d.nrmse["blocks"] + ")",
                ["model", "NRMSE cal", "NRMSE held-out", "RMSE cal %", "RMSE held-out %"],
                fit_rows))
    return out


def text_report(d) -> str:
    """Plain-text report."""
    lines = [d.sentence, ""]
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


def _png(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


_STYLE = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.15em; margin-top: 1.6em; }
.verdict { font-size: 1.15em; padding: 0.8em 1em; background: #eef6ee; border-left: 5px solid
  #33a02c; } .verdict.none { background: #f4f4f4; border-color: #888; }
table { border-collapse: collapse; margin: 0.5em 0 1em; font-size: 0.9em; }
td, th { border: 1px solid #ccc; padding: 3px 8px; text-align: left; }
th { background: #f0f0f0; } img.plot { max-width: 100%; display: block; margin: 0.5em 0; }
.meta { color: #666; font-size: 0.85em; }
"""

_SCRIPT = """
function plotLoaded(img) {
  img.dataset.rendered = img.naturalWidth > 0 ? "yes" : "no";
  const all = document.querySelectorAll("img.plot");
  const ok = Array.from(all).filter(i => i.dataset.rendered === "yes").length;
  document.body.dataset.plotsRendered = ok + "/" + all.length;
}
"""


def _table_html(header, rows) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(x))}</td>" for x in r) + "</tr>"
                   for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def write_html(d, path: str | Path) -> None:
    """One self-contained HTML file: verdict, plots (embedded PNG) and every table."""
    from ebus_env.diagnostics.plots import FIGURES

    images = {name: _png(fn(d)) for name, fn in FIGURES.items()}

    def img(name, alt):
        return (f'<img class="plot" id="plot-{name}" alt="{html.escape(alt)}" '
                f'onload="plotLoaded(this)" src="data:image/png;base64,{images[name]}">')

    parts = [f"<h1>Diagnosis of {html.escape(d.bus)} on {html.escape(', '.join(d.logs))}</h1>",
             f'<p class="verdict{"" if d.verdict else " none"}">{html.escape(d.sentence)}</p>',
             f'<p class="meta">Missing power from {html.escape(d.basis)}, {d.window_s:g} s '
             f"windows; significance {d.significance:.1f} standard deviations above noise; "
             f"{d.excluded_windows} window(s) excluded for data problems; "
             f"{d.timings.get('total_s', 0):.1f} s.</p>",
             "<h2>Measured and simulated SoC</h2>", img("soc", "SoC overlay"),
             "<h2>Where it fails</h2>", img("missing_power", "missing power over time"),
             img("modes", "missing power by operating mode"),
             "<h2>Which effect is missing</h2>", img("attribution", "attribution"),
             "<h2>Error ladder</h2>", img("ladder", "error ladder")]
    for title, header, rows in tables(d):
        parts.append(f"<h2>{html.escape(title)}</h2>{_table_html(header, rows)}")
    if d.set_aside:
        parts.append("<h2>Candidates set aside</h2>" + _table_html(
            ["effect", "why"], [[a["effect"], a["why"]] for a in d.set_aside]))
    page = (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>ebus diagnose: "
            f"{html.escape(d.bus)}</title><style>{_STYLE}</style><script>{_SCRIPT}</script>"
            f"</head><body data-plots-rendered='0/{len(images)}'>{''.join(parts)}</body></html>")
    Path(path).write_text(page, encoding="utf-8")
