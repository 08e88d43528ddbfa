"""The out-of-family cases: one randomised service day per case, one hidden effect per day.

    python -m benchmarks.truth.cases --out DIR [--n-per-effect 10] [--n-control 30]

writes ``DIR/<case_id>.csv.gz`` (the degraded 1 Hz log; gzip with mtime 0, so the bench is
byte-reproducible) and ``DIR/truth.json`` (one truth record per case, see ``generate``).

Every case has its own seed, drawn from the bench seed; the day's plan, base bus, hidden
effect's values and log degradation come from independent streams of that seed.
"""

from __future__ import annotations

import argparse
import gzip
import io
import json
import os
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from benchmarks.truth.days import _SEASONS, route_day
from benchmarks.truth.degrade import degrade, effect_load_kw
from benchmarks.truth.sim import AIR_CP_J_PER_KG_K, FORCES, HIDDEN, simulate
from benchmarks.truth.vehicles import AIR_DENSITY_KG_PER_M3, draw_base

SOURCE = "truthsim"
MIN_SOC_FRAC = 0.10
DEFAULT_SEED = 20230117

# hidden effect -> (library effect the diagnosis should name, climate of the day)
EFFECTS = {
    "road_grade": ("road_grade", "mild"),
    "cabin_heating": ("cabin_hvac", "cold"),
    "cabin_cooling": ("cabin_hvac", "hot"),
    "regen_soc_limit": ("regen_soc_limit", "mild"),
    "cold_battery": ("ambient_battery", "cold"),
    "passenger_mass": ("passenger_mass", "mild"),
    "aux_schedule": ("aux_schedule", "cold"),
    "air_compressor": ("outside_library", "mild"),
    "battery_chiller": ("outside_library", "mild"),
    "dragging_brake": ("outside_library", "mild"),
}
# Conditions of the multi-day buses: condition -> (library effect to name, how it acts over
# the days): "weather" acts every day as the day's weather makes it, "constant" acts every
# day alike, "from_day" is a fault that starts on the bus's ``start_day`` and stays.
MULTI_DAY = {
    "cabin_heating": ("cabin_hvac", "weather"),
    "regen_soc_limit": ("regen_soc_limit", "from_day"),
    "aux_schedule": ("aux_schedule", "from_day"),
    "capacity_step": ("static_rcd", "from_day"),
    "air_compressor": ("outside_library", "constant"),
    "dragging_brake": ("outside_library", "from_day"),
}
VERDICTS = {**{k: v[0] for k, v in EFFECTS.items()}, **{k: v[0] for k, v in MULTI_DAY.items()}}
assert set(VERDICTS) == set(HIDDEN)
DAYS_PER_BUS = 6
START_DAYS = (2, 3, 4)  # a fault's first day: at least two days before it and two with it
LATER = frozenset({"dragging_brake"})
"""Single-day effects added after the first nine (their seeds from a stream of their own)."""
# effects whose power depends on the clock: their logs always carry time stamps
CLOCK_BOUND = {"cabin_heating", "cabin_cooling", "aux_schedule"}
MODES = ("accelerating", "cruising", "braking/regen", "idle", "CC charging", "CV charging")

# The library's default ``aux_schedule`` table ("evening_lights": hours -> W), used only to
# express the truth's lights as the library's ``scale`` parameter.
LIBRARY_SCHEDULE_H = (0.0, 6.0, 7.0, 16.0, 17.0, 22.0, 23.0, 24.0)
LIBRARY_SCHEDULE_W = (500.0, 500.0, 0.0, 0.0, 500.0, 500.0, 500.0, 500.0)
# The library's 12 m cabin (``configs/bus/12m.yaml``): its fresh air (0.4 kg/s) and door air
# (0.7 m^3/s while the doors are open) as conductances c_p m and rho c_p V [W/K], used only to
# express a truth's cabin as the library's envelope ``ua_w_per_k``.
LIBRARY_FRESH_AIR_W_PER_K = 0.4 * AIR_CP_J_PER_KG_K
LIBRARY_DOOR_AIR_W_PER_K = 1.2 * AIR_CP_J_PER_KG_K * 0.7


