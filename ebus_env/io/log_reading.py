"""How a run reads its measured logs (the commands' ``--columns``, ``--gaps``, ``--fill``,
``--no-unit-check``, ``--start-time``), the loader's report said as it reads them, and the
refusal of a log given twice."""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from ebus_env.errors import ConfigError
from ebus_env.io.measured import load_log
from ebus_env.outputs import same_bytes, same_file

if TYPE_CHECKING:
    from rich.console import Console

LOG_PATTERNS = ("*.csv", "*.csv.gz", "*.parquet")
"""The logs a folder given in place of logs holds."""

MAX_ACCEL_MPS2 = 4.0
"""Steps of a log that accelerate faster than this are reported by the loader: the model cannot
follow them exactly."""


def logs_in(paths, option: str = "LOGS") -> list[Path]:
    """``paths`` with each folder replaced by its logs (:data:`LOG_PATTERNS`), sorted by
    name: a folder of one bus's days reads as its days in order."""
    out: list[Path] = []
    for path in map(Path, paths):
        if not path.is_dir():
            out.append(path)
            continue
        logs = sorted({p for pattern in LOG_PATTERNS for p in path.glob(pattern)})
        if not logs:
            raise ConfigError(f"{option} {path}: no logs in the folder "
                              f"({', '.join(LOG_PATTERNS)}); give the folder of the logs, or "
                              "the logs themselves.")
        out += logs
    return out


def clock_h(text: str) -> float:
    """``HH:MM`` or ``HH:MM:SS`` as hours after midnight."""
    parts = text.split(":")
    try:
        if not 2 <= len(parts) <= 3:
            raise ValueError
        h, m, sec = (int(p) for p in parts + ["0"] * (3 - len(parts)))
    except ValueError:
        raise ConfigError(f"--start-time needs HH:MM (e.g. 07:30), got '{text}'.") from None
    if not (0 <= h <= 23 and 0 <= m <= 59 and 0 <= sec <= 59):
        raise ConfigError(f"--start-time {text} is not a time of day: give HH:MM with HH "
                          "0-23 and MM 0-59.")
    return h + m / 60 + sec / 3600


@dataclass(frozen=True)
class LogReading:
    """How measured logs are read (see :func:`~ebus_env.io.measured.load_log`).

    Parameters
    ----------
    columns
        Column map preset (``configs/logs``), e.g. ``bmw_i3_tum``; None for canonical names.
    gaps
        A gap in the rows: ``error``, ``split``, ``hold`` or ``interpolate``.
    fill
        A missing value: ``error`` or ``interpolate``.
    check_units
        Refuse a speed that looks like m/s and a SoC that looks like a fraction.
    start_time
        Clock time ``HH:MM`` of the first row of a log without date-times (else 00:00).
    """

    columns: str | None = None
    gaps: str = "error"
    fill: str = "error"
    check_units: bool = True
    start_time: str | None = None

    @property
    def start_h(self) -> float | None:
        """The start time in hours after midnight (None: not given)."""
        return None if self.start_time is None else clock_h(self.start_time)

    def load(self, paths, model, params, console: Console | None = None,
             notes: list[str] | None = None) -> list:
        """The profiles of the logs ``paths`` for ``model`` with parameter vector ``params``
        (its top speed bounds the logged one); the loader's report is said on ``console``
        (a rich Console, or None) and its changes appended to ``notes``."""
        vmax = params[model.param_index("vehicle_body.max_speed_kmh")] \
            if model.has_effect("vehicle_body") else None
        start_h = self.start_h
        profiles = []
        for path in paths:
            log = load_log(path, model.dt_s, columns=self.columns, gaps=self.gaps,
                           fill=self.fill, check_units=self.check_units, max_speed_kmh=vmax,
                           max_accel_mps2=MAX_ACCEL_MPS2, start_h=start_h)
            profiles += log.profiles
            if notes is not None:
                notes += log.report.changes
            say_report(log.report, path, "loader", console)
        return profiles


def say_report(report, path, who: str, console: Console | None) -> None:
    """A loader's report on ``console`` (None: nowhere): its changes (dim), then its warnings
    and ignored columns."""
    if console is None:
        return
    from rich.markup import escape

    for line in report.changes:
        console.print(f"[dim]{who} ({Path(path).name}):[/] {escape(line)}", highlight=False,
                      soft_wrap=True)
    for line in report.warnings + report.ignored:
        console.print(f"[yellow]{who} ({Path(path).name}):[/] {escape(line)}", highlight=False,
                      soft_wrap=True)


def refuse_same_log(option: str, given, logs, role: str, why: str) -> None:
    """Refuse a log of ``option`` that is one of ``logs`` (``role``) or a copy of it."""
    for other, log in itertools.product(given or [], logs):
        if Path(other).exists() and Path(log).exists() and (
                same_file(Path(other), Path(log)) or same_bytes(other, log)):
            raise ConfigError(f"{option} {other} is {role} ({log}) or a copy of it: {why}. "
                              "Fix: give a log of another day.")


def refuse_twice(logs) -> None:
    """Refuse a log given twice (or with a copy of it): its windows would count twice."""
    for i, log in enumerate(logs):
        refuse_same_log("log", logs[i + 1:], [log], "a log given already", "each day's windows "
                        "would count twice and its errors look more certain than they are")
