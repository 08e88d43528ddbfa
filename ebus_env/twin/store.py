"""The twin's SQL store: one schema on an embedded SQLite file (the default) or PostgreSQL
(several twin processes share it), kept in Alembic migrations (``migrations/``).

Durability: a batch of samples goes in one transaction with its batch row, so a batch is
stored whole or not at all, and the HTTP answer is sent only after the commit returns. SQLite
runs in WAL mode with ``synchronous=FULL`` (every commit is on disk before it returns: the
SQLite documentation, "Write-Ahead Logging" and "PRAGMA synchronous"); PostgreSQL commits
durably by default (``synchronous_commit=on``). A batch sent twice is stored once: its
``(bus, batch_id)`` is the batch table's primary key, and samples are keyed by ``(bus, t)``.

Times are UTC seconds since the epoch (``t``, float).
"""

from __future__ import annotations

import json
from pathlib import Path

import sqlalchemy as sa
from sqlalchemy import event

from ebus_env.errors import ConfigError

metadata = sa.MetaData()

SAMPLE_COLUMNS = ("speed_kmh", "soc_pct", "ambient_degc", "charging", "charger_kw",
                  "door_open", "passengers", "grade_pct", "altitude_m", "battery_current_a",
                  "battery_voltage_v", "logged_load_kw")
"""The canonical log columns a sample may carry (``ebus_env.io.measured``), besides ``t``."""