@dataclass(frozen=True)
class Case:
    """What defines one case; ``generate`` makes its log and truth record."""

    case_id: str
    hidden: str | None
    seed: int
    chemistry: str
    route: str
    start_clock_h: float
    hours: float
    relative_time: bool
    climate: str
    bus_seed: int | None = None
    """The seed whose stream draws the bus's base parameters (default: ``seed``): cases with
    one ``bus_seed`` are days of the same bus."""
    active: bool = True
    """Whether the hidden effect acts on this day (a multi-day bus's fault before its start
    day does not; the day is run as the bus's, with its condition's day options)."""
    date: str | None = None
    """The service date (``YYYY-MM-DD``); drawn with the plan when None."""
    bus_id: str | None = None
    """The multi-day bus this day belongs to (None for a single day)."""
    day: int | None = None
    """The day's index among its bus's days (0 first)."""


def cases(n_per_effect: int = 10, n_control: int = 30, seed: int = DEFAULT_SEED,
          effects: tuple[str, ...] | None = None) -> list[Case]:
    """The case list: ``n_per_effect`` days per hidden effect, then ``n_control`` days with
    nothing hidden. Chemistry alternates LFP/NMC and the route cycles through rt7/rt44/rt45."""
    first = np.random.default_rng(seed)
    # effects added to the bench later draw from a stream of their own, so that the first
    # effects' and the control days' seeds stay what they were
    later = np.random.default_rng([seed, 1])
    routes = ("rt7", "rt44", "rt45")
    out = []
    chosen = effects or tuple(EFFECTS)
    for hidden in (*[e for e in chosen if e not in LATER], None,
                   *[e for e in chosen if e in LATER]):
        rng = later if hidden in LATER else first
        count = n_control if hidden is None else n_per_effect
        for i in range(count):
            case_seed = int(rng.integers(2**31))
            if hidden == "aux_schedule":  # the day runs into the dark evening
                start, hours = rng.uniform(11.0, 14.0), rng.uniform(8.0, 10.0)
            else:
                start, hours = rng.uniform(5.0, 8.5), rng.uniform(8.0, 10.0)
            relative = hidden not in CLOCK_BOUND and rng.random() < 0.3
            out.append(Case(
                case_id=f"{hidden or 'control'}_{i:02d}", hidden=hidden, seed=case_seed,
                chemistry=("LFP", "NMC")[i % 2], route=routes[i % 3],
                start_clock_h=round(float(start), 3), hours=round(float(hours), 3),
                relative_time=bool(relative),
                climate=EFFECTS[hidden][1] if hidden else "mild"))
    return out


def _physical(hidden: str | None, rng: np.random.Generator, plan: pd.DataFrame,
              chemistry: str) -> tuple[dict, dict]:
    """The hidden effect's truth values and the day options (start SoC, charger stop SoC)."""
    # below the top, where the cells' voltage limit would itself cut regeneration
    stop = rng.uniform(0.85, 0.90) if chemistry == "LFP" else rng.uniform(0.80, 0.88)
    day = {"soc0_frac": rng.uniform(0.6, stop), "charge_stop_frac": stop}
    ph: dict[str, float] = {}
    if hidden in ("cabin_heating", "cabin_cooling"):
        heating = hidden == "cabin_heating"
        ph = {
            # envelope: ~140 m^2 of walls, roof, floor and glazing at U 2-4 W/(m^2 K)
            "ua_w_per_k": rng.uniform(300.0, 550.0),
            "heat_capacity_j_per_k": rng.uniform(0.6e6, 1.2e6),  # air + seats and panels
            "fresh_air_kg_per_s": rng.uniform(0.3, 0.5),  # EN 14750-1 fresh-air class
            "door_air_m3_per_s": rng.uniform(0.4, 1.0),
            "solar_area_m2": rng.uniform(3.0, 6.0),  # glazing x transmittance
            "setpoint_degc": rng.uniform(17.0, 20.0) if heating else rng.uniform(22.0, 25.0),
            "heating_max_w": 24e3, "cooling_max_w": 25e3,
            "heat_pump_max_w": rng.uniform(10e3, 16e3),
            "kp_w_per_k": 3000.0, "ki_w_per_k_s": 5.0, "blower_w": rng.uniform(400.0, 800.0),
        }
    elif hidden == "regen_soc_limit":
        top = 0.985 if chemistry == "LFP" else 0.97
        day = {"soc0_frac": rng.uniform(top - 0.05, top), "charge_stop_frac": top}
        ph = {"derate_soc_frac": rng.uniform(0.80, 0.90)}
    elif hidden == "cold_battery":
        # parked in a depot hall overnight: the pack starts above the ambient
        ph = {"start_offset_k": rng.uniform(0.0, 15.0),
              "pack_heat_capacity_j_per_k": rng.uniform(1.4e6, 2.2e6),  # ~1.8 t x 1 kJ/(kg K)
              "pack_ha_w_per_k": rng.uniform(80.0, 200.0)}
        ph["pack_temp0_degc"] = float(plan["ambient_degc"].iloc[0]) + ph["start_offset_k"]
    elif hidden == "passenger_mass":
        ph = {"passenger_mass_kg": rng.uniform(65.0, 85.0)}  # UN R107 uses 68 kg
    elif hidden == "aux_schedule":
        rise, set_ = _SEASONS[plan.attrs["climate"]]["sun_h"]
        ph = {"lights_w": rng.uniform(1000.0, 2200.0),
              "lights_on_h": set_ - rng.uniform(0.0, 0.5),
              "lights_off_h": rise + rng.uniform(0.0, 0.5)}
    elif hidden == "air_compressor":
        # electric compressors of e-buses: 4-8 kW, delivering 300-700 l/min of free air into
        # ~150 l of reservoirs (0.035-0.07 bar/s); governor 10.0-12.5 bar
        ph = {"compressor_w": rng.uniform(4e3, 8e3), "fill_bar_per_s": rng.uniform(0.035, 0.07),
              "brake_bar": rng.uniform(0.10, 0.20), "door_bar": rng.uniform(0.15, 0.30),
              "leak_bar_per_s": rng.uniform(2e-4, 5e-4), "cut_in_bar": 10.0,
              "cut_out_bar": 12.5}
    elif hidden == "battery_chiller":
        ph = {"chiller_w": rng.uniform(4e3, 9e3)}
    elif hidden == "dragging_brake":
        # a sticking caliper or slack adjuster: after an application the pads keep a residual
        # clamp, 250-800 N of drag at the wheel (a 13 t bus rolls against ~850 N), fading over
        # 200-600 m as the piston retracts, and a small drag that never goes
        ph = {"residual_n": rng.uniform(250.0, 800.0), "fade_m": rng.uniform(200.0, 600.0),
              "floor_n": rng.uniform(0.0, 100.0)}
    elif hidden == "capacity_step":
        # a weak cell group in series limits the whole string: capacity 8-15 % lower, the
        # cells' resistance 10-30 % higher
        ph = {"capacity_loss_frac": rng.uniform(0.08, 0.15),
              "resistance_growth_frac": rng.uniform(0.10, 0.30)}
    return {k: float(v) for k, v in ph.items()}, {k: float(v) for k, v in day.items()}


