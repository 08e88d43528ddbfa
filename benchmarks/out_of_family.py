"""The out-of-family truth bench: service days from simulators that are not this model, each
with one hidden effect (or none), diagnosed and scored; single days and multi-day buses, on
BMS logs (the pack's current and voltage) and SoC-only logs, from three truth sources.

``python -m benchmarks.bench_diagnose --out-of-family`` runs it; other benchmarks import its
pieces (the cases, a cached day, the right-verdict rule). The figures are
:mod:`benchmarks.truth.scoring`'s.

A job is one day or one bus, of one source, on one log type (:class:`Job`). The whole bench is
its job list (:func:`jobs`); ``--shard i/n`` runs every n-th job from the i-th, ``--rows``
keeps each finished job's row, ``--resume`` skips the jobs a rows file has, and
``--from-rows`` reports rows files together. The days are generated once per source and case
(both log types and the oracle column from one run, cached: :func:`truth_day`).
"""

from __future__ import annotations

import json
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import pandas as pd

from benchmarks.truth import scoring
from benchmarks.truth.cache import day_paths
from benchmarks.truth.scoring import LOGS, line  # noqa: F401  (other benchmarks import line)
from ebus_env.config import load_bus
from ebus_env.diagnostics import diagnose
from ebus_env.diagnostics.ladder import Freedom, improvement
from ebus_env.io.measured import load_log
from ebus_env.outputs import write_text, write_with

BENCHMARKS = Path(__file__).resolve().parent
USER_FILE = BENCHMARKS / "user_effects.py"
USER_EFFECTS = {"battery_chiller": f"{USER_FILE}:pack_chiller",
                "air_compressor": f"{USER_FILE}:air_compressor",
                "dragging_brake": f"{USER_FILE}:brake_drag",
                "underinflated_tyres": f"{USER_FILE}:soft_tyres"}
"""For each load or force the library does not have, the effect a user writes for it
(``benchmarks/user_effects.py``): what the error ladder adds on those days."""
CONTROL_ADDS = ("cabin_hvac", "passenger_mass", "road_grade", "aux_schedule",
                "regen_soc_limit", "ambient_battery")
"""On a control day the ladder adds one of these library effects (in turn, by the day's
index): what adding an effect that is not there does to the held-out error, the spread an
effect day's rise is read against."""

ORACLE = "replayed_load"
"""On an oracle day (``--oracle``) the log carries the hidden effect's own power, the day with
the effect against the same day without it, as ``logged_load_kw``; this library effect
replays it. Named, or added, it is the hidden effect in a perfect form: what the diagnosis
and the error ladder reach when the library's form is not what limits them."""
BASELINE_WITHOUT = ("cabin_hvac", "passenger_mass", "road_grade")
"""The baseline of the out-of-family bench: the 12 m bus without every sink effect that a
truth day may hide (the slot effects that may be hidden, regen_soc_limit and ambient_battery,
are refinements the 12 m bus does not have, and aux_schedule is not on it)."""
CELLS_PARALLEL = 3.0  # the 12 m pack's strings: the truth's pack capacity is theirs together
SOURCES = {"truthsim": "benchmarks.truth.cases", "fastsim": "benchmarks.truth.fastsim_source",
           "backward": "benchmarks.truth.backward_source"}
TUNE_SOURCE = "truthsim"
"""The source the diagnosis's thresholds, priors and rules are set on; the figures of the
others are the held-out ones."""
SMOKE_HOURS = 4.0
DAYS_CACHE = Path(tempfile.gettempdir()) / "ebus-truth-days"  # the generated days, by default
BMS_COLUMNS = ("battery_current_a", "battery_voltage_v")
ORACLE_COLUMN = "logged_load_kw"
KINDS = ("day", "bus")


