"""``ebus depot FOLDER --map loggers.csv --bus 12m --out report/``: a depot's folder of CAN
logger files to the buses that need a workshop visit (:func:`ebus_env.depot.depot_run.run_depot`).

``register(app)`` adds the command to the ``ebus`` typer app (``ebus_env.cli`` names this module
in its ``COMMAND_MODULES``)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ebus_env.cli_options import run_command


def register(app: typer.Typer) -> None:
    """Add ``ebus depot`` to ``app``."""

    @app.command()
    def depot(
        folder: Annotated[Path, typer.Argument(help="Folder of the loggers' files (.mf4, .blf, "
                                                    ".asc), a subfolder per logger or files "
                                                    "named LOGGER_...")],
        map_csv: Annotated[Path, typer.Option(
            "--map", help="Logger-to-bus map: CSV of logger_id, bus_id, valid_from, valid_to")],
        out: Annotated[Path, typer.Option(help="Folder for the bus-day logs and the summary")]
        = Path("depot_report"),
        bus: Annotated[str, typer.Option("--bus", "-b", help="Bus config of every bus (12m, "
                                                             "18m or a YAML file)")] = "12m",
        without: Annotated[list[str] | None, typer.Option(
            "--without", help="Remove an effect from the bus (repeatable)")] = None,
        columns: Annotated[str, typer.Option(
            help="Signal map (configs/logs): the DBC and which signal feeds which column")]
        = "ebus_j1939",
        stay_h: Annotated[float, typer.Option(
            help="A depot stay: this many hours or more without moving; service days run "
                 "between them")] = 2.0,
        margin_min: Annotated[float, typer.Option(
            help="Standing kept before a day's first departure and after its last arrival "
                 "[min]")] = 15.0,
        min_day_h: Annotated[float, typer.Option(
            help="Service days shorter than this are listed, not diagnosed [h]")] = 1.0,
        gaps: Annotated[str, typer.Option(
            help="Gaps within a service day (the logger off): split, error, hold, interpolate")]
        = "split",
        fill: Annotated[str, typer.Option(help="Missing values: error or interpolate")]
        = "error",
        calibrate: Annotated[bool, typer.Option(
            help="Calibrate each bus's own parameters on its days before diagnosing")] = True,
        domain: Annotated[str, typer.Option(
            help="soc: SoC windows; power: each bus fitted to its pack's power over its "
                 "days (the logged current and voltage second by second, or the SoC's count "
                 "in each 5-min window), with the day a change started; auto: power where "
                 "every day's log has the current and voltage")] = "soc",
        no_diagnose: Annotated[bool, typer.Option(
            "--no-diagnose", help="Only cut the folder into bus-day logs")] = False,
    ):
        """A depot's logger files: service days per bus, each bus diagnosed over its days, and
        the buses that need a workshop visit, and why."""

        def body():
            import shlex
            import sys

            from rich.console import Console
            from rich.markup import escape
            from rich.table import Table

            from ebus_env.config import load_bus
            from ebus_env.depot.depot_run import run_depot
            from ebus_env.depot.service_days import DayRule

            console = Console()
            rule = DayRule(stay_h=stay_h, margin_min=margin_min, min_day_h=min_day_h)
            parts = [p.strip() for item in without or [] for p in item.split(",") if p.strip()]
            bus_config = load_bus(bus, without=parts)
            command = "ebus " + " ".join(shlex.quote(a) for a in sys.argv[1:])
            with console.status("reading the depot's files") as status:
                result = run_depot(folder, map_csv, out, bus_config=bus_config,
                                   signal_map=columns, rule=rule, calibrate=calibrate,
                                   diagnose=not no_diagnose, gaps=gaps, fill=fill,
                                   command=command, progress=status.update,
                                   domain=domain)
            for f in result.days.files:
                if f.problem:
                    console.print(f"[yellow]{escape(f.path.name)} ({escape(f.logger)}):[/] "
                                  f"{escape(f.problem)}", highlight=False, soft_wrap=True)
            table = Table(title=f"{len(result.buses)} buses, {len(result.days.days)} service "
                                f"days from {len(result.days.files)} files")
            for name in ("bus", "action", "verdict", "status", "days", "why"):
                table.add_column(name, overflow="fold")
            style = {"workshop": "bold red", "watch": "yellow", "ok": "green"}
            for b in sorted(result.buses, key=lambda b: (b.action != "workshop", b.bus)):
                table.add_row(escape(b.bus), f"[{style.get(b.action, 'dim')}]{b.action}[/]",
                              escape(b.verdict or ""), escape(b.status),
                              f"{len(b.diagnosed)}/{len(b.days)}", escape(b.why))
            console.print(table)
            console.print(f"[bold]{len(result.workshop)} bus(es) need a workshop visit[/]"
                          + (": " + ", ".join(b.bus for b in result.workshop)
                             if result.workshop else ""), highlight=False)
            console.print(f"summary -> {result.summary}\nreport -> {result.html}",
                          highlight=False)

        run_command(body)