def modes(trace: pd.DataFrame) -> np.ndarray:
    """Operating mode of each row (index into ``MODES``), as the diagnosis classes them."""
    mode = np.full(len(trace), 1)
    mode[(trace["accel_mps2"] > 0.1) & (trace["p_wheel_w"] > 0)] = 0
    mode[(trace["p_wheel_w"] < 0) & (trace["speed_mps"] > 0.1)] = 2
    mode[trace["speed_mps"] <= 0.1] = 3
    plugged = (trace["charging"] == 1) & (trace["p_charger_w"] > 0)
    mode[plugged] = 4
    mode[plugged & (trace["cv_phase"] == 1)] = 5
    return mode


def door_weight(trace: pd.DataFrame) -> float:
    """Share of the day's cabin-to-ambient temperature difference the doors stood open for,
    sum(door dT) / sum(dT), dT = T_cab - T_amb: a door's air exchange over the day is that
    share times its conductance."""
    delta_k = (trace["cabin_temp_degc"] - trace["ambient_degc"]).to_numpy()
    return float(np.sum(trace["door_open"].to_numpy() * delta_k) / np.sum(delta_k))


def library_ua(conductance_w_per_k: float, door: float) -> float:
    """The library's envelope UA whose cabin loses heat as a truth's does over the day: a SoC
    log shows the heat-loss conductance as a whole (walls, fresh air and open doors), not how
    it splits, so the library's UA takes up the difference of the other two terms.
    ``conductance_w_per_k``: the truth's, averaged over the day like :func:`door_weight`."""
    return conductance_w_per_k - LIBRARY_FRESH_AIR_W_PER_K - LIBRARY_DOOR_AIR_W_PER_K * door


