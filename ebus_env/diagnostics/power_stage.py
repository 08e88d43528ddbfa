"""Stages 5-10 in the power domain: the power path (:mod:`ebus_env.diagnostics.power_path`)
in place of the SoC windows' candidates and attribution.

Where every log carries the pack's current and voltage, the missing power is read second by
second in 10-s bins by operating mode (on SoC-only logs, from the charge the SoC counts in
each 5-min window: :mod:`~ebus_env.diagnostics.soc_power`), every bus-to-bus parameter (and
the current sensor's gain and offset) is fitted to the logged power, and each candidate is
decided by a held-out test. On several days of one bus each candidate is tried from each day
on too, so that a fault that starts on a day is a verdict of its own, with the day it
started.

The stage fills ``ctx.found`` in the form the report reads, ``ctx.power`` (the power path's
run) and ``ctx.days`` (the date or log of each day).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from ebus_env.diagnostics.candidates import Strength
from ebus_env.diagnostics.log_days import service_days
from ebus_env.diagnostics.power import logs_power
from ebus_env.diagnostics.power_path import (
    OUTSIDE_MODE,
    at_end_note,
    diagnose_power,
    energy_kwh,
    label,
)
from ebus_env.diagnostics.soc_power import logs_soc
from ebus_env.diagnostics.stage06_attribution import Attributed
from ebus_env.errors import ConfigError

if TYPE_CHECKING:
    from ebus_env.diagnostics.diagnosis_run import DiagnosisRun

DOMAINS = ("soc", "power", "auto")
"""``soc``: SoC windows (the default: on BMS logs the current counts the charge in each);
``power``: the power path, BMS logs second by second and SoC-only logs by the charge the SoC
counts in each 5-min window (:mod:`~ebus_env.diagnostics.soc_power`); ``auto``: the power
domain where every log carries the pack's current and voltage and no reference day is
given, SoC windows otherwise."""


def domain_of(ctx: DiagnosisRun) -> str:
    """The domain the diagnosis works in: ``power`` or ``soc`` (see :data:`DOMAINS`)."""
    bms = all(logs_power(p) for p in ctx.profiles)
    if ctx.domain == "power" and not bms:
        missing = [p.name for p in ctx.profiles if not (logs_power(p) or logs_soc(p))]
        if missing:
            raise ConfigError(f"diagnose(domain='power') needs the pack's current and voltage "
                              f"or the SoC, and {', '.join(dict.fromkeys(missing))} lack(s) "
                              "both. Fix: map the battery_current_a and battery_voltage_v "
                              "columns, or the soc_frac column.")
    if ctx.domain == "power":
        return "power"
    return "power" if ctx.domain == "auto" and bms and ctx.reference is None else "soc"


def run(ctx: DiagnosisRun) -> None:
    """Fill ``ctx.power``, ``ctx.days``, ``ctx.aside`` and ``ctx.found``."""
    day_of, ctx.days = service_days(ctx.profiles)
    ctx.power = power = diagnose_power(ctx.bus, ctx.profiles, day_of, add=ctx.add,
                                       fixed=ctx.held, say=ctx.say)
    ctx.aside = list(power.aside)
    ctx.found = attributed(power, ctx.days)


def gain_band(test, boot: int = 200, seed: int = 0) -> tuple[float, float]:
    """The 5-95 % band of a test's held-out gain over resamples of its blocks (the null's
    held-out loss of a block is the candidate's plus what the candidate removes there)."""
    gain, loss = test.block_gain, test.folds_loss
    if len(gain) < 2 or len(loss) != len(gain):
        return (math.nan, math.nan)
    rows = np.random.default_rng(seed).integers(0, len(gain), (boot, len(gain)))
    null = (gain + loss)[rows].sum(axis=1)
    shares = gain[rows].sum(axis=1) / np.where(null > 0, null, np.nan)
    low, high = np.nanquantile(shares, [0.05, 0.95])
    return float(low), float(high)


