"""The depot's fleet summary: ``summary.csv``, ``files.csv``, ``days.csv`` and ``index.html``
(the project's report writer, :mod:`ebus_env.html_report`), the buses that need a workshop
visit first."""

from __future__ import annotations

import os

import pandas as pd

from ebus_env.html_report import Section, Table, write_report
from ebus_env.outputs import atomic


def _csv(frame: pd.DataFrame, path) -> None:
    with atomic(path) as tmp:
        frame.to_csv(tmp, index=False)


def _table(frame: pd.DataFrame, title: str = "") -> Table:
    return Table(list(frame.columns), [[("" if pd.isna(v) else v) for v in row]
                                       for row in frame.itertuples(index=False)], title)


def day_rows(run, rule) -> pd.DataFrame:
    rows = []
    for d in run.days.days:
        short = f"shorter than {rule.min_day_h:g} h: not diagnosed" \
            if d.path and d.hours < rule.min_day_h else ""
        rows.append({"bus": d.bus, "start": d.first, "hours": round(d.hours, 2),
                     "log": os.path.relpath(d.path, run.out) if d.path else "",
                     "problem": d.problem or short, "notes": "; ".join(d.notes)})
    return pd.DataFrame(rows, columns=["bus", "start", "hours", "log", "problem", "notes"])


def write_summary(run, smap, loggers, rule, command: str = "") -> None:
    """Write the summary files of a :class:`~ebus_env.depot.depot_run.DepotRun` into its ``out``."""
    out = run.out
    order = {"workshop": 0, "watch": 1, "no diagnosis": 2, "ok": 3}
    buses = pd.DataFrame([b.row(out) for b in sorted(run.buses,
                                                     key=lambda b: (order[b.action], b.bus))],
                         columns=["bus", "action", "verdict", "status", "days",
                                  "days_diagnosed", "first_day", "last_day", "hours", "why",
                                  "sentence", "report"])
    files = pd.DataFrame([f.row(run.folder, smap) for f in run.days.files])
    days = day_rows(run, rule)
    run.summary = out / "summary.csv"
    _csv(buses, run.summary)
    _csv(files, out / "files.csv")
    _csv(days, out / "days.csv")
    sections = []
    for b in run.workshop:
        sections.append(Section(f"Bus {b.bus}: workshop ({b.verdict or b.status})",
                                b.sentence or b.why,  # the sentence holds the why
                                link=(os.path.relpath(b.report, out), "diagnosis report")
                                if b.report else None))
    shown = buses.drop(columns=["sentence"])
    sections.append(Section("Buses", "One row per bus, diagnosed over its service days "
                            "together; the workshop's first.", tables=[_table(shown)]))
    sections.append(Section("Service days", f"A service day runs between depot stays of "
                            f"{rule.stay_h:g} h or more without moving, with "
                            f"{rule.margin_min:g} min of standing kept at either end; days "
                            f"under {rule.min_day_h:g} h are listed, not diagnosed.",
                            tables=[_table(days)]))
    sections.append(Section("Logger files", "Frames the DBC does not describe, of another "
                            "length than the DBC's, with values out of range, or outside "
                            "every installation of their logger: counted per file.",
                            tables=[_table(files)]))
    n_work = len(run.workshop)
    verdict = (f"{n_work} of {len(run.buses)} buses need a workshop visit: "
               + ", ".join(f"{b.bus} ({b.verdict or b.status})" for b in run.workshop)
               if n_work else f"No bus of {len(run.buses)} needs a workshop visit.")
    run.html = write_report(
        out / "index.html", "Depot: which bus needs a workshop visit", sections,
        ran=command, verdict=verdict, verdict_found=bool(n_work),
        settings={"folder": str(run.folder), "logger map": str(loggers.path),
                  "signal map": f"{smap.name} ({smap.dbc_path.name})",
                  "stay_h": rule.stay_h, "margin_min": rule.margin_min,
                  "min_day_h": rule.min_day_h},
        how_to_read="workshop: the diagnosis names a missing effect; watch: power is "
                    "missing and no effect is named (look again with more days); ok: nothing "
                    "missing above the noise. Each bus's report says why.")
