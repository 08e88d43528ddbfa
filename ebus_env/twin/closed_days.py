"""Closed service days: when a bus's day is finished, and what its diagnosis says.

A bus's samples are cut into service days by the depot's rule
(:func:`ebus_env.depot.service_days.service_days`: the runs between stays of at least
``stay_h`` without moving, or without samples: a logger asleep at the depot) with the twin's
``day_end_idle_min`` as the stay: longer than any layover. A day is *finished* once a later day
has begun, or once the bus has stood ``day_end_idle_min`` after its last move with its logger
on. It is named by the UTC date of its first sample; a bus that drives again on the same date
after such a stand (a midday depot charge) extends that day, which is then fitted and
diagnosed again over all of it.

The bus's first finished day is its *normal day*: the diagnosis measures it once
(:func:`reference_task`: its calibrated bus-to-bus values and the power its model misses per
operating mode), and every later finished day is diagnosed with
:func:`ebus_env.diagnostics.diagnose` against it (the configured bus, calibrated on the day).
The adapter reads only the public ``verdict``, ``status`` and ``why`` of the diagnosis.
A day's *finding* is the named effect, or "outside library" when no library effect explains
the missing power (with the operating mode where it is missing, the diagnosis's
``mode_clue``, when it names one), or "nothing missing". A finding that differs from the bus's
usual one (that of its first day diagnosed against its normal day) raises an alarm: a fault
that starts on a day.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import sqlalchemy as sa

from ebus_env.depot.service_days import DayRule, service_days
from ebus_env.twin.store import alarms, diagnoses
from ebus_env.twin.store import service_days as days_table


def day_rule(day_end_idle_min: float) -> DayRule:
    """The depot's day rule with the twin's stay: a day keeps a third of it as its margin
    before the first and after the last move."""
    return DayRule(stay_h=day_end_idle_min / 60.0, margin_min=day_end_idle_min / 3.0,
                   min_day_h=0.0)


def finished_days(t: np.ndarray, speed_kmh: np.ndarray, rule: DayRule
                  ) -> list[tuple[float, float]]:
    """(start, end) [s] of each finished day in time-ordered samples (after the last
    finished day): its stay has begun and either a later day has too, or the samples reach
    ``stay_h`` past its last move (see the module docstring)."""
    days = service_days(t, speed_kmh, rule)
    margin = 60.0 * rule.margin_min
    done = []
    for k, (a, b) in enumerate(days):
        last_move = b - margin
        if k + 1 < len(days) or t[-1] - last_move >= 3600.0 * rule.stay_h:
            done.append((max(a, float(t[0])), min(b, float(t[-1]))))
    return done


def close_days(twin, bus: str, settings) -> list[str]:
    """Close the bus's finished days; returns their names."""
    from ebus_env.twin.bus_refit import open_day_start

    bus_id = twin.bus_id(bus)
    start = open_day_start(twin, bus_id)
    frame = twin.samples(bus, t_from=start + 1e-3 if np.isfinite(start) else -np.inf,
                         columns=("speed_kmh",))
    if len(frame) < 2:
        return []
    t, v = frame["t"].to_numpy(float), frame["speed_kmh"].to_numpy(float)
    closed = []
    for a, b in finished_days(t, v, day_rule(settings.day_end_idle_min)):
        day = str(pd.Timestamp(a, unit="s").date())
        key = (days_table.c.bus_id == bus_id) & (days_table.c.day == day)
        with twin.store.engine.begin() as conn:
            known = conn.execute(sa.select(days_table.c.t_start, days_table.c.t_end)
                                 .where(key)).first()
            if known is None:
                conn.execute(days_table.insert().values(
                    bus_id=bus_id, day=day, t_start=a, t_end=b, finished_at=twin.clock(),
                    state="finished"))
            else:  # the bus came back on the same date after a long stand: the day grows
                conn.execute(days_table.update().where(key).values(
                    t_start=min(a, known.t_start), t_end=max(b, known.t_end),
                    finished_at=twin.clock(),
                    state="finished"))
        if day not in closed:
            closed.append(day)
    return closed


def finding(diagnosis) -> str:
    """The day's finding from the diagnosis's public fields."""
    if diagnosis.verdict:
        return diagnosis.verdict
    if diagnosis.status == "outside library":
        # the mode where the power is missing tells two such days apart (a compressor that
        # runs while the bus stands: "idle")
        clue = getattr(diagnosis, "mode_clue", None)
        return "outside library" + (f" ({clue})" if clue else "")
    return "nothing missing"


def reference_task(reference_frame: pd.DataFrame, bus_config: str, dt_s: float):
    """The bus's normal day as the diagnosis measures it (here or as a Ray task): its
    calibrated bus-to-bus values and the power its model misses per operating mode
    (:class:`ebus_env.diagnostics.normal_day.Reference`), once per bus and reused for each of
    its later days; None when the day holds no profile."""
    from ebus_env.config import load_bus
    from ebus_env.diagnostics.stage02_reference import reference_stage
    from ebus_env.twin.bus_refit import profiles_of

    profiles = profiles_of(reference_frame, dt_s, "reference")
    if not profiles:
        return None
    return reference_stage(load_bus(bus_config), profiles, None, None, None, None)


