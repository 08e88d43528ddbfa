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
import tempfile
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from benchmarks.truth.days import _SEASONS, route_day
from benchmarks.truth.degrade import degrade, effect_load_kw
from benchmarks.truth.sim import AIR_CP_J_PER_KG_K, HIDDEN, simulate
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
}
assert set(EFFECTS) == set(HIDDEN)
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


def cases(n_per_effect: int = 10, n_control: int = 30, seed: int = DEFAULT_SEED,
          effects: tuple[str, ...] | None = None) -> list[Case]:
    """The case list: ``n_per_effect`` days per hidden effect, then ``n_control`` days with
    nothing hidden. Chemistry alternates LFP/NMC and the route cycles through rt7/rt44/rt45."""
    rng = np.random.default_rng(seed)
    routes = ("rt7", "rt44", "rt45")
    out = []
    for hidden in (*(effects or tuple(EFFECTS)), None):
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
                         case.route, climate=case.climate, **chargers)
        base["driver_preview_s"], ph, day = _physics_draw(phys_ss, case, plan)
        if case.bus_seed is not None and case.hidden is not None:  # another day of one bus:
            # the effect's values as the bus's first day drew them
            first = _physics_draw(np.random.SeedSequence(case.bus_seed).spawn(4)[2], case, plan)
            ph.update({k: v for k, v in first[1].items() if k not in DAY_LEVEL})
        trace = simulate(plan, base, case.hidden, ph, **day)
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
    log_ss = _streams(case)[3]
    # the hidden effect's size: the energy the loads and the battery's losses take, with the
    # effect against the same day without it
    without = trace if case.hidden is None else simulate(plan, base, None, {}, **day)
    logged = ["time_s", "clock_h", "speed_mps", "soc_frac", "ambient_degc", "charging",
              "charger_kw", "door_open"]
    if case.hidden == "road_grade":
        logged.append("altitude_m")
    if case.hidden == "passenger_mass":
        logged.append("passengers")
    if current_voltage:
        logged += ["battery_current_a", "battery_voltage_v"]
    clean = trace[logged].copy()
    clean.attrs.update(trace.attrs)
    log = degrade(clean, np.random.default_rng(log_ss), relative_time=case.relative_time,
                  current_voltage=current_voltage)
    if oracle:
        log["logged_load_kw"] = effect_load_kw(trace["time_s"].to_numpy(float),
                                               _used_series(trace) - _used_series(without))

    mode = modes(trace)
    hidden_j = float(trace["e_hidden_j"].iloc[-1])
    shares = None
    if hidden_j > 0.0:
        per = np.bincount(mode, weights=trace["p_hidden_w"].to_numpy(), minlength=len(MODES))
        shares = {m: round(float(s / per.sum()), 4) for m, s in zip(MODES, per, strict=True)}
    expected = EFFECTS[case.hidden][0] if case.hidden else None
    km = float(trace["distance_m"].iloc[-1]) / 1000.0
    net_kwh = (float(trace["e_drive_dc_j"].iloc[-1] + trace["e_aux_j"].iloc[-1]) + hidden_j) / 3.6e6
    truth = {
        **asdict(case),
        "source": SOURCE,
        "columns": list(log.columns),
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
    return log, truth


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


def write(case_list: list[Case], out_dir: str | Path) -> list[dict]:
    """Write each case's ``<case_id>.csv.gz`` and all truth records in ``truth.json``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    records = []
    for case in case_list:
        log, truth = generate(case)
        _atomic_write(out / f"{case.case_id}.csv.gz", log_bytes(log))
        records.append(truth)
    _atomic_write(out / "truth.json",
                  (json.dumps(records, indent=1, sort_keys=True) + "\n").encode())
    return records


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="folder for the logs and truth.json")
    parser.add_argument("--n-per-effect", type=int, default=10)
    parser.add_argument("--n-control", type=int, default=30)
    parser.add_argument("--seed", type=int, default=DEFAULT_SEED)
    parser.add_argument("--effects", default=None,
                        help=f"comma-separated subset of {','.join(EFFECTS)}")
    args = parser.parse_args(argv)
    effects = tuple(args.effects.split(",")) if args.effects else None
    if effects and set(effects) - set(EFFECTS):
        parser.error(f"unknown effects {sorted(set(effects) - set(EFFECTS))}; "
                     f"known: {', '.join(EFFECTS)}")
    records = write(cases(args.n_per_effect, args.n_control, args.seed, effects), args.out)
    for r in records:
        s = r["summary"]
        print(f"{r['case_id']:<20} {r['chemistry']} {r['route']:<5} {s['km']:7.1f} km "
              f"{s['kwh_per_km']:.3f} kWh/km  effect {s['effect_kwh']:6.2f} kWh  "
              f"SoC {s['soc_min_pct']:.1f}-{s['soc_max_pct']:.1f} %")


if __name__ == "__main__":
    main()