def _strength(hidden: str | None, ph: dict, trace: pd.DataFrame) -> dict:
    """The truth expressed in the library's parameters, where it has an equivalent."""
    if hidden in ("cabin_heating", "cabin_cooling"):
        door = door_weight(trace)
        conductance = (ph["ua_w_per_k"] + ph["fresh_air_kg_per_s"] * AIR_CP_J_PER_KG_K
                       + AIR_DENSITY_KG_PER_M3 * AIR_CP_J_PER_KG_K * ph["door_air_m3_per_s"]
                       * door)
        return {"cabin_hvac.ua_w_per_k": library_ua(conductance, door)}
    if hidden == "regen_soc_limit":
        # both start derating at this SoC and reach zero at 100 %; the truth derates the
        # charge current from the motor's regen current, the library the regenerative force
        # from the drive's (the pack's voltage and the drive's torque limit make them differ)
        return {"regen_soc_limit.derate_soc_pct": 100.0 * ph["derate_soc_frac"]}
    if hidden == "cold_battery":
        # the pack starts this far above the ambient and relaxes with tau = C / hA (the
        # truth adds Joule heating, which the library lacks)
        return {"ambient_battery.initial_offset_k": ph["start_offset_k"],
                "ambient_battery.time_constant_h":
                    ph["pack_heat_capacity_j_per_k"] / ph["pack_ha_w_per_k"] / 3600.0}
    if hidden == "passenger_mass":
        return {"passenger_mass.passenger_mass_kg": ph["passenger_mass_kg"]}
    if hidden == "capacity_step":  # the library's ageing: capacity factor 1 - RCD
        return {"static_rcd.rcd_frac": ph["capacity_loss_frac"]}
    if hidden == "aux_schedule":
        # least-squares scale of the library's table to the truth's lights over the day:
        # scale = <P_truth, S> / <S, S> on the trace's clock samples
        shape = np.interp(trace["clock_h"] % 24.0, LIBRARY_SCHEDULE_H, LIBRARY_SCHEDULE_W)
        load = trace["p_hidden_w"].to_numpy()
        return {"aux_schedule.scale": float(load @ shape / (shape @ shape))}
    return {}


def _used_series(trace: pd.DataFrame) -> np.ndarray:
    """Energy taken by the drive, the loads and the battery's own losses since the start [J]."""
    return (trace["e_drive_dc_j"] + trace["e_aux_j"] + trace["e_hidden_j"]
            + trace["e_battery_loss_j"]).to_numpy(float)


def _used_j(trace: pd.DataFrame) -> float:
    """Energy taken by the drive, the loads and the battery's own losses over the day [J]."""
    return float(_used_series(trace)[-1])


def _streams(case: Case) -> list[np.random.SeedSequence]:
    """The case's independent random streams: plan, base parameters, physics, log (the base
    parameters' from ``bus_seed`` where the case has one)."""
    streams = np.random.SeedSequence(case.seed).spawn(4)
    if case.bus_seed is not None:
        streams[1] = np.random.SeedSequence(case.bus_seed).spawn(4)[1]
    return streams


@dataclass(frozen=True)
class Bus:
    """A multi-day bus: its own parameters (base draw, pack, the condition's bus-level values)
    held across ``n_days`` service days from November to February, each day with its own
    weather, plan, passengers, driver and start SoC. ``condition`` is a hidden effect acting
    as :data:`MULTI_DAY` says (every day as the weather makes it, every day alike, or from
    ``start_day`` on), or None for a control bus."""

    bus_id: str
    condition: str | None
    seed: int
    chemistry: str | None
    route: str
    start_day: int | None = None
    """The index of the day a fault starts (None: the condition acts on every day)."""
    n_days: int = DAYS_PER_BUS
    first_date: str = "2025-11-03"


def buses(n_per_condition: int = 5, n_control: int = 4, seed: int = DEFAULT_SEED,
          conditions: dict | None = None) -> list[Bus]:
    """The multi-day buses: ``n_per_condition`` buses per condition of ``conditions`` (default
    :data:`MULTI_DAY`: condition -> (verdict, kind)), then ``n_control`` control buses. Chemistry
    alternates LFP/NMC, the route cycles rt7/rt44/rt45; a fault's start day is drawn from
    :data:`START_DAYS`; the first day falls between 3 and 23 November (no day of a bus is a
    daylight-saving change)."""
    conditions = MULTI_DAY if conditions is None else conditions
    rng = np.random.default_rng([seed, 2])  # a stream of its own: the single days stay
    routes = ("rt7", "rt44", "rt45")
    out = []
    for condition in (*conditions, None):
        kind = conditions[condition][1] if condition else None
        for i in range(n_control if condition is None else n_per_condition):
            bus_seed = int(rng.integers(2**31))
            start = int(rng.choice(START_DAYS)) if kind == "from_day" else None
            first = pd.Timestamp("2025-11-03") + pd.Timedelta(days=int(rng.integers(0, 21)))
            out.append(Bus(bus_id=f"bus_{condition or 'control'}_{i:02d}", condition=condition,
                           seed=bus_seed, chemistry=("LFP", "NMC")[i % 2], route=routes[i % 3],
                           start_day=start, first_date=str(first.date())))
    return out