@dataclass(frozen=True)
class Job:
    """One unit of the bench: a single day (``kind`` "day", ``item`` a ``Case``) or a
    multi-day bus (``kind`` "bus", ``item`` a ``Bus``) of a source, diagnosed from one log
    type (``log`` "bms" or "soc")."""

    source: str
    log: str
    kind: str
    item: object
    folder: str
    oracle: bool = False
    reference: bool = False
    known_mass: bool = False
    days: int = 1
    domain: str = "soc"  # "power": BMS logs second by second, SoC-only logs by window

    @property
    def key(self) -> tuple[str, str, str, str]:
        return (self.source, self.log, self.kind, item_id(self.item))


def item_id(item) -> str:
    return getattr(item, "bus_id", None) or item.case_id


def row_key(row: dict) -> tuple[str, str, str, str]:
    """The job a row belongs to (rows of earlier runs: a day, its log type inferred)."""
    return (row["source"], scoring.log_of(row), scoring.kind_of(row), row["case"])


def truth_module(source: str):
    """The truth source's module, or the reason it cannot be used."""
    import importlib

    try:
        return importlib.import_module(SOURCES[source]), ""
    except ImportError as exc:  # fastsim not installed, or the source not there
        return None, f"{source} not available ({exc})"


def truth_cases(source: str, smoke: bool, per_effect: int | None = None,
                controls: int | None = None, effects: tuple[str, ...] = ()) -> list:
    """The single days of a source: the whole bench (or its first ``per_effect`` days of each
    effect, of ``effects`` only when given, and first ``controls`` control days), or 1 day
    per effect and 3 controls, each the last ``SMOKE_HOURS`` of its day (so that an evening
    load stays in it)."""
    module, _ = truth_module(source)
    if not smoke:
        return first_of(module.cases(), lambda c: c.hidden, per_effect, controls, effects)
    return [replace(c, start_clock_h=round(c.start_clock_h + max(c.hours - SMOKE_HOURS, 0), 3),
                    hours=min(c.hours, SMOKE_HOURS)) for c in module.cases(1, 3)]


def truth_buses(source: str, per_condition: int | None = None, controls: int | None = None,
                conditions: tuple[str, ...] = ()) -> list:
    """The multi-day buses of a source (its first ``per_condition`` buses of each condition,
    of ``conditions`` only when given, and its first ``controls`` control buses)."""
    module, _ = truth_module(source)
    return first_of(module.buses(), lambda b: b.condition, per_condition, controls, conditions)


def first_of(items: list, hidden_of, per_kind: int | None, controls: int | None,
             kinds: tuple[str, ...]) -> list:
    """The first ``per_kind`` items of each hidden effect (of ``kinds`` only, when given) and
    the first ``controls`` control items (hidden None), in the list's order (None: all)."""
    taken: dict = {}
    out = []
    for item in items:
        hidden = hidden_of(item)
        limit = controls if hidden is None else per_kind
        taken[hidden] = taken.get(hidden, 0) + 1
        if (limit is None or taken[hidden] <= limit) and (
                not kinds or hidden is None or hidden in kinds):
            out.append(item)
    return out


def _write_csv(frame: pd.DataFrame, path: Path) -> None:
    # a temporary file of its own: two runs that share a cache may write the same day at once
    write_with(path, lambda tmp: frame.to_csv(tmp, index=False, compression="gzip"))


def generate_day(source: str, case, folder: Path) -> tuple[Path, Path]:
    """Generate a day once: its whole log (the pack's current and voltage and the oracle
    column: every variant is this log less columns) and its truth record, cached in
    ``folder``. A case cut shorter (the smoke run's last hours of a day) is cached under its
    own name. Returns the paths of the whole log and the record."""

    log_path, truth_path = day_paths(folder, source, case)
    if not truth_path.exists():
        module, _ = truth_module(source)
        log, truth = module.generate(case, current_voltage=True, oracle=True)
        _write_csv(log, log_path)
        write_text(truth_path, json.dumps(truth, default=str))  # the record last: the day is whole
    return log_path, truth_path


