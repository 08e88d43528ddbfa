"""A depot's morning: from a folder of logger files to the buses that need a workshop visit.

:func:`run_depot` cuts the folder into service days per bus
(:mod:`~ebus_env.depot.bus_days`), diagnoses each bus over its service days with
:func:`ebus_env.diagnostics.diagnose` (``calibrate=True``: the bus's own parameters fitted to
its days), and writes a fleet summary: ``summary.csv`` (one row per bus), ``files.csv`` (one
row per logger file, with its frame counts), ``index.html``, and per bus the diagnosis report
(``buses/<bus>.html``, ``buses/<bus>.json``).

The diagnosis is read only through its public result: ``verdict`` (the effect it names, or
None), ``status`` (how it ended), ``why`` and ``sentence``. :func:`action` turns them into what
the depot does with the bus:

=================  ==========================================================================
action             when
=================  ==========================================================================
``workshop``       the diagnosis names a missing effect (a verdict: a regen limit, a cold pack,
                   a cabin load, ...): something on the bus draws or loses power its model
                   does not, and the report says what and how much
``watch``          power is missing but no effect is named: ``outside library`` (no library
                   effect explains it; the diagnosis says that a day with nothing wrong can
                   end so too), ``tie``, ``implausible``, ``parameter``, or a status this
                   table does not know; look again with more days, and at the report's clues
``ok``             nothing missing above the noise (status ``noise``)
``no diagnosis``   too few usable windows, no service day long enough, or an error (named)
=================  ==========================================================================
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from ebus_env.depot.bus_days import BusDay, DepotDays, safe_name, split_depot
from ebus_env.depot.loggers import read_logger_map
from ebus_env.depot.service_days import DEFAULT_RULE, DayRule
from ebus_env.errors import ConfigError, EbusError
from ebus_env.io.can_map import load_signal_map
from ebus_env.outputs import atomic, check_folder

ACTIONS = ("workshop", "watch", "ok", "no diagnosis")
OK_STATUSES = ("noise",)
NO_DIAGNOSIS_STATUSES = ("too few windows",)


def action(verdict: str | None, status: str) -> str:
    """What the depot does with a bus, from its diagnosis (see the module docstring)."""
    if verdict:
        return "workshop"
    if status in OK_STATUSES:
        return "ok"
    if status in NO_DIAGNOSIS_STATUSES:
        return "no diagnosis"
    return "watch"


@dataclass
class BusResult:
    """One bus's diagnosis over its service days, as the summary shows it."""

    bus: str
    days: list[BusDay]
    diagnosed: list[BusDay]
    action: str = "no diagnosis"
    verdict: str | None = None
    status: str = ""
    why: str = ""
    sentence: str = ""
    report: Path | None = None
    seconds: float = 0.0

    def row(self, out: Path) -> dict:
        dates = [d.first[:10] for d in self.diagnosed]
        return {"bus": self.bus, "action": self.action, "verdict": self.verdict or "",
                "status": self.status, "days": len(self.days),
                "days_diagnosed": len(self.diagnosed),
                "first_day": min(dates) if dates else "", "last_day": max(dates) if dates else "",
                "hours": round(sum(d.hours for d in self.diagnosed), 2), "why": self.why,
                "sentence": self.sentence,
                "report": os.path.relpath(self.report, out) if self.report else ""}


@dataclass
class DepotRun:
    """What :func:`run_depot` found and wrote."""

    folder: Path
    out: Path
    days: DepotDays
    buses: list[BusResult] = field(default_factory=list)
    summary: Path | None = None
    html: Path | None = None

    @property
    def workshop(self) -> list[BusResult]:
        return [b for b in self.buses if b.action == "workshop"]


def diagnose_bus(bus_config, days: list[BusDay], *, calibrate: bool, gaps: str, fill: str,
                 progress=None, domain: str = "soc"):
    """The diagnosis of one bus over its service days (their canonical logs read with every
    check of :func:`~ebus_env.io.measured.load_log`): the library's
    :func:`~ebus_env.diagnostics.diagnose` on the days' profiles, each keeping its date, in
    ``domain`` (``power``: the bus fitted to its logged power, second by second or by the
    SoC's count in each window, which takes the place of the SoC calibration)."""
    from ebus_env.diagnostics import diagnose
    from ebus_env.io.measured import load_log

    profiles, notes = [], []
    for day in days:
        log = load_log(day.path, gaps=gaps, fill=fill, name=day.path.name.split(".")[0])
        profiles += log.profiles
        notes += [f"{day.path.name}: {line}" for line in
                  day.notes + log.report.changes + log.report.warnings]
    return diagnose(bus_config, profiles, calibrate=calibrate and domain != "power",
                    loader_notes=notes, progress=progress, domain=domain)