fleets = sa.Table("fleets", metadata, sa.Column("name", sa.String(64), primary_key=True))
buses = sa.Table(
    "buses", metadata,
    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("name", sa.String(64), nullable=False, unique=True),
    sa.Column("fleet", sa.String(64), sa.ForeignKey("fleets.name"), nullable=False),
    sa.Column("reserve_soc_pct", sa.Float, nullable=False, server_default="30"),
    # the newest sample and when it came (wall clock), kept with each batch: the fleet page
    # reads them without scanning the samples
    sa.Column("last_t", sa.Float(53)),
    sa.Column("last_soc_pct", sa.Float),
    sa.Column("last_speed_kmh", sa.Float),
    sa.Column("seen_at", sa.Float(53)),
)
tokens = sa.Table(
    "tokens", metadata,
    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("token_hash", sa.String(64), nullable=False, unique=True),
    sa.Column("kind", sa.String(8), nullable=False),  # "write" (one bus) or "read" (one fleet)
    sa.Column("bus", sa.String(64), nullable=True),
    sa.Column("fleet", sa.String(64), nullable=True),
    sa.Column("label", sa.String(200), nullable=False, server_default=""),
    sa.Column("created_at", sa.Float, nullable=False),
    sa.Column("revoked", sa.Boolean, nullable=False, server_default=sa.false()),
)
batches = sa.Table(
    "batches", metadata,
    sa.Column("bus_id", sa.Integer, sa.ForeignKey("buses.id"), primary_key=True),
    sa.Column("batch_id", sa.String(128), primary_key=True),
    sa.Column("received_at", sa.Float, nullable=False),
    sa.Column("n_rows", sa.Integer, nullable=False),
    sa.Column("n_new", sa.Integer, nullable=False),
    sa.Column("t_first", sa.Float, nullable=False),
    sa.Column("t_last", sa.Float, nullable=False),
    sa.Column("arrival", sa.String(16), nullable=False),  # "in order", "out of order", "late"
)
samples = sa.Table(
    "samples", metadata,
    sa.Column("bus_id", sa.Integer, primary_key=True),
    sa.Column("t", sa.Float(53), primary_key=True),
    sa.Column("batch_id", sa.String(128), nullable=False),
    *(sa.Column(c, sa.Float, nullable=c != "speed_kmh") for c in SAMPLE_COLUMNS),
    sqlite_with_rowid=False,
)
minutes = sa.Table(
    "minute_aggregates", metadata,
    sa.Column("bus_id", sa.Integer, primary_key=True),
    sa.Column("t", sa.Float(53), primary_key=True),  # the minute's start
    sa.Column("n", sa.Integer, nullable=False),
    sa.Column("speed_kmh", sa.Float, nullable=False),  # mean
    sa.Column("speed_kmh_max", sa.Float, nullable=False),
    sa.Column("distance_km", sa.Float, nullable=False),
    sa.Column("soc_pct", sa.Float),  # last of the minute
    sa.Column("soc_pct_min", sa.Float),
    sa.Column("ambient_degc", sa.Float),
    sa.Column("charging", sa.Float),  # share of the minute
    sa.Column("charger_kw", sa.Float),  # max
    sa.Column("door_open", sa.Float),  # share of the minute
    sqlite_with_rowid=False,
)
schedules = sa.Table(
    "schedules", metadata,
    sa.Column("bus_id", sa.Integer, primary_key=True),
    sa.Column("day", sa.String(10), primary_key=True),
    sa.Column("block", sa.Text, nullable=False),  # JSON
)
service_days = sa.Table(
    "service_days", metadata,
    sa.Column("bus_id", sa.Integer, primary_key=True),
    sa.Column("day", sa.String(10), primary_key=True),
    sa.Column("t_start", sa.Float, nullable=False),
    sa.Column("t_end", sa.Float, nullable=False),
    sa.Column("finished_at", sa.Float, nullable=False),
    sa.Column("state", sa.String(16), nullable=False),  # "finished", "diagnosed", "failed"
)
fits = sa.Table(
    "fits", metadata,
    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("bus_id", sa.Integer, nullable=False, index=True),
    sa.Column("kind", sa.String(16), nullable=False),  # "window" or "cross-day"
    sa.Column("fitted_at", sa.Float, nullable=False),
    sa.Column("t_from", sa.Float, nullable=False),
    sa.Column("t_to", sa.Float, nullable=False),
    sa.Column("fit_values", sa.Text, nullable=False),  # JSON: qualified name -> value
    sa.Column("nrmse", sa.Float),
    sa.Column("wall_s", sa.Float),
)
diagnoses = sa.Table(
    "diagnoses", metadata,
    sa.Column("bus_id", sa.Integer, primary_key=True),
    sa.Column("day", sa.String(10), primary_key=True),
    sa.Column("diagnosed_at", sa.Float, nullable=False),
    sa.Column("verdict", sa.String(64)),
    sa.Column("status", sa.String(32), nullable=False),
    sa.Column("finding", sa.String(64), nullable=False),
    sa.Column("why", sa.Text, nullable=False),
    sa.Column("sentence", sa.Text, nullable=False),
)
alarms = sa.Table(
    "alarms", metadata,
    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("bus_id", sa.Integer, nullable=False, index=True),
    sa.Column("kind", sa.String(32), nullable=False),  # "reserve", "diagnosis"
    sa.Column("raised_at", sa.Float, nullable=False),  # wall clock
    sa.Column("data_t", sa.Float, nullable=False),  # the bus's sample time it was known at
    sa.Column("day", sa.String(10), nullable=False),
    sa.Column("message", sa.Text, nullable=False),
    sa.Column("lead_s", sa.Float),  # how early it was known (reserve alarms)
)
predictions = sa.Table(
    "predictions", metadata,
    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("bus_id", sa.Integer, nullable=False, index=True),
    sa.Column("day", sa.String(10), nullable=False),
    sa.Column("made_at", sa.Float, nullable=False),
    sa.Column("data_t", sa.Float, nullable=False),
    sa.Column("end_soc_pct", sa.Float, nullable=False),
    sa.Column("end_low_pct", sa.Float, nullable=False),
    sa.Column("end_high_pct", sa.Float, nullable=False),
    sa.Column("min_high_pct", sa.Float, nullable=False),
    sa.Column("detail", sa.Text, nullable=False),  # JSON: chargers, members, ...
)


def database_url(db: str | Path) -> str:
    """A SQLAlchemy URL for ``db``: a ``postgresql://`` URL (given to psycopg 3), any other
    SQLAlchemy URL as given, or a file path (SQLite)."""
    text = str(db)
    if text.startswith(("postgresql://", "postgres://")):
        return "postgresql+psycopg://" + text.split("://", 1)[1]
    if "://" in text:
        return text
    path = Path(text).expanduser()
    if path.is_dir():
        raise ConfigError(f"--db {path}: a folder; give a database file (twin.sqlite) or a "
                          "postgresql:// URL.")
    path.parent.mkdir(parents=True, exist_ok=True)
    return f"sqlite:///{path.resolve()}"


def _sqlite_pragmas(dbapi_connection, _record) -> None:
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA journal_mode=WAL")
    cursor.execute("PRAGMA synchronous=FULL")
    cursor.execute("PRAGMA busy_timeout=30000")  # writers of other processes wait, not fail
    cursor.close()


