"""``ebus study``: run a study file and write its rows, summary and report."""

from __future__ import annotations

from pathlib import Path

# the columns the console shows (the report and summary.csv hold them all)
CONSOLE = ("scenario", "cost_per_km", "site_peak_kw", "site_peak_15min_kw", "lowest_soc_pct",
           "buses_short", "feasible", "pareto")


def study_command(study_file: Path, out: Path, resume: bool, use_ray: bool, address: str | None,
                  workers: int | None, console) -> Path:
    """Check the study, run what is left of it, write ``summary.csv`` and ``report.html``."""
    from ebus_env.outputs import check_folder
    from ebus_env.study.backends import run_study
    from ebus_env.study.study_file import load_study
    from ebus_env.study.summary import COLUMNS, table_rows, write_summary

    spec = load_study(study_file)  # every check before any work
    check_folder(out, "--out", inputs=[Path(spec.source)])
    rows = run_study(spec, out, resume=resume, use_ray=use_ray or address is not None,
                     address=address, workers=workers,
                     say=lambda line: console.print(line, highlight=False))
    summary = write_summary(spec, rows, out)
    from rich.table import Table

    table = Table(title=f"{spec.name}: cost in {spec.costs.currency}", title_justify="left")
    shown = [i for i, (column, _, _) in enumerate(COLUMNS) if column in CONSOLE]
    for i in shown:
        table.add_column(COLUMNS[i][1])
    for row in table_rows(summary):
        table.add_row(*[row[i] for i in shown])
    console.print(table)
    console.print(f"rows -> {Path(out) / 'rows'}  summary -> {Path(out) / 'summary.csv'}")
    return Path(out) / "report.html"
