"""Closed service days: when a bus's day is finished, and what its diagnosis says.

A bus's samples are cut into service days by the depot's rule
(:func:`ebus_env.depot.service_days.service_days`: the runs between stays of at least
``stay_h`` without moving, or without samples: a logger asleep at the depot) with the twin's
``day_end_idle_min`` as the stay: longer than any layover. A day is *finished* once a later day
has begun, or once the bus has stood ``day_end_idle_min`` after its last move with its logger
on. It is named by the UTC date of its first sample.

Each finished day is diagnosed with :func:`ebus_env.diagnostics.diagnose` (the bus as its
last fit left it, calibrated on the day, against the bus's first finished day as its normal
day). The adapter reads only the public ``verdict``, ``status`` and ``why`` of the diagnosis.
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
    from ebus_env.twin.refit import open_day_start

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
        with twin.store.engine.begin() as conn:
            conn.execute(twin.store.insert(days_table).values(
                bus_id=bus_id, day=day, t_start=a, t_end=b, finished_at=twin.clock(),
                state="finished").on_conflict_do_nothing())
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


def diagnose_task(day_frame: pd.DataFrame, reference_frame: pd.DataFrame | None,
                  values: dict, bus_config: str, dt_s: float) -> dict:
    """The diagnosis of one day (here or as a Ray task): its verdict, status, why, sentence
    and the twin's finding. The bus starts from the twin's fitted ``values`` except the
    bus-to-bus parameters (:func:`~ebus_env.diagnostics.ladder.nuisance_ranges`): the
    diagnosis fits those itself, in a fleet's spread around the configured bus (its ranges are
    factors of the starting value: centred on the twin's own fit they would drift with it,
    and a fitted zero would leave no range at all)."""
    from ebus_env.config import load_bus
    from ebus_env.diagnostics import diagnose
    from ebus_env.diagnostics.ladder import NUISANCE, RESOLVED_BY_CURRENT
    from ebus_env.twin.refit import profiles_of

    bus = load_bus(bus_config)
    own = {k: v for k, v in values.items() if k not in NUISANCE and k not in RESOLVED_BY_CURRENT}
    if own:
        bus = bus.overlay(_overlay(own), "the twin's last fit")
    profiles = profiles_of(day_frame, dt_s, "day")
    reference = profiles_of(reference_frame, dt_s, "reference") \
        if reference_frame is not None else None
    if not profiles:
        return {"verdict": None, "status": "too little data", "why": "the day has no "
                "stretch of an hour or more with SoC", "sentence": "", "finding": "no data"}
    d = diagnose(bus, profiles, calibrate=True, reference=reference or None)
    return {"verdict": d.verdict, "status": d.status, "why": d.why, "sentence": d.sentence,
            "finding": finding(d)}


def _overlay(values: dict) -> dict:
    out: dict[str, dict] = {}
    for name, value in values.items():
        effect, param = name.split(".", 1)
        out.setdefault(effect, {})[param] = float(value)
    return {"params": out}


def diagnose_day(twin, bus: str, day: str, settings, runner=None) -> dict:
    """Diagnose ``bus``'s finished ``day``; alarm when its finding differs from the bus's
    usual one."""
    from ebus_env.twin.refit import latest_values

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
    ref_frame = twin.samples(bus, reference.t_start, reference.t_end) if reference else None
    run = runner or (lambda fn, *a: fn(*a))
    values = latest_values(twin, bus_id, before_t=this.t_start)
    result = run(diagnose_task, frame, ref_frame, values, settings.bus_config, settings.dt_s)
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