def ranking_of(power, days: list[str]) -> list[dict]:
    """A row per candidate tested, the verdict's first, then by held-out chi-square: the share
    of the held-out missing power it removes (``explained_fraction``, with its 5-95 % band over
    block resamples), its chi-square against the one needed, the day it acts from, and the
    energy it adds over the logs at its fit (the verdict's: with its 90 % interval)."""
    f = power.finding
    rows = []
    for t in f.tests:
        form = f.forms[t.name]
        band = gain_band(t)
        row = {"effect": form.name, "kind": form.kind, "label": label(form),
               "explained_fraction": t.gain, "explained_band": list(band),
               "chi2": t.chi2, "needed": f.needed, "since": days[form.since_day],
               "since_day": form.since_day, "parameters": {}, "interval": {},
               "fitted_energy_kwh": energy_kwh(t, form, power.bins.seconds)}
        rows.append(row)
    if f.verdict is not None and f.strength:
        named = next((r for r in rows if r["effect"] == f.verdict
                      and r["since_day"] == f.since_day), None)
        if named is None:  # named from the logged voltage, not a tested power form
            named = {"effect": f.verdict, "kind": "missing effect", "label": f.verdict,
                     "explained_fraction": math.nan, "explained_band": [math.nan, math.nan],
                     "chi2": math.nan, "needed": f.needed, "since": days[f.since_day],
                     "since_day": f.since_day, "fitted_energy_kwh": f.strength["energy_kwh"]}
            rows.append(named)
        named |= {"parameters": f.strength.get("parameters", {}),
                  "interval": {k: tuple(v) for k, v in f.strength.get("interval", {}).items()},
                  "energy_kwh": f.strength["energy_kwh"],
                  "energy_interval_kwh": tuple(f.strength["energy_interval_kwh"])}
        rows.remove(named)
        rows.insert(0, named)  # the verdict's row first (Diagnosis.named reads it)
    return rows


def attributed(power, days: list[str]) -> Attributed:
    """The power path's finding in the form the report reads."""
    f = power.finding
    ranking = ranking_of(power, days)
    strength = Strength({}, {})
    if f.verdict is not None and f.strength:
        strength = Strength(dict(f.strength.get("parameters", {})),
                            {k: tuple(v) for k, v in f.strength.get("interval", {}).items()},
                            energy_kwh=f.strength["energy_kwh"],
                            energy_interval_kwh=tuple(f.strength["energy_interval_kwh"]))
    why = f.why
    if f.status == "named":
        t = next(t for t in f.tests if f.forms[t.name].name == f.verdict
                 and f.forms[t.name].since_day == f.since_day)
        why = (f"it removes {100 * t.gain:.0f} % of the missing power on held-out blocks "
               f"(chi-square {t.chi2:.0f}, {f.needed:.0f} needed){at_end_note(f.strength)}")
    top = f.tests[0] if f.tests else None
    significance = math.sqrt(max(top.chi2, 0.0) / max(f.needed, 1e-12)) if top else 0.0
    clue = f.clue
    if clue is None and f.status == "outside library" and top is not None:
        clue = OUTSIDE_MODE.get(f.forms[top.name].name)
    return Attributed(
        ranked=list(f.tests), selected=[f.verdict] if f.verdict else [], verdict=f.verdict,
        why=why, significance=significance, strength=strength, verdict_w=None,
        ranking=ranking, parameters=[], clues=[], modes=f.modes, bins={}, worst=[],
        status=f.status, clue=clue)


def since_of(power, days: list[str]) -> tuple[str | None, list[str] | None]:
    """The date (or log) from which the named effect, or the form outside the library, acts,
    and the days it may have started on (None, None where it acts on every day, or nothing
    was found)."""
    f = power.finding
    if f.status not in ("named", "outside library", "voltage") or f.since_day == 0:
        return None, None
    low, high = f.since_interval
    return days[f.since_day], [days[low], days[high]]


def held_out_falls(power) -> dict[str, float]:
    """The share of the held-out missing power each library effect removes, at its best start
    day: the power domain's error fall after adding it."""
    f = power.finding
    out: dict[str, float] = {}
    for t in f.tests:  # best first
        form = f.forms[t.name]
        if form.kind != "outside" and form.name not in out:
            out[form.name] = t.gain
    return out
