"""FASTSim 3 as a third-party truth source: a BEV from FASTSim's own vehicle files, scaled to a
12 m city bus, driven through the same route days as the independent simulator.

FASTSim (NREL's Future Automotive Systems Technology Simulator, ``fastsim`` 3.x on PyPI,
Apache-2.0) is a forward-facing vehicle model of its own: road load with a wheel-inertia term,
a traction limit, an electric-machine efficiency map over output power, a constant-efficiency
pack, and a lumped cabin with a PID-controlled HVAC (resistance heater or heat pump, cooling at
a fraction of the Carnot COP). None of it shares code or equations with ``ebus_env``.

How a day is made
-----------------
1. The driving plan comes from :func:`benchmarks.truth.days.route_day` (the same King County
   route days as the independent simulator): FASTSim drives the plan's 1 Hz target speed as
   its cycle, with the plan's grade on road-grade days and 0 elsewhere, and the plan's ambient
   temperature and solar load on HVAC days.
2. The bus (:func:`bus_vehicle`) is the Renault Zoe ZE50 file shipped with FASTSim 3
   (a BEV without thermal models, constant pack efficiency), with the chassis, motor, pack and
   auxiliary fields replaced by a 12 m bus's; on HVAC days the lumped cabin and HVAC of
   FASTSim's 2016 Nissan Leaf thermal file are added, scaled to a bus cabin.
3. FASTSim's vehicle mass and auxiliary power are constant during a run. Days whose hidden
   effect changes them over the day (passenger mass, a time-of-day auxiliary load) are run as
   a chain of FASTSim runs cut at standstill samples where the mass or load changes.
4. FASTSim 3.1 starts every run at the pack's ``max_soc`` and does not charge at standstill
   (a cycle's ``pwr_max_chrg_watts`` had no effect on the pack in 3.1.0). So FASTSim's pack is
   a large energy meter: its energy out per step is taken from its SoC history, and the logged
   SoC of the bus's real pack (capacity ``capacity_kwh``) is rebuilt from it, with the plan's
   opportunity charging added at layovers by this module (:func:`rebuild_soc`): the rated
   power times a charge efficiency, tapering linearly towards the day's stop SoC, where the
   session ends.
   A whole-day run starts with a 10 min pre-trip standstill (auxiliaries and HVAC on, dropped
   from the log): a run that starts at ``max_soc`` would otherwise refuse regeneration above
   it on a downhill start. A run whose FASTSim pack returns to full raises an error.
5. The clean trace goes through :func:`benchmarks.truth.degrade.degrade`.

FASTSim's pack efficiency is constant, so the capacity of its energy meter does not change the
physics; the bus's pack has no chemistry (``chemistry: None`` in the truth record).
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import time
from functools import cache
from pathlib import Path

import numpy as np
import pandas as pd

from benchmarks.truth import cases as truthsim
from benchmarks.truth.days import route_day
from benchmarks.truth.degrade import degrade, effect_load_kw

try:
    import fastsim
except ImportError:  # the bench's other source runs without it
    fastsim = None

FASTSIM_VERSION = "3.1.0"  # the version this module was written and checked against
SOURCE = "fastsim"
BASE_VEHICLE = "2022_Renault_Zoe_ZE50_R135.yaml"
THERMAL_DONOR = "2016 Nissan Leaf 30 kWh thrml.yaml"
KELVIN = 273.15

# Nominal 12 m bus. Curb mass, c_d, A and C_rr: ADVISOR vehicle files VEH_RTS06 (glider
# 12 156 kg, A = 7.90 m^2, c_d 0.79) and VEH_ORIONVI (12 636 kg, 7.24 m^2), C_rr 0.008
# (ADVISOR, Bosch); motor 200 kW, 200 kWh pack, 450 kW opportunity charging: the Volvo 7900
# Electric of Hasan et al., Appl. Sci. 2023, 13(2), 940. Wheel radius 0.48 m (275/70 R22.5).
NOMINAL = {
    "curb_mass_kg": 13000.0,
    "drag_coef": 0.70,
    "frontal_area_m2": 7.5,
    "rolling_coef": 0.008,
    "motor_kw": 200.0,
    "capacity_kwh": 200.0,
    "drivetrain_efficiency": 0.94,  # gearbox and final drive, on top of FASTSim's motor map
}
WHEEL_RADIUS_M = 0.48
WHEEL_INERTIA_KG_M2 = 15.0  # assumed: a 22.5" wheel with tyre, ~100 kg at ~0.4 m gyration
# FASTSim 3.1.0 raises an error (instead of blending friction brakes) when a braking step asks
# the motor for more than its rating; the motor's rating is therefore this factor times the
# bus's, with its efficiency map rescaled so that the efficiency at a given power is the
# rated motor's (see bus_vehicle)
MOTOR_HEADROOM = 3.0
FASTSIM_PACK_KWH = 5000.0  # FASTSim's pack: an energy meter that never runs empty in a day
PRETRIP_S = 600
CHARGE_EFFICIENCY = 0.93  # charger to cells (assumed)
TAPER_FRAC = 0.05  # the charge power tapers linearly over this SoC below the stop SoC
END_OF_CHARGE_FRAC = 0.05  # a session ends below this fraction of the rated power (~C/20)
BUS_CABIN_M = (12.0, 2.55, 2.3)  # length, width, interior height (EU maximum width 2.55 m)
CAR_CABIN_HEIGHT_M = 1.2  # interior height assumed for the donor car's cabin volume
HVAC_THERMAL_MAX_W = 30000.0  # assumed rating of a 12 m bus roof unit
AIR_CP_J_PER_KG_K = 1005.0
# FASTSim's cabin-to-ambient conductance of the bus cabin with the Leaf's heat-transfer
# coefficients, -sum(Q_from_ambient) / sum(T_cab - T_amb) over four 3 h route days (cold and
# hot, rt7/rt44/rt45): 299-321 W/K
FASTSIM_CABIN_W_PER_K = 315.0

# the hidden effects FASTSim's own models express (names, verdicts and climates as in cases.py)
HIDDEN = ("road_grade", "cabin_heating", "cabin_cooling", "passenger_mass", "aux_schedule")
HVAC_EFFECTS = ("cabin_heating", "cabin_cooling")


def require_fastsim() -> None:
    """Raise a clear error when ``fastsim`` is not installed."""
    if fastsim is None:
        raise ImportError("The FASTSim truth source needs fastsim: "
                          f"pip install 'fastsim=={FASTSIM_VERSION}' (the 'bench' extra)")


@cache
def _donor(name: str) -> dict:
    return fastsim.Vehicle.from_resource(name).to_dict()


def draw_base(rng: np.random.Generator) -> dict:
    """Base parameters of one day's bus, drawn over the spreads of the bench: curb mass +-15 %,
    C_rr +-30 %, c_d A +-20 % (through c_d), drivetrain efficiency +-5 points, base auxiliaries
    2-9 kW and capacity +-10 %."""
    return {
        "curb_mass_kg": NOMINAL["curb_mass_kg"] * rng.uniform(0.85, 1.15),
        "rolling_coef": NOMINAL["rolling_coef"] * rng.uniform(0.7, 1.3),
        "drag_coef": NOMINAL["drag_coef"] * rng.uniform(0.8, 1.2),
        "frontal_area_m2": NOMINAL["frontal_area_m2"],
        "drivetrain_efficiency": NOMINAL["drivetrain_efficiency"] + rng.uniform(-0.05, 0.05),
        "aux_base_w": rng.uniform(2000.0, 9000.0),
        "capacity_kwh": NOMINAL["capacity_kwh"] * rng.uniform(0.9, 1.1),
        "motor_kw": NOMINAL["motor_kw"],
    }


def draw_hvac(rng: np.random.Generator, hidden: str) -> dict:
    """The cabin of an HVAC day: setpoint, envelope conductance, fresh air and glazing.

    FASTSim's lumped cabin has one conductance to ambient and no fresh-air term, so its
    heat-transfer coefficients are scaled to carry both the envelope (``ua_w_per_k``) and the
    fresh air (``fresh_air_kg_per_s`` times c_p of air): ``conductance_scale`` is their sum
    over ``FASTSIM_CABIN_W_PER_K``, FASTSim's own conductance for the bus cabin.
    """
    heating = hidden == "cabin_heating"
    ua_w_per_k = rng.uniform(300.0, 550.0)  # the envelope spread of cases.py
    fresh_kg_per_s = rng.uniform(0.3, 0.5)  # the fresh-air spread of cases.py (EN 14750-1)
    return {
        "setpoint_degc": rng.uniform(17.0, 20.0) if heating else rng.uniform(22.0, 25.0),
        "ua_w_per_k": ua_w_per_k,
        "fresh_air_kg_per_s": fresh_kg_per_s,
        "conductance_scale": (ua_w_per_k + fresh_kg_per_s * AIR_CP_J_PER_KG_K)
        / FASTSIM_CABIN_W_PER_K,
        "solar_area_m2": rng.uniform(3.0, 6.0),  # transmitted glazing area tau_g A_glass
    }


def _scale_motor(em: dict, rated_w: float) -> None:
    """Set FASTSim's motor to ``MOTOR_HEADROOM`` times ``rated_w`` with its efficiency at each
    absolute power kept: the output-power grid of the map is divided by the headroom and held
    flat to the new peak; the input-power grid is output over efficiency, as in FASTSim's
    own files."""
    achieved = em["eff_interp_achieved"]["data"]
    frac = np.asarray(achieved["grid"][0]["data"], float) / MOTOR_HEADROOM
    eff = np.asarray(achieved["values"]["data"], float)
    frac, eff = np.append(frac, 1.0), np.append(eff, eff[-1])
    for interp, grid in ((achieved, frac), (em["eff_interp_at_max_input"]["data"], frac / eff)):
        interp["grid"][0].update(data=grid.tolist(), dim=[len(grid)])
        interp["values"].update(data=eff.tolist(), dim=[len(eff)])
    em["pwr_out_max_watts"] = MOTOR_HEADROOM * rated_w


def bus_vehicle(base: dict, mass_kg: float, aux_w: float, hvac: dict | None = None,
                cabin_temp_degc: float | None = None) -> dict:
    """FASTSim vehicle dict of the bus.

    Fields replaced in the donor BEV (and why):

    * ``mass_kilograms``: curb mass plus passengers; chassis and component masses are cleared
      so that FASTSim uses this total;
    * ``chassis``: ``drag_coef``, ``frontal_area_square_meters`` and ``wheel_rr_coef`` carry the
      bus's road load; six 0.48 m wheels with a bus wheel's inertia; rear drive with 65 % of
      the weight on the drive axle (traction limit);
    * ``pt_type.BEV.em``: ``MOTOR_HEADROOM`` times the bus motor's rating, and the efficiency
      maps (over the fraction of rated power) squeezed by the same factor and held flat above
      the rated power: the efficiency at a given power is the rated motor's, and braking
      never asks more than FASTSim 3.1.0 can take (so regeneration is not cut at the motor
      rating: the one place where this bus recovers more than a real one would);
    * ``pt_type.BEV.transmission.eff_interp``: the drawn drivetrain efficiency;
    * ``pt_type.BEV.res``: energy ``FASTSIM_PACK_KWH`` (an energy meter, see the module
      docstring), SoC window 0-1, no power limit of its own beyond the motor's;
    * ``pwr_aux_base_watts``: the base auxiliaries (plus a time-of-day load when hidden);
    * on HVAC days ``cabin`` and ``hvac`` from the Leaf thermal file: the cabin's length and
      width of a 12 m bus, its heat capacitance and the PID gains scaled by the ratio of
      interior volumes (so the controller's time constants stay as FASTSim calibrated them),
      the heat-transfer coefficients to ambient (moving and standing) by the day's
      ``conductance_scale`` (:func:`draw_hvac`), a heat pump, and a bus roof unit's rating.
    """
    veh = copy.deepcopy(_donor(BASE_VEHICLE))
    veh["name"] = "12 m city bus (scaled from the FASTSim Renault Zoe ZE50)"
    veh["mass_kilograms"] = float(mass_kg)
    veh["pwr_aux_base_watts"] = float(aux_w)
    veh["chassis"].update(
        drag_coef=base["drag_coef"], frontal_area_square_meters=base["frontal_area_m2"],
        wheel_rr_coef=base["rolling_coef"], wheel_inertia_kilogram_square_meters=WHEEL_INERTIA_KG_M2,
        num_wheels=6, wheel_radius_meters=WHEEL_RADIUS_M, drive_type="RWD",
        drive_axle_weight_frac=0.65, wheel_base_meters=6.0, cg_height_meters=1.0,
        mass_kilograms=None, glider_mass_kilograms=None, cargo_mass_kilograms=None)
    bev = veh["pt_type"]["BEV"]
    _scale_motor(bev["em"], base["motor_kw"] * 1e3)
    bev["transmission"]["eff_interp"] = base["drivetrain_efficiency"]
    res = bev["res"]
    res.update(energy_capacity_joules=FASTSIM_PACK_KWH * 3.6e6, min_soc=0.0, max_soc=1.0,
               pwr_out_max_watts=2.0 * MOTOR_HEADROOM * base["motor_kw"] * 1e3)
    if hvac is not None:
        leaf = _donor(THERMAL_DONOR)
        cabin = copy.deepcopy(leaf["cabin"])
        lumped = cabin["LumpedCabin"]
        length_m, width_m, height_m = BUS_CABIN_M
        volume_ratio = (length_m * width_m * height_m) / (
            lumped["length_meters"] * lumped["width_meters"] * CAR_CABIN_HEIGHT_M)
        lumped.update(length_meters=length_m, width_meters=width_m)
        lumped["heat_capacitance_joules_per_kelvin"] *= volume_ratio
        for key in ("cab_shell_htc_to_amb_watts_per_square_meter_kelvin",
                    "cab_htc_to_amb_stop_watts_per_square_meter_kelvin"):
            lumped[key] *= hvac["conductance_scale"]
        start_k = KELVIN + (cabin_temp_degc if cabin_temp_degc is not None
                            else hvac["setpoint_degc"])
        lumped["state"].update(temperature_kelvin=start_k, temp_prev_kelvin=start_k)
        control = copy.deepcopy(leaf["hvac"])
        pid = control["LumpedCabin"]
        pid["te_set_kelvin"] = KELVIN + hvac["setpoint_degc"]
        pid["p_watts_per_kelvin"] *= volume_ratio
        pid["i"] *= volume_ratio
        pid.update(heat_source="HeatPump", pwr_i_max_watts=HVAC_THERMAL_MAX_W,
                   pwr_thrml_max_watts=HVAC_THERMAL_MAX_W,
                   pwr_aux_for_hvac_max_watts=HVAC_THERMAL_MAX_W)
        veh["cabin"], veh["hvac"] = cabin, control
    return veh


def _cycle(speed_mps: np.ndarray, grade_frac: np.ndarray, ambient_degc: np.ndarray,
           solar_w: np.ndarray, altitude_m: float):
    n = len(speed_mps)
    return fastsim.Cycle.from_dict({
        "time_seconds": np.arange(n, dtype=float).tolist(),
        "speed_meters_per_second": np.asarray(speed_mps, float).tolist(),
        "grade": np.asarray(grade_frac, float).tolist(),
        "pwr_max_chrg_watts": [0.0] * n,
        "temp_amb_air_kelvin": (np.asarray(ambient_degc, float) + KELVIN).tolist(),
        "pwr_solar_load_watts": np.asarray(solar_w, float).tolist(),
        "init_elev_meters": float(altitude_m),
    })


_HISTORY = {
    "soc_fs": "veh.pt_type.BEV.res.history.soc",
    "speed_mps": "veh.history.speed_ach_meters_per_second",
    "distance_m": "veh.history.dist_meters",
    "rolling_w": "veh.history.pwr_rr_watts",
    "drag_w": "veh.history.pwr_drag_watts",
    "air_density_kg_per_m3": "veh.history.air_density_kilograms_per_cubic_meter",
    "cabin_temp_k": "veh.cabin.LumpedCabin.history.temperature_kelvin",
    "cabin_from_ambient_w": "veh.cabin.LumpedCabin.history.pwr_thrml_from_amb_watts",
    "hvac_elec_w": "veh.hvac.LumpedCabin.history.pwr_aux_for_hvac_watts",
    "hvac_thermal_w": "veh.hvac.LumpedCabin.history.pwr_thrml_hvac_to_cabin_watts",
}


def run_fastsim(veh: dict, speed_mps, grade_frac, ambient_degc, solar_w, altitude_m: float,
                pretrip_s: int = 0) -> dict[str, np.ndarray]:
    """One FASTSim run; returns the history rows after the pre-trip standstill, with
    ``energy_out_j`` the pack's energy out in each step (0 in the first row)."""
    pre = np.zeros(pretrip_s)
    cyc = _cycle(np.concatenate((pre, speed_mps)), np.concatenate((pre, grade_frac)),
                 np.concatenate((pre + ambient_degc[0], ambient_degc)),
                 np.concatenate((pre, solar_w)), altitude_m)
    params = fastsim.SimParams.default().to_dict()
    params["trace_miss_opts"] = "Allow"  # a heavy bus may fall behind the plan on a climb
    sim = fastsim.SimDrive(fastsim.Vehicle.from_dict(veh), cyc, fastsim.SimParams.from_dict(params))
    sim.run()
    frame = sim.to_dataframe()
    out = {key: frame[col].to_numpy(float)[pretrip_s:] for key, col in _HISTORY.items()
           if col in frame.columns}
    soc = out.pop("soc_fs")
    if np.max(soc[1:], initial=0.0) >= 1.0 - 1e-12:
        raise RuntimeError("FASTSim's pack came back to full: regeneration was refused; "
                           "lengthen the pre-trip standstill")
    out["energy_out_j"] = np.concatenate(([0.0], -np.diff(soc))) * FASTSIM_PACK_KWH * 3.6e6
    out["distance_m"] = out["distance_m"] - out["distance_m"][0]
    return out


def rebuild_soc(energy_out_j: np.ndarray, charger_w: np.ndarray, capacity_kwh: float,
                start_soc_frac: float, stop_soc_frac: float,
                dt_s: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """SoC of the bus's pack [1] and the charging-session flag, from the energy FASTSim's pack
    gave out per step [J] and the rated power of the charger the bus stands under [W] (0 off
    a charger).

    ``SoC_k = SoC_{k-1} - E_out,k / E_cap + eta_c P_c f(SoC_{k-1}) dt / E_cap`` with
    ``f = clip((SoC_stop - SoC) / TAPER, 0, 1)``: full power up to ``TAPER`` below the
    session's stop SoC, then a linear taper (the constant-voltage phase). The session ends
    when ``f`` falls below ``END_OF_CHARGE_FRAC`` (the end-of-charge current) and stays ended
    until the bus leaves the charger.
    """
    e_cap_j = capacity_kwh * 3.6e6
    soc = np.empty(len(energy_out_j))
    session = np.zeros(len(energy_out_j), dtype=np.int8)
    soc[0] = start_soc_frac
    ended = False
    for k in range(1, len(soc)):
        taper = min(max((stop_soc_frac - soc[k - 1]) / TAPER_FRAC, 0.0), 1.0)
        ended = charger_w[k] > 0.0 and (ended or taper < END_OF_CHARGE_FRAC)
        on = charger_w[k] > 0.0 and not ended
        session[k] = on
        soc[k] = (soc[k - 1] - energy_out_j[k] / e_cap_j
                  + (CHARGE_EFFICIENCY * charger_w[k] * taper * dt_s / e_cap_j if on else 0.0))
    return soc, session


def _pieces(speed_mps: np.ndarray, *piecewise: np.ndarray) -> list[tuple[int, int]]:
    """Sample ranges ``[a, b]`` to run one after the other: every ``piecewise`` array keeps its
    value at ``a`` on ``a..b-1`` and changes only at a standstill sample, where one run ends
    and the next starts (consecutive ranges share that sample)."""
    change = np.zeros(len(speed_mps), dtype=bool)
    for values in piecewise:
        change[1:] |= values[1:] != values[:-1]
    starts = np.flatnonzero(change)
    if np.any(speed_mps[starts] > 0.0):
        raise ValueError("a piecewise input changes while the bus moves")
    edges = np.concatenate(([0], starts, [len(speed_mps) - 1]))
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def aux_schedule_w(clock_h: np.ndarray, speed_mps: np.ndarray, on_before_h: float,
                   on_after_h: float, power_w: float) -> np.ndarray:
    """A time-of-day load [W]: ``power_w`` before ``on_before_h`` and after ``on_after_h``
    (lights, destination signs and heated mirrors in the dark), switched at the first
    standstill after each switch time (FASTSim's auxiliary power is constant within a run)."""
    dark = (clock_h % 24.0 < on_before_h) | (clock_h % 24.0 >= on_after_h)
    switch = np.flatnonzero(np.diff(dark.astype(int))) + 1
    held = dark.copy()
    for i in switch:
        stands = np.flatnonzero(speed_mps[i:] == 0.0)
        j = i + int(stands[0]) if len(stands) else len(held)  # first standstill from i
        held[i:j] = dark[i - 1]
    return np.where(held, power_w, 0.0)


def simulate(plan: pd.DataFrame, base: dict, hidden: str | None, effect: dict,
             soc0_frac: float = 0.8, charge_stop_frac: float = 0.9) -> pd.DataFrame:
    """Clean truth trace of one day (1 Hz): plan + base parameters + hidden effect.

    Returns ``time_s, clock_h, speed_mps, soc_frac, ambient_degc, plugged`` (under a
    charger), ``charging, charger_kw`` (while a session runs), ``door_open, altitude_m,
    passengers`` plus ``energy_out_j`` (FASTSim's pack energy out per
    step), ``distance_m``, ``aux_w``, ``p_hidden_w`` (a hidden load), ``mass_kg`` and, on HVAC days,
    ``cabin_temp_degc``, ``hvac_elec_w``, ``hvac_thermal_w``, ``cabin_from_ambient_w``.
    """
    require_fastsim()
    speed = plan["speed_target_mps"].to_numpy(float)
    n = len(speed)
    grade = plan["grade_frac"].to_numpy(float) if hidden == "road_grade" else np.zeros(n)
    altitude = plan["altitude_m"].to_numpy(float) if hidden == "road_grade" \
        else np.full(n, float(plan["altitude_m"].iloc[0]))
    ambient = plan["ambient_degc"].to_numpy(float)
    hvac = effect if hidden in HVAC_EFFECTS else None
    solar = plan["solar_w_per_m2"].to_numpy(float) * hvac["solar_area_m2"] if hvac \
        else np.zeros(n)
    passengers = plan["passengers"].to_numpy(int) if hidden == "passenger_mass" \
        else np.zeros(n, dtype=int)
    mass = base["curb_mass_kg"] + passengers * effect.get("passenger_mass_kg", 0.0)
    hidden_w = np.zeros(n)
    if hidden == "aux_schedule":  # the lights of cases.py
        hidden_w = aux_schedule_w(plan["clock_h"].to_numpy(float), speed,
                                  effect["lights_off_h"], effect["lights_on_h"],
                                  effect["lights_w"])
    aux = base["aux_base_w"] + hidden_w
    pieces = _pieces(speed, mass, aux)
    pretrip = PRETRIP_S if len(pieces) == 1 else 0  # chained days are flat: see the docstring
    runs = []
    cabin_temp = None
    for a, b in pieces:
        sl = slice(a, b + 1)
        veh = bus_vehicle(base, mass[a], aux[a], hvac, cabin_temp)
        run = run_fastsim(veh, speed[sl], grade[sl], ambient[sl], solar[sl], altitude[a],
                          pretrip)
        if hvac is not None:
            cabin_temp = run["cabin_temp_k"][-1] - KELVIN
        runs.append({k: v if not runs else v[1:] for k, v in run.items()})
    hist = {k: np.concatenate([r[k] for r in runs]) for k in runs[0]}
    hist["distance_m"] = np.concatenate(
        [r["distance_m"] + off for r, off in
         zip(runs, np.cumsum([0.0] + [r["distance_m"][-1] for r in runs[:-1]]), strict=True)])
    charger_w = plan["charger_kw"].to_numpy(float) * 1e3 * plan["charging"].to_numpy(float)
    soc, session = rebuild_soc(hist["energy_out_j"], charger_w, base["capacity_kwh"],
                               soc0_frac, charge_stop_frac)
    clean = pd.DataFrame({
        "time_s": plan["time_s"].to_numpy(float),
        "clock_h": plan["clock_h"].to_numpy(float),
        "speed_mps": hist["speed_mps"],
        "soc_frac": soc,
        "ambient_degc": ambient,
        # as in the independent simulator: the logged session ends at the stop SoC, though
        # the bus may stay under the charger
        "plugged": plan["charging"].to_numpy(int),
        "charging": session.astype(int),
        "charger_kw": np.where(session == 1, charger_w / 1e3, 0.0),
        "door_open": plan["door_open"].to_numpy(int),
        "altitude_m": altitude,
        "passengers": passengers,
        "energy_out_j": hist["energy_out_j"],
        "distance_m": hist["distance_m"],
        "aux_w": aux,
        "p_hidden_w": hidden_w,
        "mass_kg": mass,
    })
    if hvac is not None:
        clean["cabin_temp_degc"] = hist["cabin_temp_k"] - KELVIN
        for key in ("hvac_elec_w", "hvac_thermal_w", "cabin_from_ambient_w"):
            clean[key] = hist[key]
        clean["p_hidden_w"] = hist["hvac_elec_w"]
    clean.attrs.update(plan.attrs)
    return clean


def consumption_kwh_per_km(clean: pd.DataFrame) -> float:
    """Energy the pack gave out over the day per distance driven [kWh/km] (charging excluded)."""
    return float(clean["energy_out_j"].sum() / 3.6e6 / (clean["distance_m"].iloc[-1] / 1e3))


def cases(n_per_effect: int = 10, n_control: int = 30,
          seed: int = truthsim.DEFAULT_SEED) -> list[truthsim.Case]:
    """The FASTSim cases: the days of :func:`benchmarks.truth.cases.cases` (same seeds, so the
    same route days) whose hidden effect FASTSim expresses, and the control days."""
    return [dataclasses.replace(c, case_id=f"fastsim_{c.case_id}", chemistry=None)
            for c in truthsim.cases(n_per_effect, n_control, seed)
            if c.hidden is None or c.hidden in HIDDEN]


def _strength(hidden: str | None, effect: dict, clean: pd.DataFrame) -> dict:
    """The truth in the library's parameters, where it has an equivalent."""
    if hidden in HVAC_EFFECTS:
        # FASTSim's conductance over the day, measured from its own history,
        # G = -sum(Q_from_ambient) / sum(T_cab - T_amb): envelope and fresh air together, no
        # doors; the library's UA is what is left of it after the library's fresh and door air
        delta_k = clean["cabin_temp_degc"] - clean["ambient_degc"]
        measured = float(-clean["cabin_from_ambient_w"].sum() / delta_k.sum())
        return {"cabin_hvac.ua_w_per_k": truthsim.library_ua(measured, truthsim.door_weight(clean))}
    return truthsim._strength(hidden, effect, clean)


def generate(case: truthsim.Case, oracle: bool = False) -> tuple[pd.DataFrame, dict]:
    """One case: the degraded 1 Hz log and its truth record (the schema of ``cases.py``);
    ``oracle``: the log has ``logged_load_kw`` too, the power the hidden effect adds to what
    the pack gives out (as in ``cases.generate``)."""
    log, truth, _ = generate_with_clean(case, oracle)
    return log, truth


def generate_with_clean(case: truthsim.Case, oracle: bool = False) -> tuple[
        pd.DataFrame, dict, pd.DataFrame]:
    """:func:`generate`, plus the clean trace (for checks and figures)."""
    require_fastsim()
    hidden = case.hidden
    plan_ss, base_ss, phys_ss, log_ss = truthsim._streams(case)
    base = draw_base(np.random.default_rng(base_ss))
    # as in cases.py: when the drawn chargers leave the pack below MIN_SOC_FRAC, the operator
    # runs the same day with 450 kW at both terminals
    full = {"charger_kw": 450.0, "charger_terminals": (0, 1)}
    for chargers in ({}, full):
        plan = route_day(np.random.default_rng(plan_ss), case.hours, case.start_clock_h,
                         case.route, climate=case.climate, **chargers)
        phys_rng = np.random.default_rng(phys_ss)
        # the day options and the passenger mass and lights of cases.py; FASTSim's own cabin
        effect, day = truthsim._physical(hidden, phys_rng, plan, "LFP")
        if hidden in HVAC_EFFECTS:
            effect = draw_hvac(phys_rng, hidden)
        clean = simulate(plan, base, hidden, effect, **day)
        if clean["soc_frac"].min() >= truthsim.MIN_SOC_FRAC:
            break
    else:
        raise RuntimeError(f"{case.case_id}: the bus cannot finish its day "
                           f"(SoC {100 * clean['soc_frac'].min():.1f} %)")
    # the effect's size: the energy it adds against the same day without it
    without = clean if hidden is None else simulate(plan, base, None, {}, **day)
    # what the log reveals: altitude on grade days, passenger counts on passenger days
    shown = clean.drop(columns=[c for c, keep in (("altitude_m", hidden == "road_grade"),
                                                  ("passengers", hidden == "passenger_mass"))
                                if not keep])
    log = degrade(shown, np.random.default_rng(log_ss), relative_time=case.relative_time)
    if oracle:
        log["logged_load_kw"] = effect_load_kw(
            clean["time_s"].to_numpy(float),
            np.cumsum(clean["energy_out_j"].to_numpy(float) - without["energy_out_j"].to_numpy(float)))
    km = float(clean["distance_m"].iloc[-1]) / 1e3
    out_j = float(clean["energy_out_j"].sum())
    capacity_j = base["capacity_kwh"] * 3.6e6
    soc = clean["soc_frac"]
    truth = {
        **dataclasses.asdict(case),
        "source": SOURCE,
        "columns": list(log.columns),
        "expected_verdict": truthsim.EFFECTS[hidden][0] if hidden else None,
        "outside_mode": None,
        "mode_shares": None,
        "strength": _strength(hidden, effect, clean),
        "physical": {k: float(v) for k, v in effect.items()},
        "base": {k: float(v) for k, v in base.items()},
        "date": plan.attrs["date"],
        "charger_kw": plan.attrs["charger_kw"],
        "charger_terminals": plan.attrs["charger_terminals"],
        **day,
        "summary": {"km": round(km, 3),
                    "kwh_per_km": round(out_j / 3.6e6 / km, 4),
                    "hidden_kwh": round(float(clean["p_hidden_w"].sum()) / 3.6e6, 3),
                    "effect_kwh": round((out_j - float(without["energy_out_j"].sum())) / 3.6e6,
                                        3),
                    # what the charger put in = SoC gained + energy given out
                    "charger_kwh": round((capacity_j * (soc.iloc[-1] - soc.iloc[0]) + out_j)
                                         / 3.6e6, 3),
                    "soc_min_pct": round(100.0 * float(soc.min()), 2),
                    "soc_max_pct": round(100.0 * float(soc.max()), 2),
                    "soc_footprint_pct": truthsim.soc_footprint_pct(clean, without)},
        "fastsim_version": fastsim.__version__,
    }
    return log, truth, clean


def write(case_list: list[truthsim.Case], out_dir: str | Path) -> list[dict]:
    """Write each case's ``<case_id>.csv.gz`` and the truth records in ``truth_fastsim.json``;
    prints each day's figures and FASTSim run time."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    records = []
    for case in case_list:
        start = time.perf_counter()
        log, truth = generate(case)
        seconds = time.perf_counter() - start
        truthsim._atomic_write(out / f"{case.case_id}.csv.gz", truthsim.log_bytes(log))
        records.append(truth)
        s = truth["summary"]
        print(f"{case.case_id:<30} {truth['route']:<5} {case.hours:5.2f} h {s['km']:7.1f} km "
              f"{s['kwh_per_km']:.3f} kWh/km  effect {s['effect_kwh']:6.2f} kWh  "
              f"SoC {s['soc_min_pct']:.1f}-{s['soc_max_pct']:.1f} %  {seconds:5.2f} s")
    truthsim._atomic_write(out / "truth_fastsim.json",
                           (json.dumps(records, indent=1, sort_keys=True) + "\n").encode())
    return records


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="folder for the logs and truth_fastsim.json")
    parser.add_argument("--n-per-effect", type=int, default=10)
    parser.add_argument("--n-control", type=int, default=30)
    parser.add_argument("--seed", type=int, default=truthsim.DEFAULT_SEED)
    args = parser.parse_args(argv)
    write(cases(args.n_per_effect, args.n_control, args.seed), args.out)


if __name__ == "__main__":
    main()