def run_depot(folder: str | Path, logger_map: str | Path, out: str | Path, *, bus_config=None,
              signal_map: str | Path | dict = "ebus_j1939", rule: DayRule = DEFAULT_RULE,
              calibrate: bool = True, diagnose: bool = True, gaps: str = "split",
              fill: str = "error", command: str = "", progress=None,
              domain: str = "soc") -> DepotRun:
    """Cut the depot's folder into service days per bus, diagnose each bus over them and write
    the fleet summary into ``out`` (see the module docstring). ``bus_config``: the
    :class:`~ebus_env.config.BusConfig` of every bus (default ``load_bus('12m')``);
    ``domain``: how each bus is diagnosed (:data:`~ebus_env.diagnostics.power_stage.DOMAINS`)."""
    import time

    from ebus_env.config import load_bus
    from ebus_env.diagnostics.power_stage import DOMAINS

    if domain not in DOMAINS:
        raise ConfigError(f"run_depot: domain={domain!r} is not one of {', '.join(DOMAINS)}. "
                          "Fix: soc (SoC windows), power (the logged power second by second) "
                          "or auto.")
    folder, out = Path(folder), Path(out)
    say = progress or (lambda text: None)
    if not folder.is_dir():
        raise ConfigError(f"{folder} is not a folder. Fix: give the folder of the loggers' "
                          "files.")
    if out.resolve() == folder.resolve() or folder.resolve() in out.resolve().parents:
        raise ConfigError(f"--out {out} is inside the depot folder {folder}, whose files are "
                          "the inputs. Fix: write the report elsewhere.")
    from ebus_env.io.measured import FILL_POLICIES, GAP_POLICIES

    if gaps not in GAP_POLICIES or fill not in FILL_POLICIES:
        raise ConfigError(f"--gaps must be one of {', '.join(GAP_POLICIES)} and --fill one of "
                          f"{', '.join(FILL_POLICIES)}; got '{gaps}' and '{fill}'.")
    check_folder(out, "--out", inputs=[Path(logger_map)])
    smap = load_signal_map(signal_map)
    loggers = read_logger_map(logger_map, smap.timezone)
    bus_config = bus_config or load_bus("12m")
    days = split_depot(folder, loggers, smap, out, rule, say)
    run = DepotRun(folder, out, days)
    for bus in days.buses:
        all_days = days.of(bus)
        result = BusResult(bus, all_days, [d for d in all_days if d.usable(rule)])
        run.buses.append(result)
        if not result.diagnosed:
            result.why = (f"no service day of {rule.min_day_h:g} h or more" if all_days else
                          "no service day")
            continue
        if not diagnose:
            result.why = "not diagnosed (--no-diagnose)"
            continue
        t0 = time.perf_counter()
        try:
            diagnosis = diagnose_bus(bus_config, result.diagnosed, calibrate=calibrate,
                                     gaps=gaps, fill=fill, domain=domain,
                                     progress=lambda text, b=bus: say(f"{b}: {text}"))
        except EbusError as exc:
            result.why = f"error: {exc}"
            continue
        result.seconds = time.perf_counter() - t0
        result.verdict, result.status = diagnosis.verdict, diagnosis.status
        result.why, result.sentence = diagnosis.why, diagnosis.sentence
        result.action = action(diagnosis.verdict, diagnosis.status)
        report = out / "buses" / f"{safe_name(bus)}.html"
        report.parent.mkdir(parents=True, exist_ok=True)
        with atomic(report) as tmp:
            diagnosis.write_html(tmp)
        with atomic(report.with_suffix(".json")) as tmp:
            diagnosis.write_json(tmp)
        result.report = report
    from ebus_env.depot.fleet_summary import write_summary

    write_summary(run, smap, loggers, rule, command)
    return run
