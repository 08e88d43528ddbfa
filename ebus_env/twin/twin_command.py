"""``ebus twin``: serve the fleet's live twin, manage its tokens, replay logs into it.

``register(app)`` adds the group to the ``ebus`` typer app (``ebus_env.cli`` names this module
in its ``COMMAND_MODULES``). Imported at ``ebus`` start-up: only typer, the standard library
and :mod:`ebus_env.cli_options` at the top; each command imports its work when it runs."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ebus_env.cli_options import BusOpt, console, run_command

twin_app = typer.Typer(no_args_is_help=True, help="The fleet's live digital twin: serve it, "
                                                 "give tokens, replay logs into it.")
token_app = typer.Typer(no_args_is_help=True, help="Access tokens (stored hashed).")
twin_app.add_typer(token_app, name="token")

DbOpt = Annotated[str, typer.Option(
    "--db", help="The store: an SQLite file (default twin.sqlite) or postgresql://user@host/db")]


@twin_app.command()
def serve(
    db: DbOpt = "twin.sqlite",
    host: Annotated[str, typer.Option(help="Address to listen on")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="TCP port")] = 8690,
    mqtt: Annotated[str | None, typer.Option(
        help="Subscribe to fleet/<bus>/telemetry on this broker, host:port")] = None,
    mqtt_user: Annotated[str | None, typer.Option(help="The twin's broker user")] = None,
    mqtt_password_file: Annotated[Path | None, typer.Option(
        help="File holding the twin's broker password")] = None,
    jobs: Annotated[bool, typer.Option(
        help="Run re-fits, diagnoses and predictions in this process (--no-jobs: ingest "
             "only, for extra ingest processes)")] = True,
    use_ray: Annotated[bool, typer.Option("--ray", help="Run the jobs on Ray")] = False,
    address: Annotated[str | None, typer.Option(help="Join the Ray cluster at host:port")] = None,
    bus_config: BusOpt = "12m",  # the model every bus's starts from
    keep_raw_days: Annotated[float, typer.Option(
        help="Keep raw 1 Hz samples this many days, then 1-min aggregates")] = 30.0,
):
    """Run the twin: HTTP ingest and queries, the dashboard at http://HOST:PORT/."""

    def body():
        import uvicorn

        from ebus_env.twin.fleet_twin import Twin
        from ebus_env.twin.jobs import Jobs, JobSettings
        from ebus_env.twin.server import create_app
        from ebus_env.twin.store import open_store

        store = open_store(db)
        twin = Twin(store)
        runner = None
        if jobs or use_ray:
            runner = Jobs(twin, JobSettings(bus_config=bus_config, keep_raw_days=keep_raw_days),
                          ray=use_ray or address is not None, address=address)
            twin.jobs = runner
        subscriber = None
        if mqtt:
            from ebus_env.twin.mqtt_bridge import Subscriber

            password = mqtt_password_file.read_text().strip() if mqtt_password_file else None
            subscriber = Subscriber(twin, mqtt, mqtt_user, password)
        app = create_app(twin, mqtt=subscriber, jobs=runner)
        console().print(f"twin on http://{host}:{port}/ (store {store})")
        uvicorn.run(app, host=host, port=port, log_level="warning")

    run_command(body)


@token_app.command("create")
def token_create(
    fleet: Annotated[str, typer.Option(help="The fleet (a named set of buses one operator "
                                            "owns)")],
    bus: Annotated[str | None, typer.Option(help="A write token for this bus (created in the "
                                                 "fleet when new); without it a read token "
                                                 "of the fleet")] = None,
    label: Annotated[str, typer.Option(help="What the token is for")] = "",
    reserve_soc_pct: Annotated[float | None, typer.Option(
        help="The bus's SoC reserve [%] for the 'will not make it' alarm (default 30)")] = None,
    db: DbOpt = "twin.sqlite",
):
    """Create a token and print it (once: only its hash is stored)."""

    def body():
        from ebus_env.inputs import check
        from ebus_env.twin.store import open_store
        from ebus_env.twin.tokens import create

        if reserve_soc_pct is not None:
            check("soc_start_pct", reserve_soc_pct, "--reserve-soc-pct")
        token = create(open_store(db), fleet=fleet, bus=bus, label=label,
                       reserve_soc_pct=reserve_soc_pct)
        print(token)

    run_command(body)