def truth_day(source: str, case, folder: Path, current_voltage: bool = False,
              oracle: bool = False):
    """A truth day's profiles and truth record: the SoC-only log, or with the pack's
    current and voltage (``current_voltage``, a BMS log), with the hidden effect's own power
    (``oracle``, column ``logged_load_kw``) or not; each variant is the generated day's whole
    log less the columns it lacks (:func:`generate_day`), written once beside it."""
    log_path, truth_path = generate_day(source, case, Path(folder))
    variant = ("bms" if current_voltage else "soc") + ("-oracle" if oracle else "")
    path = log_path.with_name(log_path.name.replace(".full.", f".{variant}."))
    truth = json.loads(truth_path.read_text())
    drop = [c for c in truth["columns"] if (c in BMS_COLUMNS and not current_voltage)
            or (c == ORACLE_COLUMN and not oracle)]
    if not path.exists():
        _write_csv(pd.read_csv(log_path).drop(columns=drop), path)
    truth["columns"] = [c for c in truth["columns"] if c not in drop]
    return load_log(path).profiles, truth


def truth_bus(source: str, bus, folder: Path, current_voltage: bool = False):
    """A multi-day bus: the profiles of all its days (each keeping its date), its days'
    truth records and the bus's truth record."""
    module, _ = truth_module(source)
    profiles, records = [], []
    for case in bus_days_of(source, bus):
        more, truth = truth_day(source, case, folder, current_voltage)
        profiles += more
        records.append(truth)
    truth = module.bus_truth(getattr(bus, "bus", bus), records)
    return profiles, records, {**truth, "bus_id": bus.bus_id}


def same_bus_days(case, days: int) -> list:
    """The cases of ``days - 1`` more days of the bus of ``case`` (the truth simulator's:
    FASTSim's cases draw their hidden effect per day)."""
    from benchmarks.truth.cases import same_bus_case

    return [same_bus_case(case, day) for day in range(1, days)]


def named_right(expected, verdict: str | None, status: str, effects: list[str],
                oracle: bool) -> bool:
    """Whether a day's verdict is right: the expected effect (None on a control day: no
    verdict); on an oracle day also :data:`ORACLE`, the only right one for a load outside the
    library, or a tie of the library's effect and its perfect form (``effects``: the effect
    candidates, best first)."""
    right = {ORACLE} if oracle and expected == "outside_library" else \
        {expected, ORACLE} if oracle else {expected}
    tied = set(effects[:2]) if status == "tie" else set()
    return verdict in right or (oracle and tied == {expected, ORACLE})


def _verdict_row(d, truth: dict, source: str, name: str, hidden, oracle: bool) -> dict:
    """The row fields every job shares: the verdict and what it rests on."""
    plain = d.to_json()
    row = {"source": source, "case": name, "hidden": hidden,
           "expected": truth["expected_verdict"],
           "outside_modes": truth.get("outside_modes") or [],
           "truth": truth.get("strength", {}),
           "verdict": d.verdict, "status": d.status, "clue": d.mode_clue,
           # the missing power by operating mode the clue is read from, and what it moves
           # with: for analyses of the clue's rule
           "modes": plain["modes"], "clues": plain["clues"][:5],
           # on a BMS log: the pack's resistance the logged voltage shows, over the model's
           "resistance": {k: d.resistance[k] for k in ("level", "span", "significance",
                                                       "changes")} if d.resistance else None,
           "top": d.ranking[0]["effect"] if d.ranking else None,
           "estimate": d.named["parameters"] if d.verdict else {},
           "interval": d.named["interval"] if d.verdict else {},
           # the energy the named effect adds over the day, against the truth's: the one
           # strength two structurally different models share (a UA or a derating SoC is
           # defined by each model's own form)
           "energy_kwh": d.named.get("energy_kwh") if d.verdict else None,
           "energy_interval_kwh": d.named.get("energy_interval_kwh") if d.verdict else None,
           "truth_kwh": truth.get("summary", {}).get("effect_kwh"),
           "footprint_pct": truth.get("summary", {}).get("soc_footprint_pct"),
           "why": d.why, "range_ends": d.range_ends}
    # the day a change started, where the diagnosis dates one (a bus's days together)
    for key in ("since", "since_interval"):
        if key in plain:
            row[key] = plain[key]
    row["right"] = named_right(row["expected"], d.verdict, d.status,
                               [r["effect"] for r in d.ranking], oracle)
    return row