def diagnose_task(day_frame: pd.DataFrame, reference,
                  bus_config: str, dt_s: float) -> dict:
    """The diagnosis of one day (here or as a Ray task): its verdict, status, why, sentence
    and the twin's finding. It starts from the configured bus, not from the twin's fits: it
    calibrates the bus itself, its bus-to-bus parameters within a fleet's spread around the
    configured values, and the bus's normal day (``reference``, from :func:`reference_task`;
    None: none) says what this bus misses on any day. (Started from the twin's fits, its
    ranges, factors of the starting values, would drift with them, and the within-day values
    of a window re-fit belong to another day.)"""
    from ebus_env.config import load_bus
    from ebus_env.diagnostics import diagnose
    from ebus_env.twin.bus_refit import profiles_of

    profiles = profiles_of(day_frame, dt_s, "day")
    if not profiles:
        return {"verdict": None, "status": "too little data", "why": "the day has no "
                "stretch of an hour or more with SoC", "sentence": "", "finding": "no data"}
    d = diagnose(load_bus(bus_config), profiles, calibrate=True, reference=reference)
    return {"verdict": d.verdict, "status": d.status, "why": d.why, "sentence": d.sentence,
            "finding": finding(d)}


def normal_day_result(normal) -> dict:
    """What the bus's first day, its normal day, shows on its page: what its calibrated model
    misses there, against which its later days are diagnosed."""
    if normal is None:
        return {"verdict": None, "status": "too little data", "why": "the day has no stretch "
                "of an hour or more with SoC: the next day is diagnosed without a normal day",
                "sentence": "", "finding": "no data"}
    missing = ", ".join(f"{m['missing_kw']:.1f} kW {m['mode']}"
                        for m in normal.to_json()["missing_by_mode"])
    why = (f"the bus's normal day: its later days are diagnosed against it. Calibrated on "
           f"it, the model's held-out NRMSE is {normal.held_out_nrmse:.4f}; the power it "
           f"misses by operating mode: {missing or 'none measured'}")
    return {"verdict": None, "status": "normal day", "why": why, "sentence": why[0].upper()
            + why[1:] + ".", "finding": "normal day"}


def diagnose_day(twin, bus: str, day: str, settings, runner=None) -> dict:
    """Diagnose ``bus``'s finished ``day``; alarm when its finding differs from the bus's
    usual one."""
    bus_id = twin.bus_id(bus)
    with twin.store.engine.connect() as conn:
        days = conn.execute(sa.select(days_table).where(days_table.c.bus_id == bus_id)
                            .order_by(days_table.c.day)).all()
        # the bus's usual finding: that of its first day diagnosed against its normal day
        first = conn.execute(sa.select(diagnoses).where(
            diagnoses.c.bus_id == bus_id, diagnoses.c.day > days[0].day,
            diagnoses.c.day != day).order_by(diagnoses.c.day).limit(1)).first()
    this = next(d for d in days if d.day == day)
    reference = days[0] if days[0].day != day else None
    frame = twin.samples(bus, this.t_start, this.t_end)
    run = runner or (lambda fn, *a: fn(*a))
    first_day = days[0]
    key = (first_day.t_start, first_day.t_end, settings.bus_config)
    cached = twin.reference_cache.get(bus)
    if reference is None or cached is None or cached[0] != key:
        # measured once per bus and process (again when a late batch changed it)
        frame0 = frame if reference is None else twin.samples(bus, first_day.t_start,
                                                              first_day.t_end)
        cached = (key, run(reference_task, frame0, settings.bus_config, settings.dt_s))
        twin.reference_cache[bus] = cached
    normal = cached[1]
    if reference is None:
        result = normal_day_result(normal)
    else:
        result = run(diagnose_task, frame, normal, settings.bus_config, settings.dt_s)
    usual = first.finding if first is not None and first.day < day else None
    with twin.store.engine.begin() as conn:
        conn.execute(diagnoses.delete().where(diagnoses.c.bus_id == bus_id,
                                              diagnoses.c.day == day))
        conn.execute(diagnoses.insert().values(
            bus_id=bus_id, day=day, diagnosed_at=twin.clock(), verdict=result["verdict"],
            status=result["status"], finding=result["finding"], why=result["why"],
            sentence=result["sentence"]))
        conn.execute(days_table.update().where(days_table.c.bus_id == bus_id,
                                                 days_table.c.day == day)
                     .values(state="diagnosed"))
        if usual is not None and result["finding"] != usual:
            what = ("no library effect explains it" + result["finding"][15:]
                    if result["finding"].startswith("outside library")
                    else f"the diagnosis names {result['finding']}"
                    if result["finding"] not in ("nothing missing", "no data")
                    else "the missing power of its usual days is gone")
            conn.execute(alarms.insert().values(
                bus_id=bus_id, kind="diagnosis", raised_at=twin.clock(), data_t=this.t_end,
                day=day, lead_s=None,
                message=f"{bus} changed on {day}: {what} (its usual days: {usual}). "
                        f"{result['why']}"))
    return result
