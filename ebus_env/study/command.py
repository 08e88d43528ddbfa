"""``ebus study`` as one function: run a study file and write its rows, summary and report;
and what the command prints of it."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from ebus_env.study.study_file import StudySpec

if TYPE_CHECKING:
    import pandas as pd
    from rich.console import Console

# the columns the console shows (the report and summary.csv hold them all)
CONSOLE = ("scenario", "cost_per_km", "site_peak_kw", "site_peak_15min_kw", "lowest_soc_pct",
           "buses_short", "feasible", "pareto")


@dataclass
class StudyRun:
    """What :func:`run_study_file` ran and wrote.

    Attributes
    ----------
    spec
        The study, as checked.
    summary
        One row per scenario: cost, grid load, feasibility, Pareto front (a DataFrame).
    out
        The folder holding ``rows/``, ``summary.csv`` and ``report.html``.
    """

    spec: StudySpec
    summary: pd.DataFrame
    out: Path

    @property
    def report(self) -> Path:
        """The HTML report."""
        return self.out / "report.html"


def run_study_file(study_file: str | Path, out: str | Path = "study", *, resume: bool = False,
                   use_ray: bool = False, address: str | None = None,
                   workers: int | None = None, console: Console | None = None) -> StudyRun:
    """Check a study file, run what is left of it, write ``summary.csv`` and ``report.html``
    (``ebus study``).

    Parameters
    ----------
    study_file
        The study YAML (``configs/studies/``).
    out
        Folder for ``rows/`` (one Parquet file per scenario as it finishes), ``summary.csv``
        and ``report.html``; refused when it holds the study file.
    resume
        Skip the scenarios already in ``out``.
    use_ray, address
        Run the scenarios on Ray: a local runtime, or the cluster at ``host:port`` (which
        implies ``use_ray``).
    workers
        Threads in this process, or CPUs of a local Ray runtime (default: every CPU).
    console
        A rich Console told each scenario as it finishes (None: nothing is said).

    Returns
    -------
    StudyRun
        The study, its summary table and where it was written.
    """
    from ebus_env.outputs import check_folder
    from ebus_env.study.backends import run_study
    from ebus_env.study.study_file import load_study
    from ebus_env.study.summary import write_summary

    spec = load_study(study_file)  # every check before any work
    check_folder(Path(out), "--out", inputs=[Path(spec.source)])
    say = (lambda line: console.print(line, highlight=False)) if console else (lambda line: None)
    rows = run_study(spec, out, resume=resume, use_ray=use_ray or address is not None,
                     address=address, workers=workers, say=say)
    return StudyRun(spec, write_summary(spec, rows, out), Path(out))


def print_study(done: StudyRun, console: Console) -> None:
    """What ``ebus study`` prints of a :class:`StudyRun`: the summary's main columns by
    scenario, and where the rows and the summary went."""
    from rich.table import Table

    from ebus_env.study.summary import COLUMNS, table_rows

    table = Table(title=f"{done.spec.name}: cost in {done.spec.costs.currency}",
                  title_justify="left")
    shown = [i for i, (column, _, _) in enumerate(COLUMNS) if column in CONSOLE]
    for i in shown:
        table.add_column(COLUMNS[i][1])
    for row in table_rows(done.summary):
        table.add_row(*[row[i] for i in shown])
    console.print(table)
    console.print(f"rows -> {done.out / 'rows'}  summary -> {done.out / 'summary.csv'}")