def diagnose_truth_day(job, ladder: bool = True) -> dict:
    """Diagnose one truth day and (``ladder``) measure the error's fall with the right effect
    added (worker of the pool): a SoC-only log calibrated, the effect added and the bus
    re-calibrated (the held-out SoC NRMSE's fall); a BMS log in the power domain, the bus
    fitted to the logged power (the held-out missing power's fall). ``job``: a
    :class:`Job`, or the tuple ``(source, case, folder[, current_voltage, oracle, reference,
    known_mass, days])``. On an oracle day (the
    log carries the hidden effect's own power) the right effect is the library's or
    :data:`ORACLE`, and the ladder adds :data:`ORACLE`: the hidden effect in a perfect form.
    On a control day the ladder adds one of :data:`CONTROL_ADDS`. With ``days`` > 1 the
    case's day and ``days - 1`` more days of the same bus
    (:func:`~benchmarks.truth.cases.same_bus_case`) are diagnosed together, as one bus's
    logs."""
    from ebus_env.diagnostics.ladder import error_ladder, split_blocks

    if isinstance(job, Job):
        source, case, folder, current_voltage = job.source, job.item, job.folder, job.log == "bms"
        oracle, reference, known_mass, days = job.oracle, job.reference, job.known_mass, job.days
    else:
        source, case, folder, current_voltage, oracle, reference, known_mass, days = (
            *job, False, False, False, False, 1)[:8]
    profiles, truth = truth_day(source, case, Path(folder), current_voltage, oracle)
    for other in same_bus_days(case, days):
        more, their = truth_day(source, other, Path(folder), current_voltage, oracle)
        profiles = [*profiles, *more]
        truth["summary"]["effect_kwh"] += their["summary"]["effect_kwh"]
        truth["summary"]["soc_footprint_pct"] = max(truth["summary"]["soc_footprint_pct"],
                                                    their["summary"]["soc_footprint_pct"])
    bus = load_bus("12m", without=list(BASELINE_WITHOUT))
    freedom = None
    if known_mass:  # a weighed bus: its true curb mass held (the 12 m config's mass bounds
        # widened to the bench's spread of +-15 %)
        bus = replace(bus, bounds={**bus.bounds, "vehicle_body": {
            **bus.bounds.get("vehicle_body", {}), "curb_mass_kg": [9000.0, 17000.0]}})
        freedom = Freedom(fixed={"vehicle_body.curb_mass_kg": truth["base"]["curb_mass_kg"]})
    t0, cpu0 = time.perf_counter(), time.process_time()
    if reference:  # a normal day of the same bus
        from benchmarks.truth.cases import reference_case
        from ebus_env.diagnostics.stage02_reference import reference_stage

        normal_day = truth_day(source, reference_case(case), Path(folder), current_voltage)[0]
        reference = reference_stage(bus, normal_day)
    expected = truth["expected_verdict"]
    # the right effect: the library's, or for a load it lacks the user's own file; on an
    # oracle day the hidden effect's own power; on a control day an effect that is not there
    added = (ORACLE if oracle else USER_EFFECTS.get(case.hidden)
             if expected == "outside_library" else
             CONTROL_ADDS[_index(case.case_id) % len(CONTROL_ADDS)] if expected is None
             else expected)
    # the power domain: a BMS log second by second, a SoC-only log by window
    power = isinstance(job, Job) and job.domain == "power" and not reference
    if power:  # the bus fitted to the logged power; each library candidate's held-out fall
        d = diagnose(bus, profiles, freedom=freedom, domain="power")
    else:
        d = diagnose(bus, profiles, calibrate=True, reference=reference or None,
                     freedom=freedom)
    if reference:  # the ladder searches as the diagnosis did
        bus = bus.overlay(reference.overlay(), "the reference day")
        freedom = reference.freedom(bus.build(profiles[0].dt_s), freedom)
    row = {"cpu_s": time.process_time() - cpu0, "log": "bms" if current_voltage else "soc",
           "kind": "day", "domain": d.domain,
           **_verdict_row(d, truth, source, case.case_id, case.hidden, oracle),
           "days": days, "time_s": time.perf_counter() - t0,
           "hours": sum(p.duration_s for p in profiles) / 3600.0, "added": added}
    if ladder and added and power:  # the held-out missing power's fall (none where the
        # effect was set aside: its inputs do not move along the log)
        fall = power_fall(d, bus, profiles, added, freedom)
        if fall is not None:
            row["fall"] = fall
    elif ladder and added:
        rungs = error_ladder(bus, profiles, [added], profiles[0].dt_s,
                             first=d.ladder[0], blocks=split_blocks(profiles), freedom=freedom)
        row["nrmse"] = (rungs[0].held_out["nrmse"], rungs[-1].held_out["nrmse"])
        row["fall"] = improvement(rungs)
        # against the diagnosis's own calibration, where the ladder searched the bus without
        # the effect again from where the bus with it ended and found it fitting better
        row["fall_first_search"] = improvement([d.ladder[0], rungs[-1]])
        if "charge_nrmse" in rungs[0].held_out:  # a BMS log: the counted charge's fall too
            row["fall_charge"] = improvement(rungs, "charge_nrmse")
        row["added_values"] = {k: v for k, v in rungs[-1].values.items()
                               if k.split(".")[0] == rungs[-1].effects[-1]}
    return row