def bus_days(bus: Bus, chemistry: bool = True) -> list[Case]:
    """The service days of a bus, as cases: one ``bus_seed`` (the bus's base draw and its
    condition's bus-level values), dates 5-14 days apart, each day's seed, start and length
    its own; the condition acts on the days from ``start_day`` on (``active``)."""
    rng = np.random.default_rng([bus.seed, 3])
    date = pd.Timestamp(bus.first_date)
    out = []
    for k in range(bus.n_days):
        if k:
            date += pd.Timedelta(days=int(rng.integers(5, 15)))
        if bus.condition == "aux_schedule":  # the days run into the dark evening
            start, hours = rng.uniform(11.0, 14.0), rng.uniform(8.0, 10.0)
        else:
            start, hours = rng.uniform(5.0, 8.5), rng.uniform(8.0, 10.0)
        out.append(Case(
            case_id=f"{bus.bus_id}_day{k}", hidden=bus.condition, seed=int(rng.integers(2**31)),
            chemistry=bus.chemistry if chemistry else None, route=bus.route,
            start_clock_h=round(float(start), 3), hours=round(float(hours), 3),
            relative_time=False, climate="season", bus_seed=bus.seed,
            active=bus.start_day is None or k >= bus.start_day, date=str(date.date()),
            bus_id=bus.bus_id, day=k))
    return out


def bus_truth(bus: Bus, records: list[dict], source: str = SOURCE,
              kinds: dict | None = None) -> dict:
    """The truth record of a multi-day bus from its days' records: the expected verdict, how
    the condition acts (``kind``), the start day and date of a fault (None where it acts on
    every day), the outside modes over its active days (energy-weighted), the effect's
    energy over all days, and each day's date, ambient mean and effect energy."""
    kinds = MULTI_DAY if kinds is None else kinds
    kind = kinds[bus.condition][1] if bus.condition else None
    active = [r for r in records if r["active"] and r["hidden"] is not None]
    shares = None
    weights = [(r["mode_shares"], r["summary"]["hidden_kwh"]) for r in active
                if r.get("mode_shares")]
    if weights:
        total = sum(w for _, w in weights)
        shares = {m: round(sum(sh[m] * w for sh, w in weights) / total, 4) for m in MODES}
    expected = kinds[bus.condition][0] if bus.condition else None
    outside = expected == "outside_library" and shares
    return {
        "bus_id": bus.bus_id, "source": source, "condition": bus.condition,
        "hidden": bus.condition, "kind": kind, "expected_verdict": expected,
        "start_day": bus.start_day,
        "start_date": records[bus.start_day]["date"] if bus.start_day is not None else None,
        "chemistry": bus.chemistry, "route": bus.route, "seed": bus.seed,
        "days": [r["case_id"] for r in records], "dates": [r["date"] for r in records],
        "ambient_mean_degc": [r["ambient_mean_degc"] for r in records],
        "day_effect_kwh": [r["summary"]["effect_kwh"] for r in records],
        "strength": active[0]["strength"] if active else {},
        "physical": active[0]["physical"] if active else {},
        "base": records[0]["base"],
        "mode_shares": shares,
        "outside_mode": max(shares, key=shares.get) if outside else None,
        "outside_modes": sorted(m for m, v in shares.items() if v >= 0.25) if outside else None,
        "summary": {"effect_kwh": round(sum(r["summary"]["effect_kwh"] for r in records), 3),
                    "soc_footprint_pct": max(r["summary"]["soc_footprint_pct"]
                                             for r in records),
                    "hours": round(sum(r["hours"] for r in records), 3)},
    }


def reference_case(case: Case) -> Case:
    """A normal day of the same bus as ``case`` (what a fleet engineer holds as known-good):
    its base draw, its route and pack, another plan, a mild day from 06:30 for 9 h, nothing
    hidden."""
    return replace(case, case_id=f"{case.case_id}_reference", hidden=None,
                   seed=case.seed + 1, start_clock_h=6.5, hours=9.0, climate="mild",
                   bus_seed=case.seed)


def same_bus_case(case: Case, day: int) -> Case:
    """Another service day (``day`` = 1, 2, ...) of the bus of ``case``, with the same hidden
    effect: its base draw, route, pack, climate and hours, another plan, driver, start SoC
    and log degradation. What belongs to the bus, not the day (a cabin's envelope, the BMS's
    derating SoC, the lights, the passengers' mass, a compressor or chiller) is the first
    day's; a cold pack's start above the air is the night's, drawn per day
    (:data:`DAY_LEVEL`)."""
    if day < 1:
        raise ValueError(f"day must be 1 or more (the case itself is day 0), not {day}")
    return replace(case, case_id=f"{case.case_id}_day{day}", seed=case.seed + 1000 * day,
                   bus_seed=case.seed if case.bus_seed is None else case.bus_seed)