@twin_app.command()
def replay(
    logs: Annotated[list[Path], typer.Argument(help="Logger files, streamed in this order")],
    bus: Annotated[str, typer.Option(help="The bus the logs are of")],
    url: Annotated[str, typer.Option(help="The twin, http://host:port")] = "http://127.0.0.1:8690",
    token: Annotated[str | None, typer.Option(
        help="The bus's write token (or $EBUS_TWIN_TOKEN)", envvar="EBUS_TWIN_TOKEN")] = None,
    speed: Annotated[str, typer.Option(help="Factor of real time, e.g. 60x")] = "60x",
    batch_s: Annotated[float, typer.Option(help="Seconds of log per batch")] = 10.0,
    limit_min: Annotated[float | None, typer.Option(
        help="Stop after this many minutes of wall time")] = None,
):
    """Stream logs to a twin as the bus's logger would (1 Hz samples in batches)."""

    def body():
        from ebus_env.errors import ConfigError
        from ebus_env.twin.replay import parse_speed
        from ebus_env.twin.replay import replay as run

        if not token:
            raise ConfigError("--token: give the bus's write token (ebus twin token create "
                              "--fleet NAME --bus ID), or set EBUS_TWIN_TOKEN")
        counts = run(logs, bus, url, token, parse_speed(speed), batch_s,
                     limit_s=None if limit_min is None else 60.0 * limit_min)
        console().print(f"{bus}: {counts['batches']} batches, {counts['samples']} samples "
                         f"stored, {counts['duplicates']} duplicates, {counts['schedules']} "
                         "blocks")

    run_command(body)


@twin_app.command()
def retain(
    keep_raw_days: Annotated[float, typer.Option(help="Days of raw 1 Hz samples to keep")] = 30.0,
    db: DbOpt = "twin.sqlite",
):
    """Reduce raw samples older than --keep-raw-days to 1-min aggregates (the twin does this
    itself once an hour)."""

    def body():
        from ebus_env.twin.retention import reduce_old
        from ebus_env.twin.store import open_store

        done = reduce_old(open_store(db), keep_raw_days)
        console().print(f"{done['samples']} samples reduced to {done['minutes']} 1-min rows")

    run_command(body)


@twin_app.command()
def demo(
    minutes: Annotated[float, typer.Option(help="How long to replay [min of wall time]")] = 3.0,
    buses: Annotated[int, typer.Option(help="How many of the shipped fleet's buses")] = 3,
    speed: Annotated[str, typer.Option(help="Factor of real time")] = "60x",
    port: Annotated[int, typer.Option(help="TCP port of the twin")] = 8690,
    db: DbOpt = "report/twin/twin.sqlite",
):
    """Serve a twin and replay a few buses of the shipped made-up fleet into it (open the
    dashboard's link while it runs)."""

    def body():
        import threading
        import time

        import uvicorn

        from ebus_env import paths
        from ebus_env.twin.fleet_twin import Twin
        from ebus_env.twin.jobs import Jobs
        from ebus_env.twin.replay import parse_speed
        from ebus_env.twin.replay import replay as run
        from ebus_env.twin.server import create_app
        from ebus_env.twin.store import open_store
        from ebus_env.twin.tokens import create

        fleet = paths.here_or_shipped("data/twin_fleet")
        names = sorted(p.name for p in fleet.glob("bus-*"))[:buses]
        store = open_store(db)
        twin = Twin(store)
        twin.jobs = Jobs(twin)
        writes = {bus: create(store, fleet="demo", bus=bus) for bus in names}
        read = create(store, fleet="demo", label="demo dashboard")
        server = uvicorn.Server(uvicorn.Config(create_app(twin, jobs=twin.jobs),
                                               host="127.0.0.1", port=port,
                                               log_level="warning"))
        threading.Thread(target=server.run, daemon=True).start()
        while not server.started:
            time.sleep(0.1)
        console().print(f"dashboard: http://127.0.0.1:{port}/?fleet=demo&token={read}")
        factor = parse_speed(speed)
        threads = [threading.Thread(target=run, daemon=True, args=(
            sorted((fleet / bus).glob("*.csv.gz")), bus, f"http://127.0.0.1:{port}",
            writes[bus], factor), kwargs={"limit_s": 60.0 * minutes}) for bus in names]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        for row in twin.fleet("demo"):
            console().print(f"{row['bus']}: SoC {row['soc_pct']} %, {row['alarms']} alarm(s)"
                             f" {row['latest_alarm'] or ''}", soft_wrap=True)
        server.should_exit = True

    run_command(body)


def register(app: typer.Typer) -> None:
    """Add ``ebus twin ...`` to ``app`` (``ebus_env.cli`` names this module in its
    ``COMMAND_MODULES``)."""
    app.add_typer(twin_app, name="twin")