def power_fall(d, bus, profiles, added, freedom) -> float | None:
    """The share of the held-out missing power ``added`` removes on a BMS log read second by
    second: a library effect's from the diagnosis ``d`` itself (it tests every library effect
    beside the bus's parameters); a user's effect from a second diagnosis with it added (the
    verdict stays ``d``'s, made without knowing the effect)."""
    from ebus_env.diagnostics.ladder import as_effect

    effect = as_effect(added)
    falls = d.nrmse.get("power_held_out_fall", {})
    if effect.name not in falls and not effect.builtin:
        falls = diagnose(bus, profiles, add=[added], freedom=freedom,
                         domain="power").nrmse.get("power_held_out_fall", {})
    return falls.get(effect.name)


def _index(case_id: str) -> int:
    """The trailing number of a case id (``control_07`` -> 7; 0 where there is none)."""
    tail = case_id.rsplit("_", 1)[-1]
    return int(tail) if tail.isdigit() else 0


def diagnose_truth_bus(job: Job) -> dict:
    """Diagnose a multi-day bus: all its days' logs in one call, calibrated, as
    ``diagnose(bus, profiles, calibrate=True)`` with each profile keeping its date (worker
    of the pool). The row carries the verdict, the diagnosis's ``since`` and
    ``since_interval`` where it gives them, and the truth's start day and dates."""
    bus_case = job.item
    profiles, records, truth = truth_bus(job.source, bus_case, Path(job.folder), job.log == "bms")
    bus = load_bus("12m", without=list(BASELINE_WITHOUT))
    t0, cpu0 = time.perf_counter(), time.process_time()
    # the power domain: the bus fitted to the logged power (a SoC-only log's by window)
    power = job.domain == "power"
    d = diagnose(bus, profiles, calibrate=not power, domain="power" if power else "soc")
    return {"cpu_s": time.process_time() - cpu0, "log": job.log, "kind": "bus",
            "domain": d.domain,
            **_verdict_row(d, truth, job.source, bus_case.bus_id, bus_case.condition, False),
            "condition_kind": truth["kind"], "start_day": truth["start_day"],
            "start_date": truth["start_date"], "dates": truth["dates"],
            "ambient_mean_degc": truth["ambient_mean_degc"],
            "days": len(records), "time_s": time.perf_counter() - t0,
            "hours": sum(p.duration_s for p in profiles) / 3600.0}