DAY_LEVEL = frozenset({"start_offset_k", "pack_temp0_degc"})
"""A hidden effect's values that change from day to day on one bus (a cold pack's start above
the air, after the night's depot); its other values are the bus's (:func:`same_bus_case`)."""


def _physics_draw(stream: np.random.SeedSequence, case: Case,
                  plan: pd.DataFrame) -> tuple[float, dict, dict]:
    """A day's draws from a physics stream: the driver's preview [s], then the hidden
    effect's values and the day options (:func:`_physical`)."""
    rng = np.random.default_rng(stream)
    preview_s = float(rng.uniform(1.5, 2.5))
    return (preview_s, *_physical(case.hidden, rng, plan, case.chemistry))


def day_trace(case: Case) -> tuple[pd.DataFrame, dict, dict, dict, pd.DataFrame]:
    """The truth simulator's run of a case: its plan, the bus's base parameters, the hidden
    effect's physical values, the day's options and the 1 Hz trace (every signal, before the
    log is degraded)."""
    plan_ss, base_ss, phys_ss, _ = _streams(case)
    base = draw_base(np.random.default_rng(base_ss), case.chemistry)
    # An operator plans charging so that the bus finishes its day: when the drawn chargers
    # leave the pack below MIN_SOC_FRAC, the same day is run with 450 kW at both terminals.
    full = {"charger_kw": 450.0, "charger_terminals": (0, 1)}
    # regen-limit days are topped up at every layover, so the bus runs at high SoC
    for chargers in ((full,) if case.hidden == "regen_soc_limit" else ({}, full)):
        plan = route_day(np.random.default_rng(plan_ss), case.hours, case.start_clock_h,
                         case.route, climate=case.climate, date=case.date, **chargers)
        base["driver_preview_s"], ph, day = _physics_draw(phys_ss, case, plan)
        if case.bus_seed is not None and case.hidden is not None:  # another day of one bus:
            # the effect's values as the bus's first day drew them
            first = _physics_draw(np.random.SeedSequence(case.bus_seed).spawn(4)[2], case, plan)
            ph.update({k: v for k, v in first[1].items() if k not in DAY_LEVEL})
        trace = simulate(plan, base, case.hidden if case.active else None, ph, **day)
        if trace["soc_frac"].min() >= MIN_SOC_FRAC:
            return plan, base, ph, day, trace
    raise RuntimeError(f"{case.case_id}: the bus cannot finish its day "
                       f"(SoC {100 * trace['soc_frac'].min():.1f} %)")


def generate(case: Case, current_voltage: bool = False,
             oracle: bool = False) -> tuple[pd.DataFrame, dict]:
    """The degraded log and the truth record of one case; ``current_voltage``: the log has
    the pack's current and voltage too (a BMS log), the rest of it unchanged; ``oracle``: it
    has ``logged_load_kw`` too, the power the hidden effect adds to what the pack supplies
    (:func:`~benchmarks.truth.degrade.effect_load_kw`), the rest of it unchanged.

    The truth record holds ``case_id, source, hidden, expected_verdict`` (the library effect
    the diagnosis should name; None for control days, ``"outside_library"`` for loads the
    library does not have), ``outside_mode`` (the operating mode that takes most of an
    outside load's energy; ``outside_modes`` every mode with at least 25 % of it;
    ``mode_shares`` for every hidden load), ``strength`` (library
    ``"effect.param"`` -> truth value), ``physical`` (the truth's own values), ``base``,
    ``chemistry, route, climate, date, start_clock_h, hours, relative_time, seed``, the
    logged ``columns``, the day
    options and a summary (km, kWh/km at the battery, the hidden load's energy, and
    ``effect_kwh``: what the effect adds to the energy used against the same day without it;
    ``soc_footprint_pct``: the most it moves the SoC, :func:`soc_footprint_pct`).
    """
    plan, base, ph, day, trace = day_trace(case)
    acting = case.hidden if case.active else None
    # the hidden effect's size: the energy the loads and the battery's losses take, with the
    # effect against the same day without it
    without = trace if acting is None else simulate(plan, base, None, {}, **day)
    log = day_log(case, trace, without, base, current_voltage, oracle)
    return log, record(case, plan, base, ph, day, trace, without, list(log.columns))