class Store:
    """An engine on the twin's database, its schema migrated to the newest revision."""

    def __init__(self, url: str, migrate: bool = True):
        self.url = url
        self.dialect = url.split(":", 1)[0].split("+")[0]
        kwargs = {"pool_pre_ping": True}
        if self.dialect == "sqlite":
            kwargs["connect_args"] = {"check_same_thread": False, "timeout": 30}
        self.engine = sa.create_engine(url, **kwargs)
        if self.dialect == "sqlite":
            event.listen(self.engine, "connect", _sqlite_pragmas)
        if migrate:
            upgrade(self.engine)

    def __repr__(self) -> str:
        return f"Store({self.engine.url.render_as_string(hide_password=True)})"

    def insert(self, table: sa.Table):
        """``INSERT`` of this dialect, for ``on_conflict_do_nothing``."""
        if self.dialect == "postgresql":
            from sqlalchemy.dialects.postgresql import insert
        else:
            from sqlalchemy.dialects.sqlite import insert
        return insert(table)

    def bus_id(self, conn, name: str) -> int | None:
        return conn.execute(sa.select(buses.c.id).where(buses.c.name == name)).scalar()

    def add_bus(self, name: str, fleet: str, reserve_soc_pct: float | None = None) -> int:
        """The bus's id; the bus (and its fleet) created when new. A bus belongs to one fleet."""
        with self.engine.begin() as conn:
            row = conn.execute(sa.select(buses.c.id, buses.c.fleet)
                               .where(buses.c.name == name)).first()
            if row is not None:
                if row.fleet != fleet:
                    raise ConfigError(f"bus '{name}' belongs to fleet '{row.fleet}', not "
                                      f"'{fleet}'.")
                if reserve_soc_pct is not None:
                    conn.execute(buses.update().where(buses.c.id == row.id)
                                 .values(reserve_soc_pct=reserve_soc_pct))
                return row.id
            conn.execute(self.insert(fleets).values(name=fleet).on_conflict_do_nothing())
            values = {"name": name, "fleet": fleet}
            if reserve_soc_pct is not None:
                values["reserve_soc_pct"] = reserve_soc_pct
            return conn.execute(buses.insert().values(**values)).inserted_primary_key[0]

    def bus_names(self, fleet: str | None = None) -> list[str]:
        query = sa.select(buses.c.name).order_by(buses.c.name)
        if fleet is not None:
            query = query.where(buses.c.fleet == fleet)
        with self.engine.connect() as conn:
            return list(conn.execute(query).scalars())

    def put_schedule(self, bus: str, day: str, block: dict) -> None:
        with self.engine.begin() as conn:
            bus_id = self.bus_id(conn, bus)
            if bus_id is None:
                raise ConfigError(f"unknown bus '{bus}'")
            conn.execute(schedules.delete().where(schedules.c.bus_id == bus_id,
                                                  schedules.c.day == day))
            conn.execute(schedules.insert().values(bus_id=bus_id, day=day,
                                                   block=json.dumps(block)))

    def schedule(self, bus_id: int, day: str) -> dict | None:
        text = self.schedule_text(bus_id, day)
        return None if text is None else json.loads(text)

    def schedule_text(self, bus_id: int, day: str) -> str | None:
        """The bus's block for ``day`` as stored (JSON text), or None."""
        with self.engine.connect() as conn:
            return conn.execute(sa.select(schedules.c.block).where(
                schedules.c.bus_id == bus_id, schedules.c.day == day)).scalar()


def alembic_config(url: str | None = None):
    from alembic.config import Config

    cfg = Config()
    cfg.set_main_option("script_location", str(Path(__file__).parent / "migrations"))
    if url:
        cfg.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    return cfg


def upgrade(engine: sa.Engine, revision: str = "head") -> None:
    """Migrate the database to ``revision`` (Alembic ``upgrade``), on ``engine``'s own
    connection (an SQLite file, a PostgreSQL database). Concurrent twin processes that start
    together serialise here on PostgreSQL's advisory lock."""
    from alembic import command

    cfg = alembic_config()
    with engine.begin() as conn:
        if engine.dialect.name == "postgresql":
            conn.execute(sa.text("SELECT pg_advisory_xact_lock(690069)"))
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, revision)


def open_store(db: str | Path = "twin.sqlite", migrate: bool = True) -> Store:
    """The store at ``db`` (a file path for SQLite, or a ``postgresql://`` URL)."""
    return Store(database_url(db), migrate=migrate)