def run_job(job: Job, ladder: bool = True) -> dict:
    """A job's row: a day (with the error ladder, ``ladder``) or a bus."""
    return diagnose_truth_bus(job) if job.kind == "bus" else diagnose_truth_day(job, ladder)


def generate_job(job: Job) -> float:
    """Generate (or find cached) every day a job reads; returns the seconds it took."""
    t0 = time.perf_counter()
    folder = Path(job.folder)
    if job.kind == "bus":
        for case in bus_days_of(job.source, job.item):
            generate_day(job.source, case, folder)
    else:
        generate_day(job.source, job.item, folder)
        for other in same_bus_days(job.item, job.days):
            generate_day(job.source, other, folder)
        if job.reference:
            from benchmarks.truth.cases import reference_case

            generate_day(job.source, reference_case(job.item), folder)
    return time.perf_counter() - t0


def jobs(folder: Path, smoke: bool, sources: tuple[str, ...] = tuple(SOURCES),
         logs: tuple[str, ...] = LOGS, kinds: tuple[str, ...] = KINDS,
         per_effect: int | None = None, controls: int | None = None,
         effects: tuple[str, ...] = (), per_condition: int | None = None,
         control_buses: int | None = None, oracle: bool = False, reference: bool = False,
         known_mass: bool = False, days: int = 1, say=print) -> list[Job]:
    """The bench's job list in a fixed order: per source, its single days on each log type,
    then its buses on each log type (``smoke``: the smoke days, no buses)."""
    out = []
    for source in sources:
        module, why = truth_module(source)
        if module is None:
            say(f"  {why}: skipped")
            continue
        if "day" in kinds:
            if days > 1 and source != "truthsim":
                say(f"  {source}: its days draw their hidden effect each day, not per bus: "
                    "skipped")
            else:
                for log in logs:
                    out += [Job(source, log, "day", c, str(folder), oracle, reference,
                                known_mass, days)
                            for c in truth_cases(source, smoke, per_effect, controls, effects)
                            if not (oracle and c.hidden is None)]
        if "bus" in kinds and not smoke:
            for log in logs:
                out += [Job(source, log, "bus", b, str(folder))
                        for b in truth_buses(source, per_condition, control_buses, effects)]
    return out


CI_DAYS = {"truthsim": ("road_grade", "dragging_brake", None),
           "fastsim": ("road_grade", None),
           "backward": ("road_grade", None)}
"""The CI subset's single days of each source: its first day of these hidden effects (None:
a control day), the last ``CI_DAY_HOURS`` of it, from both log types."""
CI_BUSES = {"truthsim": "regen_soc_limit", "fastsim": "cabin_heating",
            "backward": "dragging_brake"}
"""The CI subset's multi-day bus of each source: its first bus of this condition, each of
its days cut to its last ``CI_BUS_DAY_HOURS``, from both log types."""
CI_DAY_HOURS = 2.5
CI_BUS_DAY_HOURS = 1.0


def cut(case, hours: float):
    """A case cut to the last ``hours`` of its day (an evening load stays in it)."""
    return replace(case, start_clock_h=round(case.start_clock_h + max(case.hours - hours, 0), 3),
                   hours=min(case.hours, hours))