def day_log(case: Case, trace: pd.DataFrame, without: pd.DataFrame, base: dict,
            current_voltage: bool, oracle: bool) -> pd.DataFrame:
    """The degraded log of a day's trace (the truth simulator's columns: also the backward
    source's): what every log holds, altitude on grade days and passenger counts on
    passenger days; the BMS's SoC counted against the pack's rated capacity (``base``: a
    weak cell group's loss unknown to it); the pack's current and voltage kept on a BMS log
    (``current_voltage``); ``oracle``: the hidden effect's own power, from ``without``."""
    logged = ["time_s", "clock_h", "speed_mps", "soc_frac", "ambient_degc", "charging",
              "charger_kw", "door_open", "battery_current_a", "battery_voltage_v"]
    if case.hidden == "road_grade":
        logged.append("altitude_m")
    if case.hidden == "passenger_mass":
        logged.append("passengers")
    clean = trace[logged].copy()
    clean.attrs.update(trace.attrs, capacity_ah=base["capacity_ah"], chemistry=base["chemistry"])
    log = degrade(clean, np.random.default_rng(_streams(case)[3]),
                  relative_time=case.relative_time, current_voltage=current_voltage)
    if oracle:
        log["logged_load_kw"] = effect_load_kw(trace["time_s"].to_numpy(float),
                                               _used_series(trace) - _used_series(without))
    return log


def record(case: Case, plan: pd.DataFrame, base: dict, ph: dict, day: dict,
           trace: pd.DataFrame, without: pd.DataFrame, columns: list[str],
           source: str = SOURCE) -> dict:
    """The truth record of a case's day (see :func:`generate`), from the day's trace with
    the effect and the same day's without it. A source's trace needs the truth simulator's
    energy columns (``e_drive_dc_j, e_aux_j, e_hidden_j, e_force_j, e_battery_loss_j,
    e_charger_j``), their powers ``p_hidden_w, p_force_w`` and what :func:`modes` reads."""
    acting = case.hidden if case.active else None
    mode = modes(trace)
    force = acting in FORCES
    hidden_j = float(trace["e_force_j" if force else "e_hidden_j"].iloc[-1])
    shares = None
    if hidden_j > 0.0:
        per = np.bincount(mode, weights=trace["p_force_w" if force else "p_hidden_w"].to_numpy(),
                          minlength=len(MODES))
        shares = {m: round(float(s / per.sum()), 4) for m, s in zip(MODES, per, strict=True)}
    expected = VERDICTS[acting] if acting else None
    km = float(trace["distance_m"].iloc[-1]) / 1000.0
    net_kwh = float(trace["e_drive_dc_j"].iloc[-1] + trace["e_aux_j"].iloc[-1]
                    + trace["e_hidden_j"].iloc[-1]) / 3.6e6
    truth = {
        **asdict(case),
        "source": source,
        "columns": columns,
        "expected_verdict": expected,
        "outside_mode": (max(shares, key=shares.get)
                         if expected == "outside_library" and shares else None),
        "mode_shares": shares,
        # a load spread over modes (the compressor: standing and pulling away) has more than
        # one right clue: every mode with at least a quarter of its energy
        "outside_modes": (sorted(m for m, v in shares.items() if v >= 0.25)
                          if expected == "outside_library" and shares else None),
        "strength": _strength(case.hidden, ph, trace),
        "physical": ph,
        "base": {k: (v if isinstance(v, str) else float(v)) for k, v in base.items()},
        "date": plan.attrs["date"],
        "charger_kw": plan.attrs["charger_kw"],
        "charger_terminals": plan.attrs["charger_terminals"],
        "ambient_mean_degc": round(float(trace["ambient_degc"].mean()), 2),
        # seconds the voltage floor cut traction (a cold or nearly empty pack)
        "derated_s": int(trace["derated"].sum()),
        **day,
        "summary": {"km": round(km, 3),
                    "kwh_per_km": round(net_kwh / km, 4),
                    "hidden_kwh": round(hidden_j / 3.6e6, 3),
                    "effect_kwh": round((_used_j(trace) - _used_j(without)) / 3.6e6, 3),
                    "charger_kwh": round(float(trace["e_charger_j"].iloc[-1]) / 3.6e6, 3),
                    "soc_min_pct": round(100.0 * float(trace["soc_frac"].min()), 2),
                    "soc_max_pct": round(100.0 * float(trace["soc_frac"].max()), 2),
                    "soc_footprint_pct": soc_footprint_pct(trace, without)},
    }
    return truth


