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
   a large energy meter, and the bus's own pack is added around FASTSim's electrical power at
   the pack terminals (what the motor, auxiliaries and HVAC draw, second by second) by this
   module (:func:`rebuild_pack`): an LFP pack of 200 cells in series with an OCV curve (the
   truth simulator's LFP cell table) and one resistance, its SoC counted in charge, with the
   plan's opportunity charging added at layovers: the rated power times a charge efficiency,
   tapering linearly towards the day's stop SoC, where the session ends, the charge current
   capped so the cells stay at or below 3.65 V. This gives the BMS log its pack current and
   voltage.
   A whole-day run starts with a 10 min pre-trip standstill (auxiliaries and HVAC on, dropped
   from the log): a run that starts at ``max_soc`` would otherwise refuse regeneration above
   it on a downhill start. A run whose FASTSim pack returns to full raises an error.
5. The clean trace goes through :func:`benchmarks.truth.degrade.degrade`.

FASTSim's pack efficiency is constant, so the capacity of its energy meter does not change the
physics. FASTSim 3.1's pack has no voltage: its limits are one power limit both ways
(``pwr_out_max_watts``, flat over SoC) and a hard SoC window (``min_soc``, ``max_soc``: a run
that reaches it stops with an error). It therefore has no voltage window; the bus's pack added
here has one (LFP 2.5-3.65 V per cell, as in ``vehicles.py``), enforced on the charger's
current and checked on what FASTSim drives: a day whose traction or regeneration would take the
cells outside it raises an error (no day of the bench comes near: FASTSim's powers are at most
about 250 kW on a pack of about 650 V).
"""

from __future__ import annotations

import copy
import dataclasses
import sys
from functools import cache
from pathlib import Path

import numpy as np
import pandas as pd

from benchmarks.truth import cases as truthsim
from benchmarks.truth.days import route_day
from benchmarks.truth.degrade import degrade, effect_load_kw
from benchmarks.truth.sim import OCV_TABLES, ocv_cell_v
from benchmarks.truth.vehicles import PACKS

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
    "pack_r_ohm": 0.09,  # the bus's pack around FASTSim's (below)
}
# The bus's pack around FASTSim's terminal power: 200 LFP cells in series (~650 V), the truth
# simulator's LFP OCV table, one resistance R (0.06-0.12 ohm: the 10-s resistance of a 200 kWh
# LFP bus pack, as in vehicles.PACKS), the cells' voltage window of vehicles.PACKS
PACK_CELLS = 200
PACK_CHEMISTRY = "LFP"
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
# the multi-day buses' conditions FASTSim expresses: (library effect to name, how it acts);
# under-inflated tyres raise FASTSim's own rolling-resistance coefficient, a force the library
# has no effect for (its rolling coefficient is a bus-to-bus value, not a change on a day)
MULTI_DAY = {
    "cabin_heating": ("cabin_hvac", "weather"),
    "aux_schedule": ("aux_schedule", "from_day"),
    "capacity_step": ("static_rcd", "from_day"),
    "underinflated_tyres": ("outside_library", "from_day"),
}
VERDICTS = {"underinflated_tyres": "outside_library"}


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
        "pack_r_ohm": rng.uniform(0.06, 0.12),
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
    "elec_out_w": "veh.pt_type.BEV.res.history.pwr_out_electrical_watts",
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


def pack_capacity_ah(capacity_kwh: float) -> float:
    """The bus pack's charge capacity [Ah]: its energy over its nominal voltage, the mean OCV
    of the cells between 10 and 90 % SoC times the cells in series."""
    soc = np.linspace(0.1, 0.9, 81)
    nominal_v = PACK_CELLS * float(np.mean([ocv_cell_v(PACK_CHEMISTRY, x) for x in soc]))
    return capacity_kwh * 1e3 / nominal_v


def rebuild_pack(elec_out_w: np.ndarray, charger_w: np.ndarray, base: dict,
                 start_soc_frac: float, stop_soc_frac: float, capacity_factor: float = 1.0,
                 resistance_factor: float = 1.0, dt_s: float = 1.0) -> dict[str, np.ndarray]:
    """The bus's pack around FASTSim's terminal power: SoC [1], charging-session flag, current
    [A] (> 0 discharging) and terminal voltage [V], second by second.

    Per step, with ``E = N OCV(SoC)`` and the pack's resistance ``R``::

        P_t = P_elec - P_in,   I = (E - sqrt(E^2 - 4 R P_t)) / (2 R),   V = E - R I
        SoC_k = SoC_{k-1} - I dt / (3600 Q)

    ``P_elec`` is FASTSim's electrical power out of its pack (``elec_out_w``) and ``P_in`` the
    charger's power into the bus's pack: ``eta_c P_c f(SoC)`` with ``f = clip((SoC_stop -
    SoC) / TAPER, 0, 1)`` (full power up to ``TAPER`` below the session's stop SoC, then a
    linear taper), the current capped at ``(N V_max - E) / R`` (the cells' charge voltage),
    the session ended when ``f`` falls below ``END_OF_CHARGE_FRAC`` and until the bus leaves
    the charger. ``capacity_factor`` and ``resistance_factor`` scale the pack's capacity and
    resistance (a weak cell group). Raises where FASTSim's own power takes the cells outside
    their voltage window (FASTSim has none: see the module docstring).
    """
    pack = PACKS[PACK_CHEMISTRY]
    n = len(elec_out_w)
    q_as = 3600.0 * pack_capacity_ah(base["capacity_kwh"]) * capacity_factor
    r_ohm = base["pack_r_ohm"] * resistance_factor
    v_max, v_min = PACK_CELLS * pack["cell_v_max"], PACK_CELLS * pack["cell_v_min"]
    ocv_x, ocv_y = (np.asarray(a) for a in OCV_TABLES[PACK_CHEMISTRY])
    out = {k: np.zeros(n) for k in ("soc_frac", "charging", "battery_current_a",
                                    "battery_voltage_v", "charger_in_w")}
    soc = start_soc_frac
    ended = False
    for k in range(n):
        emf = PACK_CELLS * float(np.interp(soc, ocv_x, ocv_y))
        taper = min(max((stop_soc_frac - soc) / TAPER_FRAC, 0.0), 1.0)
        ended = charger_w[k] > 0.0 and (ended or taper < END_OF_CHARGE_FRAC)
        on = k > 0 and charger_w[k] > 0.0 and not ended
        p_t = elec_out_w[k] - (CHARGE_EFFICIENCY * charger_w[k] * taper if on else 0.0)
        disc = emf * emf - 4.0 * r_ohm * p_t
        if disc < 0.0:
            raise RuntimeError(f"row {k}: {p_t / 1e3:.0f} kW is more than the pack can give")
        current = (emf - np.sqrt(disc)) / (2.0 * r_ohm)
        if on:  # the BMS caps the charge current at the cells' charge voltage
            current = max(current, -(v_max - emf) / r_ohm)
        volts = emf - r_ohm * current
        if not v_min - 1e-6 <= volts <= v_max + 1e-6:
            raise RuntimeError(f"row {k}: the pack at {volts / PACK_CELLS:.3f} V per cell, "
                               f"outside the cells' {pack['cell_v_min']}-{pack['cell_v_max']} V")
        if k:
            soc -= current * dt_s / q_as
        out["soc_frac"][k] = soc
        out["charging"][k] = on
        out["battery_current_a"][k] = current
        out["battery_voltage_v"][k] = volts
        out["charger_in_w"][k] = elec_out_w[k] - volts * current if on else 0.0
    out["charging"] = out["charging"].astype(np.int8)
    return out


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

    Returns ``time_s, clock_h, speed_mps, soc_frac, battery_current_a, battery_voltage_v,
    ambient_degc, plugged`` (under a charger), ``charging, charger_kw`` (while a session
    runs), ``door_open, altitude_m, passengers`` plus ``energy_out_j`` (FASTSim's electrical
    energy out of its pack per step: what the bus draws at its pack's terminals),
    ``distance_m``, ``aux_w``, ``p_hidden_w`` (a hidden load), ``p_force_w`` (a hidden
    force's power at the wheel), ``rolling_w``, ``mass_kg`` and, on HVAC days,
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
    rise = effect["rolling_rise_frac"] if hidden == "underinflated_tyres" else 0.0
    run_base = {**base, "rolling_coef": base["rolling_coef"] * (1.0 + rise)}
    aux = base["aux_base_w"] + hidden_w
    pieces = _pieces(speed, mass, aux)
    pretrip = PRETRIP_S if len(pieces) == 1 else 0  # chained days are flat: see the docstring
    runs = []
    cabin_temp = None
    for a, b in pieces:
        sl = slice(a, b + 1)
        veh = bus_vehicle(run_base, mass[a], aux[a], hvac, cabin_temp)
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
    weak = hidden == "capacity_step"
    pack = rebuild_pack(hist["elec_out_w"], charger_w, base, soc0_frac, charge_stop_frac,
                        1.0 - effect["capacity_loss_frac"] if weak else 1.0,
                        1.0 + effect["resistance_growth_frac"] if weak else 1.0)
    clean = pd.DataFrame({
        "time_s": plan["time_s"].to_numpy(float),
        "clock_h": plan["clock_h"].to_numpy(float),
        "speed_mps": hist["speed_mps"],
        "soc_frac": pack["soc_frac"],
        "battery_current_a": pack["battery_current_a"],
        "battery_voltage_v": pack["battery_voltage_v"],
        "ambient_degc": ambient,
        # as in the independent simulator: the logged session ends at the stop SoC, though
        # the bus may stay under the charger
        "plugged": plan["charging"].to_numpy(int),
        "charging": pack["charging"].astype(int),
        "charger_kw": np.where(pack["charging"] == 1, charger_w / 1e3, 0.0),
        "charger_in_w": pack["charger_in_w"],
        "door_open": plan["door_open"].to_numpy(int),
        "altitude_m": altitude,
        "passengers": passengers,
        "energy_out_j": hist["elec_out_w"],  # 1 s steps
        "distance_m": hist["distance_m"],
        "aux_w": aux,
        "p_hidden_w": hidden_w,
        # the under-inflated tyres' share of FASTSim's rolling-resistance power
        "p_force_w": hist["rolling_w"] * rise / (1.0 + rise),
        "rolling_w": hist["rolling_w"],
        "mass_kg": mass,
    })
    if hvac is not None:
        clean["cabin_temp_degc"] = hist["cabin_temp_k"] - KELVIN
        for key in ("hvac_elec_w", "hvac_thermal_w", "cabin_from_ambient_w"):
            clean[key] = hist[key]
        clean["p_hidden_w"] = hist["hvac_elec_w"]
    clean.attrs.update(plan.attrs)
    return clean


def modes(clean: pd.DataFrame) -> np.ndarray:
    """Operating mode of each row (index into ``cases.MODES``) from speed, acceleration and
    the charging session: FASTSim's trace has no wheel force split, so a row accelerates at
    more than 0.1 m/s^2 and brakes at less than -0.1 m/s^2 while moving; a charging row is CC
    (FASTSim's pack has no CV phase of its own)."""
    speed = clean["speed_mps"].to_numpy(float)
    accel = np.gradient(speed)
    mode = np.full(len(speed), 1)
    mode[accel > 0.1] = 0
    mode[(accel < -0.1) & (speed > 0.1)] = 2
    mode[speed <= 0.1] = 3
    mode[clean["charging"].to_numpy() == 1] = 4
    return mode


def consumption_kwh_per_km(clean: pd.DataFrame) -> float:
    """Energy the pack gave out over the day per distance driven [kWh/km] (charging excluded)."""
    return float(clean["energy_out_j"].sum() / 3.6e6 / (clean["distance_m"].iloc[-1] / 1e3))


def cases(n_per_effect: int = 10, n_control: int = 30,
          seed: int = truthsim.DEFAULT_SEED) -> list[truthsim.Case]:
    """The FASTSim cases: the days of :func:`benchmarks.truth.cases.cases` (same seeds, so the
    same route days) whose hidden effect FASTSim expresses, and the control days."""
    return [dataclasses.replace(c, case_id=f"fastsim_{c.case_id}", chemistry=PACK_CHEMISTRY)
            for c in truthsim.cases(n_per_effect, n_control, seed)
            if c.hidden is None or c.hidden in HIDDEN]


def buses(n_per_condition: int = 5, n_control: int = 4,
          seed: int = truthsim.DEFAULT_SEED) -> list[truthsim.Bus]:
    """The multi-day buses of the conditions FASTSim expresses (:data:`MULTI_DAY`)."""
    return [dataclasses.replace(b, bus_id=f"fastsim_{b.bus_id}", chemistry=PACK_CHEMISTRY)
            for b in truthsim.buses(n_per_condition, n_control, seed, MULTI_DAY)]


def bus_days(bus: truthsim.Bus) -> list[truthsim.Case]:
    """The service days of a bus (:func:`benchmarks.truth.cases.bus_days`)."""
    return truthsim.bus_days(bus)


def bus_truth(bus: truthsim.Bus, records: list[dict]) -> dict:
    """The truth record of a multi-day bus (:func:`benchmarks.truth.cases.bus_truth`)."""
    return truthsim.bus_truth(bus, records, SOURCE, MULTI_DAY)


def _strength(hidden: str | None, effect: dict, clean: pd.DataFrame) -> dict:
    """The truth in the library's parameters, where it has an equivalent."""
    if hidden in HVAC_EFFECTS:
        # FASTSim's conductance over the day, measured from its own history,
        # G = -sum(Q_from_ambient) / sum(T_cab - T_amb): envelope and fresh air together, no
        # doors; the library's UA is what is left of it after the library's fresh and door air
        delta_k = clean["cabin_temp_degc"] - clean["ambient_degc"]
        measured = float(-clean["cabin_from_ambient_w"].sum() / delta_k.sum())
        return {"cabin_hvac.ua_w_per_k": truthsim.library_ua(measured, truthsim.door_weight(clean))}
    if hidden == "underinflated_tyres":
        return {}
    return truthsim._strength(hidden, effect, clean)


def _draw_effect(hidden: str | None, rng: np.random.Generator,
                 plan: pd.DataFrame) -> tuple[dict, dict]:
    """A day's hidden-effect values and day options from a physics stream: the day options,
    passenger mass, lights and weak cell group of ``cases.py``, FASTSim's own cabin, and the
    tyres' rise of rolling resistance."""
    effect, day = truthsim._physical(hidden, rng, plan, "LFP")
    if hidden in HVAC_EFFECTS:
        effect = draw_hvac(rng, hidden)
    if hidden == "underinflated_tyres":
        # assumed: tyres 20-40 % below their pressure roll 10-25 % harder
        effect = {"rolling_rise_frac": float(rng.uniform(0.10, 0.25))}
    return effect, day


def day_trace(case: truthsim.Case) -> tuple[pd.DataFrame, dict, dict, dict, pd.DataFrame]:
    """The plan, bus, hidden effect's values, day options and clean trace of a case (as in
    ``cases.py``: where the drawn chargers leave the pack below ``MIN_SOC_FRAC``, the operator
    runs the same day with 450 kW at both terminals)."""
    require_fastsim()
    hidden = case.hidden
    plan_ss, base_ss, phys_ss, _ = truthsim._streams(case)
    base = draw_base(np.random.default_rng(base_ss))
    full = {"charger_kw": 450.0, "charger_terminals": (0, 1)}
    for chargers in ({}, full):
        plan = route_day(np.random.default_rng(plan_ss), case.hours, case.start_clock_h,
                         case.route, climate=case.climate, date=case.date, **chargers)
        effect, day = _draw_effect(hidden, np.random.default_rng(phys_ss), plan)
        if case.bus_seed is not None and hidden is not None:  # a day of a multi-day bus:
            # the effect's values are the bus's (a cell group's loss drawn once per bus)
            bus_effect = _draw_effect(hidden, np.random.default_rng(
                np.random.SeedSequence(case.bus_seed).spawn(4)[2]), plan)[0]
            effect.update({k: v for k, v in bus_effect.items() if k not in truthsim.DAY_LEVEL})
        clean = simulate(plan, base, hidden if case.active else None, effect, **day)
        if clean["soc_frac"].min() >= truthsim.MIN_SOC_FRAC:
            return plan, base, effect, day, clean
    raise RuntimeError(f"{case.case_id}: the bus cannot finish its day "
                       f"(SoC {100 * clean['soc_frac'].min():.1f} %)")


def generate(case: truthsim.Case, current_voltage: bool = False,
             oracle: bool = False) -> tuple[pd.DataFrame, dict]:
    """One case: the degraded 1 Hz log and its truth record (the schema of ``cases.py``);
    ``current_voltage``: the log has the pack's current and voltage too (a BMS log, the rest
    of it unchanged); ``oracle``: the log has ``logged_load_kw`` too, the power the hidden
    effect adds to what the pack gives out (as in ``cases.generate``)."""
    log, truth, _ = generate_with_clean(case, oracle, current_voltage)
    return log, truth


def generate_with_clean(case: truthsim.Case, oracle: bool = False,
                        current_voltage: bool = False) -> tuple[
        pd.DataFrame, dict, pd.DataFrame]:
    """:func:`generate`, plus the clean trace (for checks and figures)."""
    plan, base, effect, day, clean = day_trace(case)
    hidden = case.hidden
    acting = hidden if case.active else None
    log_ss = truthsim._streams(case)[3]
    # the effect's size: the energy it adds against the same day without it
    without = clean if acting is None else simulate(plan, base, None, {}, **day)
    # what the log reveals: altitude on grade days, passenger counts on passenger days
    shown = clean.drop(columns=[c for c, keep in (("altitude_m", hidden == "road_grade"),
                                                  ("passengers", hidden == "passenger_mass"))
                                if not keep])
    shown.attrs.update(clean.attrs, capacity_ah=pack_capacity_ah(base["capacity_kwh"]),
                       chemistry=PACK_CHEMISTRY)
    log = degrade(shown, np.random.default_rng(log_ss), relative_time=case.relative_time,
                  current_voltage=current_voltage)
    if oracle:
        log["logged_load_kw"] = effect_load_kw(
            clean["time_s"].to_numpy(float),
            np.cumsum(clean["energy_out_j"].to_numpy(float) - without["energy_out_j"].to_numpy(float)))
    km = float(clean["distance_m"].iloc[-1]) / 1e3
    out_j = float(clean["energy_out_j"].clip(lower=0.0).sum())
    soc = clean["soc_frac"]
    force = acting == "underinflated_tyres"
    hidden_j = float(clean["p_force_w" if force else "p_hidden_w"].sum())
    shares = None
    if acting is not None and hidden_j > 0.0:
        per = np.bincount(modes(clean), weights=clean["p_force_w" if force else "p_hidden_w"],
                          minlength=len(truthsim.MODES))
        shares = {m: round(float(v / per.sum()), 4)
                  for m, v in zip(truthsim.MODES, per, strict=True)}
    expected = ({**{k: v[0] for k, v in truthsim.EFFECTS.items()}, **{
        k: v[0] for k, v in MULTI_DAY.items()}}[acting] if acting else None)
    outside = expected == "outside_library" and shares
    truth = {
        **dataclasses.asdict(case),
        "source": SOURCE,
        "columns": list(log.columns),
        "expected_verdict": expected,
        "outside_mode": max(shares, key=shares.get) if outside else None,
        "outside_modes": sorted(m for m, v in shares.items() if v >= 0.25) if outside else None,
        "mode_shares": shares,
        "strength": _strength(acting, effect, clean),
        "physical": {k: float(v) for k, v in effect.items()},
        "base": {k: float(v) for k, v in base.items()},
        "date": plan.attrs["date"],
        "charger_kw": plan.attrs["charger_kw"],
        "charger_terminals": plan.attrs["charger_terminals"],
        "ambient_mean_degc": round(float(clean["ambient_degc"].mean()), 2),
        "derated_s": 0,  # FASTSim's pack has no voltage window (module docstring)
        **day,
        "summary": {"km": round(km, 3),
                    "kwh_per_km": round(out_j / 3.6e6 / km, 4),
                    "hidden_kwh": round(hidden_j / 3.6e6, 3),
                    "effect_kwh": round((float(clean["energy_out_j"].sum())
                                         - float(without["energy_out_j"].sum())) / 3.6e6, 3),
                    "charger_kwh": round(float(clean["charger_in_w"].sum()) / 3.6e6, 3),
                    "soc_min_pct": round(100.0 * float(soc.min()), 2),
                    "soc_max_pct": round(100.0 * float(soc.max()), 2),
                    "soc_footprint_pct": truthsim.soc_footprint_pct(clean, without)},
        "fastsim_version": fastsim.__version__,
    }
    return log, truth, clean


def write(case_list: list[truthsim.Case], out_dir: str | Path) -> list[dict]:
    """Write each case's ``<case_id>.csv.gz`` and the truth records in ``truth_fastsim.json``;
    prints each day's figures and FASTSim run time."""
    return truthsim.write(case_list, out_dir, generate, "truth_fastsim.json")


def main(argv: list[str] | None = None) -> None:
    truthsim.cli(sys.modules[__name__], argv, "truth_fastsim.json")


if __name__ == "__main__":
    main()