@dataclass(frozen=True)
class CutBus:
    """A multi-day bus whose days are cut to their last ``hours`` (the CI subset's)."""

    bus: object
    hours: float

    @property
    def bus_id(self) -> str:
        return f"{self.bus.bus_id}-last{self.hours:g}h"

    @property
    def condition(self):
        return self.bus.condition


def ci_jobs(folder: Path, sources: tuple[str, ...] = tuple(SOURCES)) -> list[Job]:
    """The CI subset: per source (where it can run) its :data:`CI_DAYS` and its
    :data:`CI_BUSES` bus, each from both log types."""
    out = []
    for source in sources:
        if truth_module(source)[0] is None:
            continue
        listed = truth_cases(source, False, 1, 1)
        for hidden in CI_DAYS[source]:
            case = cut(next(c for c in listed if c.hidden == hidden), CI_DAY_HOURS)
            out += [Job(source, log, "day", case, str(folder)) for log in LOGS]
        bus = CutBus(next(b for b in truth_buses(source, 1, 0)
                          if b.condition == CI_BUSES[source]), CI_BUS_DAY_HOURS)
        out += [Job(source, log, "bus", bus, str(folder)) for log in LOGS]
    return out


def bus_days_of(source: str, bus) -> list:
    """A bus's days (a :class:`CutBus`'s cut)."""
    module, _ = truth_module(source)
    if isinstance(bus, CutBus):
        return [cut(day, bus.hours) for day in module.bus_days(bus.bus)]
    return module.bus_days(bus)


def shard_of(job_list: list[Job], shard: tuple[int, int] | None) -> list[Job]:
    """Every ``n``-th job from the ``i``-th (``shard`` = (i, n), i from 0): days and buses of
    every source alternate in the list, so the shards take alike."""
    if shard is None:
        return job_list
    i, n = shard
    return job_list[i::n]


def read_rows(path: Path) -> list[dict]:
    return json.loads(path.read_text()) if path.exists() else []


def write_rows(rows: list[dict], path: Path) -> None:
    write_text(path, json.dumps(rows, default=float, indent=1))


def print_row(row: dict) -> None:
    fall = f"; held-out fall {100 * scoring.fall_of(row):.0f} %" if "fall" in row else ""
    since = f"; since {row['since']}" if row.get("since") else ""
    line(f"{row['source']}/{row['log']}/{row['case']}", str(row["verdict"] or row["status"]),
         f"expected {row['expected']}; top {row['top']}; clue {row['clue']}; "
         f"{row['estimate'] or ''} (truth {row['truth'] or '-'})"
         + (f"; {row['energy_kwh']:.2f} kWh [{row['energy_interval_kwh'][0]:.2f}, "
            f"{row['energy_interval_kwh'][1]:.2f}] (truth {row['truth_kwh']:.2f})"
            if row["energy_kwh"] is not None else "") + fall + since
         + (f" (+ user's {row['added_values']})" if row["expected"] == "outside_library"
            and "added_values" in row else "") + f"; {row['time_s']:.0f} s"
         + ("" if row["verdict"] else f"; {row['why']}"))