def soc_footprint_pct(trace: pd.DataFrame, without: pd.DataFrame) -> float:
    """The most the hidden effect moves the SoC at any moment of the day [percentage points]:
    what a SoC log can show of it. A charge session that runs to its stop SoC puts back what
    a load took before it, so a load can take many kWh and leave a small footprint."""
    gap = trace["soc_frac"].to_numpy(float) - without["soc_frac"].to_numpy(float)
    return round(100.0 * float(np.max(np.abs(gap))), 3)


def _atomic_write(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def log_bytes(log: pd.DataFrame) -> bytes:
    """The log as gzip-compressed CSV bytes, with no time or name in the gzip header."""
    buf = io.BytesIO()
    with gzip.GzipFile(filename="", mode="wb", fileobj=buf, mtime=0) as gz:
        gz.write(log.to_csv(index=False, lineterminator="\n").encode())
    return buf.getvalue()


def write(case_list: list[Case], out_dir: str | Path, generate_fn=None,
          truth_name: str = "truth.json", current_voltage: bool = False) -> list[dict]:
    """Write each case's ``<case_id>.csv.gz`` and all truth records in ``truth_name``
    (``generate_fn``: a source's ``generate``, default the truth simulator's); prints each
    day's figures and the seconds it took."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    records = []
    for case in case_list:
        start = time.perf_counter()
        log, truth = (generate_fn or generate)(case, current_voltage=current_voltage)
        _atomic_write(out / f"{case.case_id}.csv.gz", log_bytes(log))
        records.append(truth)
        s = truth["summary"]
        print(f"{case.case_id:<36} {truth['chemistry'] or '-':4s} {truth['route']:<5} "
              f"{s['km']:6.1f} km {s['kwh_per_km']:.3f} kWh/km  effect {s['effect_kwh']:6.2f} "
              f"kWh  SoC {s['soc_min_pct']:.1f}-{s['soc_max_pct']:.1f} %  "
              f"{time.perf_counter() - start:5.2f} s", flush=True)
    _atomic_write(out / truth_name,
                  (json.dumps(records, indent=1, sort_keys=True) + "\n").encode())
    return records


def cli(module, argv: list[str] | None, truth_name: str) -> None:
    """A truth source's command: its single days (``--n-per-effect``, ``--n-control``,
    ``--effects``) and with ``--buses N`` its multi-day buses (N per condition, and
    ``--control-buses``), as logs and truth records in ``--out``; ``--current-voltage``
    writes BMS logs (the pack's current and voltage kept)."""
    parser = argparse.ArgumentParser(description=module.__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help=f"folder for the logs and {truth_name}")
    parser.add_argument("--n-per-effect", type=int, default=10)
    parser.add_argument("--n-control", type=int, default=30)
    parser.add_argument("--seed", type=int, default=DEFAULT_SEED)
    parser.add_argument("--effects", default=None, help="comma-separated subset of the "
                        "single days' hidden effects")
    parser.add_argument("--buses", type=int, default=0,
                        help="multi-day buses per condition (their days and bus_" + truth_name
                        + "; 0: none)")
    parser.add_argument("--control-buses", type=int, default=4)
    parser.add_argument("--current-voltage", action="store_true",
                        help="BMS logs: keep the pack's current and voltage")
    args = parser.parse_args(argv)
    effects = tuple(args.effects.split(",")) if args.effects else None
    listed = module.cases(args.n_per_effect, args.n_control, args.seed)
    known = {c.hidden for c in listed} - {None}
    if effects and set(effects) - known:
        parser.error(f"unknown effects {sorted(set(effects) - known)}; known: "
                     f"{', '.join(sorted(known))}")
    chosen = [c for c in listed if not effects or c.hidden is None or c.hidden in effects]
    write(chosen, args.out, module.generate, truth_name, args.current_voltage)
    if args.buses:
        buses = module.buses(args.buses, args.control_buses, args.seed)
        days = [d for b in buses for d in module.bus_days(b)]
        records = write(days, args.out, module.generate, "days_" + truth_name,
                        args.current_voltage)
        by_id = {r["case_id"]: r for r in records}
        truths = [module.bus_truth(b, [by_id[d.case_id] for d in module.bus_days(b)])
                  for b in buses]
        _atomic_write(Path(args.out) / ("bus_" + truth_name),
                      (json.dumps(truths, indent=1, sort_keys=True) + "\n").encode())


def main(argv: list[str] | None = None) -> None:
    cli(sys.modules[__name__], argv, "truth.json")


if __name__ == "__main__":
    main()