def out_of_family(folder: Path, smoke: bool, workers: int = 2,
                  sources: tuple[str, ...] = tuple(SOURCES), per_effect: int | None = None,
                  controls: int | None = None, current_voltage: bool = False,
                  rows_path: Path | None = None, oracle: bool = False,
                  reference: bool = False, effects: tuple[str, ...] = (),
                  resume: bool = False, known_mass: bool = False, ladder: bool = True,
                  days: int = 1, *, logs: tuple[str, ...] | None = None,
                  kinds: tuple[str, ...] = KINDS, per_condition: int | None = None,
                  control_buses: int | None = None, shard: tuple[int, int] | None = None,
                  tune_source: str = TUNE_SOURCE, generate_only: bool = False,
                  power_domain: bool = False) -> list[dict]:
    """Run the bench's jobs (or a shard of them) and print the report of every row so far;
    ``smoke``: the CI subset (:func:`ci_jobs`; with ``oracle``, ``reference``, ``known_mass``
    or ``days``: the smoke days of :func:`truth_cases`).

    ``logs``: the log types (default both; ``current_voltage`` alone: BMS logs only, as
    before); ``kinds``: single days and/or multi-day buses (the oracle, reference,
    known-mass and days-per-bus variants are single days'); ``generate_only``: make and
    cache the days, diagnose nothing; ``power_domain``: the power path
    (``diagnose(domain="power")``): BMS logs second by second, SoC-only logs by the charge
    their SoC counts in each window, not the SoC windows' attribution."""
    from concurrent.futures import ProcessPoolExecutor
    from functools import partial
    from multiprocessing import get_context

    logs = logs or (("bms",) if current_voltage else LOGS)
    if oracle or reference or known_mass or days > 1:
        kinds = ("day",)
    print("\nOut-of-family truth bench (baseline: 12m --without " + ",".join(BASELINE_WITHOUT)
          + " --calibrate): " + ", ".join(scoring.LOG_NAMES[g] for g in logs) + "; "
          + " and ".join("single days" if k == "day" else "multi-day buses" for k in kinds)
          + (", logs with the hidden effect's own power (oracle; control days left out: "
             "they have none)" if oracle else "")
          + (", each against a normal day of the same bus (--reference)" if reference else "")
          + (", the true curb mass held (--known-curb-mass)" if known_mass else "")
          + (f", {days} days of each case's bus diagnosed together (--days-per-bus)"
             if days > 1 else "")
          + ("; the power domain (--power-domain)" if power_domain else "")
          + (f"; shard {shard[0]} of {shard[1]}" if shard else ""))
    if smoke and not (oracle or reference or known_mass or days > 1):  # the CI subset
        listed = [j for j in ci_jobs(folder, sources) if j.log in logs and j.kind in kinds]
    else:
        listed = jobs(folder, smoke, sources, logs, kinds, per_effect, controls, effects,
                      per_condition, control_buses, oracle, reference, known_mass, days)
    if power_domain:
        listed = [replace(j, domain="power") for j in listed]
    todo = shard_of(listed, shard)
    rows = []
    if resume and rows_path is not None and rows_path.exists():  # the jobs already done
        rows = read_rows(rows_path)
        done = {row_key(r) for r in rows}
        todo = [j for j in todo if j.key not in done]
        print(f"  {len(done)} days and buses from {rows_path}, {len(todo)} to run")
    context = get_context("spawn")
    with ProcessPoolExecutor(workers, mp_context=context) as pool:
        # every day made once before any is diagnosed (a day's two log types share it)
        first = {}
        for job in todo:
            first.setdefault((job.source, job.kind, item_id(job.item)), job)
        t0 = time.perf_counter()
        made = list(pool.map(generate_job, first.values()))
        if made:
            print(f"  {len(first)} days and buses generated or found in {folder} in "
                  f"{time.perf_counter() - t0:.0f} s ({sum(made):.0f} s of work)")
        if generate_only:
            return rows
        for row in pool.map(partial(run_job, ladder=ladder), todo):
            rows.append(row)
            if rows_path is not None:  # every job so far, for analyses without a re-run
                write_rows(rows, rows_path)
            print_row(row)
    report(rows, oracle, workers, tune_source)
    return rows


def report(rows, oracle: bool = False, workers: int = 2,
           tune_source: str = TUNE_SOURCE, ceiling: dict | None = None) -> dict:
    """The report of rows (:func:`benchmarks.truth.scoring.report`)."""
    return scoring.report(rows, oracle, workers, tune_source, ORACLE, ceiling)


# the scoring's names, for the benchmarks and tests that read them from here
figures = scoring.figures
bus_figures = scoring.bus_figures
confusion = scoring.confusion
footprint_table = scoring.footprint_table
