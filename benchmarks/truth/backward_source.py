"""A third truth source built another way: a backward-facing bus model in the style of
ADVISOR and VECTO.

    python -m benchmarks.truth.backward_source --out DIR [--n-per-effect 10] [--n-control 30]
        [--buses 5] [--current-voltage]

The other two sources are forward-facing: a driver model asks for a force and the vehicle
answers (the truth simulator's preview driver, FASTSim's own). Here there is no driver. The
speed trace is the plan's, and each second is calculated backwards from it, as ADVISOR
(NREL, 1998-2003: Wipke, Cuddy, Burch, "ADVISOR 2.1: a user-friendly advanced powertrain
simulation using a combined backward/forward approach", IEEE Trans. Veh. Technol. 48(6),
1999) and VECTO (the European Commission's Vehicle Energy Consumption calculation TOol,
Regulation (EU) 2017/2400 and its heavy-bus extension 2019/318) do:

    speed trace -> wheel force -> axle and gearbox losses -> motor efficiency map ->
    inverter -> DC bus (+ auxiliaries, HVAC, hidden loads) -> battery equivalent circuit

1. **Wheel** (VECTO's longitudinal dynamics over one 1 s step, from ``v_0`` to ``v_1``,
   ``a = (v_1 - v_0) / dt``, ``v = (v_0 + v_1) / 2``)::

       F_wheel = m_red a + RRC m g cos(theta) + rho CdA v^2 / 2 + m g sin(theta) + F_hidden
       m_red = m + (J_wheels + J_motor i^2) / r^2

   with a rolling-resistance coefficient ``RRC`` [N/kN] independent of speed (VECTO's form).
2. **Axle** (one reduction, VECTO-style torque loss): ``T_motor = T_wheel / i + T_loss``,
   ``T_loss = T_drag + k_g |T_wheel / i|`` (a drag torque and a share of the torque, against
   the direction of power flow).
3. **Motor** (ADVISOR's efficiency map, here from a loss model evaluated on a speed x torque
   grid and interpolated): ``P_loss = k_c T^2 + k_fe w^1.5 + k_w w^3 + P_0`` (copper, iron,
   windage and a constant), the same map motoring and generating; torque limit ``T_max`` up
   to the base speed, power ``P_max`` above it.
4. **Inverter**: ``P_dc = P_ac + P_sw + k_inv |P_ac|``.
5. **Braking** (ADVISOR's regenerative braking fraction): the motor takes the braking force
   times a fraction that rises from 0 at 1.5 m/s to 1 at 4 m/s, up to a blending deceleration
   of 1.0 m/s^2, its torque and its regenerative power (160 kW); the friction brakes take the
   rest, and take over where the battery cannot accept the charge.
6. **Battery**: a Thevenin circuit with two RC pairs (``R_0``, ``R_1 C_1`` at 10 s, ``R_2
   C_2`` at 200 s; Hu, Li, Peng, "A comparative study of equivalent circuit models for
   Li-ion batteries", J. Power Sources 198 (2012) 359-367), resistances on an Arrhenius law
   ``R(T) = R_25 exp(E_a / R_g (1/T - 1/298.15 K))`` with ``E_a`` = 28 kJ/mol and rising
   at low SoC, and an OCV from two electrodes' potentials, ``OCV = U_+(y) - U_-(x)``:
   NMC811 and graphite-SiOx of the LG M50 cell (Chen et al., J. Electrochem. Soc. 167 (2020)
   080534, with its stoichiometry window), LFP (Afshar, Morris, Khajepour, arXiv 1709.03970,
   2017) against the same graphite (an assumed window: x 0.06-0.80, y 0.98-0.01).
   Voltage window per cell: LFP 2.5-3.65 V (2.0 V at or below 0 degC), NMC 2.8-4.2 V (the
   data sheets of ``vehicles.py``). Traction is cut where the pack would fall below the floor,
   the acceleration found by bisection (ADVISOR's forward correction: the speed falls behind
   the trace and catches up at the vehicle's full load); charge and regeneration are capped
   at the ceiling. Charging: constant current at the charger's power, then constant voltage,
   until the session's stop SoC.
7. **HVAC** (VECTO's bus auxiliaries "steady-state model"): no cabin thermal mass; each
   second the heat the cabin needs to stay at its setpoint,
   ``Q = (UA + c_p m_fresh + rho c_p V_door door) (T_set - T_amb) - A_sol G - q_pax n``,
   comes from a heat pump whose capacity and COP follow the ambient (tables below) and an
   electric heater for the rest, or from an air conditioner whose COP follows the ambient.
8. **Auxiliaries**: a base electric load; where hidden, a pneumatic system in VECTO's terms
   (air consumed per brake application, door cycle and kneeling, and leakage, in normal
   litres; the compressor runs when the consumed air passes its cut-in deficit until it has
   delivered it again), lights on a clock, a pack chiller on a thermostat.

Nothing here imports the other sources' physics: the plan (route, traffic, passengers,
weather) is the shared :func:`benchmarks.truth.days.route_day`, and the case list, the log
degradation and the truth record's layout are the bench's (``cases``, ``degrade``).
"""

from __future__ import annotations

import dataclasses
import math
import sys
from functools import cache

import numpy as np
import pandas as pd

from benchmarks.truth import cases as bench_cases
from benchmarks.truth.days import _SEASONS, route_day

SOURCE = "backward"
GRAVITY_MPS2 = 9.81
AIR_DENSITY_KG_PER_M3 = 1.2
AIR_CP_J_PER_KG_K = 1005.0
GAS_CONSTANT_J_PER_MOL_K = 8.314
DT_S = 1.0

# The nominal bus: curb mass and CdA of VECTO's generic 12 m city bus class (P31/P32 low-floor
# buses, 12.0-12.8 t curb), tyres of EU label class B/C (4.5-7.5 N/kN), a central motor of
# 240 kW / 1200 N m through one reduction of 9.5 on 0.482 m wheels (275/70 R22.5).
NOMINAL = {
    "curb_mass_kg": 12800.0,
    "rrc_n_per_kn": 6.0,
    "cda_m2": 4.6,
    "wheel_radius_m": 0.482,
    "wheels_inertia_kg_m2": 66.0,  # six wheels with tyres, ~11 kg m^2 each
    "motor_inertia_kg_m2": 0.45,
    "axle_ratio": 9.5,
    "axle_drag_nm": 12.0,  # at the motor shaft
    "axle_loss_frac": 0.025,
    "motor_torque_nm": 1200.0,
    "motor_power_w": 240e3,
    "motor_speed_max_rad_s": 470.0,  # 4500 rpm
    "regen_power_w": 160e3,
    "regen_decel_mps2": 1.0,
    "regen_fade_low_mps": 1.5,
    "regen_fade_high_mps": 4.0,
    # motor losses: copper [W/(N m)^2], iron [W/(rad/s)^1.5], windage [W/(rad/s)^3], constant [W]
    "k_copper": 0.0069, "k_iron": 0.5, "k_windage": 1.25e-4, "p_motor0_w": 300.0,
    "inverter_switch_w": 250.0, "inverter_loss_frac": 0.015,
    "aux_base_w": 5000.0,
}

# Packs: cells in series, capacity [Ah], R_0, R_1, R_2 [ohm] at 25 degC and 50 % SoC, the
# voltage window per cell [V], the charge C-rate, the coulombic efficiency on charge.
PACKS = {
    "LFP": {"cells_series": 208, "capacity_ah": 380.0, "r0_ohm": 0.050, "r1_ohm": 0.025,
            "r2_ohm": 0.020, "cell_v_min": 2.5, "cell_v_min_cold": 2.0, "cell_v_max": 3.65,
            "max_charge_c": 2.0, "coulombic_efficiency": 0.999},
    "NMC": {"cells_series": 180, "capacity_ah": 300.0, "r0_ohm": 0.055, "r1_ohm": 0.030,
            "r2_ohm": 0.025, "cell_v_min": 2.8, "cell_v_max": 4.2, "max_charge_c": 1.5,
            "coulombic_efficiency": 0.998},
}
TAU1_S, TAU2_S = 10.0, 200.0
ACTIVATION_J_PER_MOL = 28e3

# Heat pump (R744 bus roof units, thermal capacity and COP over the ambient) and air
# conditioner COP: assumed tables of the shape published for such units (capacity and COP
# fall with the ambient; no heat pump below -10 degC).
HEAT_PUMP_AMBIENT_DEGC = (-10.0, 0.0, 10.0, 20.0)
HEAT_PUMP_CAPACITY_FRAC = (0.55, 0.75, 0.95, 1.0)
HEAT_PUMP_COP = (1.7, 2.2, 2.9, 3.6)
COOLING_AMBIENT_DEGC = (20.0, 25.0, 30.0, 35.0, 40.0)
COOLING_COP = (4.2, 3.6, 3.0, 2.5, 2.1)
PASSENGER_HEAT_W = 75.0  # sensible heat per passenger

HIDDEN = ("road_grade", "cabin_heating", "cabin_cooling", "regen_soc_limit", "cold_battery",
          "passenger_mass", "aux_schedule", "air_compressor", "battery_chiller",
          "dragging_brake", "capacity_step")
MULTI_DAY = {
    "cabin_heating": ("cabin_hvac", "weather"),
    "regen_soc_limit": ("regen_soc_limit", "from_day"),
    "capacity_step": ("static_rcd", "from_day"),
    "battery_chiller": ("outside_library", "constant"),
    "dragging_brake": ("outside_library", "from_day"),
}


# -- cells ---------------------------------------------------------------------------------
def graphite_ocp_v(x: float) -> float:
    """Graphite-SiOx potential [V] at lithiation ``x`` (Chen et al. 2020, LG M50)."""
    return (1.9793 * math.exp(-39.3631 * x) + 0.2482 - 0.0909 * math.tanh(29.8538 * (x - 0.1234))
            - 0.04478 * math.tanh(14.9159 * (x - 0.2769))
            - 0.0205 * math.tanh(30.4444 * (x - 0.6103)))


def nmc811_ocp_v(y: float) -> float:
    """NMC811 potential [V] at lithiation ``y`` (Chen et al. 2020, LG M50)."""
    return (-0.8090 * y + 4.4875 - 0.0428 * math.tanh(18.5138 * (y - 0.5542))
            - 17.7326 * math.tanh(15.7890 * (y - 0.3117))
            + 17.5842 * math.tanh(15.9308 * (y - 0.3120)))


def lfp_ocp_v(y: float) -> float:
    """LiFePO4 potential [V] at lithiation ``y`` (Afshar, Morris, Khajepour 2017)."""
    return 3.4077 - 0.020269 * y + 0.5 * math.exp(-150.0 * y) - 0.9 * math.exp(-30.0 * (1.0 - y))


# stoichiometry windows (x: negative electrode, y: positive) at 0 % and 100 % SoC
WINDOWS = {"NMC": ((0.0279, 0.9014), (0.9084, 0.2661)), "LFP": ((0.06, 0.80), (0.98, 0.01))}


def cell_ocv_v(chemistry: str, soc_frac: float) -> float:
    """Cell OCV [V]: ``U_+(y(SoC)) - U_-(x(SoC))`` over the electrodes' windows."""
    (x0, x1), (y0, y1) = WINDOWS[chemistry]
    z = min(max(soc_frac, 0.0), 1.0)
    positive = nmc811_ocp_v if chemistry == "NMC" else lfp_ocp_v
    return positive(y0 + z * (y1 - y0)) - graphite_ocp_v(x0 + z * (x1 - x0))


@cache
def ocv_table(chemistry: str) -> tuple[np.ndarray, np.ndarray]:
    """The cell OCV on a 1001-point SoC grid, for fast interpolation."""
    soc = np.linspace(0.0, 1.0, 1001)
    return soc, np.array([cell_ocv_v(chemistry, z) for z in soc])


def resistance_factor(temp_degc: float, soc_frac: float) -> float:
    """The cells' resistance over its value at 25 degC and mid SoC: Arrhenius in temperature,
    rising below 20 % SoC (x1.5 at 0 %)."""
    arrhenius = math.exp(ACTIVATION_J_PER_MOL / GAS_CONSTANT_J_PER_MOL_K
                         * (1.0 / (temp_degc + 273.15) - 1.0 / 298.15))
    return arrhenius * (1.0 + 0.5 * math.exp(-max(soc_frac, 0.0) / 0.07))


# -- drivetrain ------------------------------------------------------------------------------
def motor_loss_w(bus: dict, torque_nm: float, speed_rad_s: float) -> float:
    """Motor losses [W] at a torque and shaft speed (motoring or generating)."""
    if speed_rad_s <= 0.0 and torque_nm == 0.0:
        return 0.0
    w = abs(speed_rad_s)
    return bus["motor_loss_scale"] * (bus["k_copper"] * torque_nm * torque_nm
                                      + bus["k_iron"] * w ** 1.5 + bus["k_windage"] * w ** 3
                                      + bus["p_motor0_w"])


def motor_torque_max_nm(bus: dict, speed_rad_s: float) -> float:
    """Full-load torque [N m]: ``T_max`` up to the base speed, ``P_max / w`` above."""
    return min(bus["motor_torque_nm"], bus["motor_power_w"] / max(speed_rad_s, 1e-6))


def dc_power_w(bus: dict, wheel_force_n: float, v_mps: float) -> tuple[float, float, float]:
    """The DC power [W] the drive draws (< 0: returns) for a motor force at the wheel over a
    step of mean speed ``v_mps``, and its axle and motor+inverter losses [W]."""
    if v_mps <= 0.0 or wheel_force_n == 0.0:
        return 0.0, 0.0, 0.0
    r, i = bus["wheel_radius_m"], bus["axle_ratio"]
    w_motor = v_mps / r * i
    t_out = wheel_force_n * r / i  # torque the axle must pass to (or take from) the wheel
    t_loss = bus["axle_drag_nm"] + bus["axle_loss_frac"] * abs(t_out)
    t_motor = t_out + t_loss  # losses against the flow: more motoring, less generating
    p_mech = t_motor * w_motor
    p_ac = p_mech + motor_loss_w(bus, t_motor, w_motor)
    p_dc = p_ac + bus["inverter_switch_w"] + bus["inverter_loss_frac"] * abs(p_ac)
    return p_dc, t_loss * w_motor, p_dc - p_mech


def draw_base(rng: np.random.Generator, chemistry: str) -> dict:
    """One bus's parameters over a fleet's spread: curb mass +-15 %, RRC 4.5-7.5 N/kN, CdA
    +-20 %, axle loss share 1.5-3.5 %, motor losses x0.8-1.3, base auxiliaries 2.5-8.5 kW,
    capacity +-10 %, resistances x0.6-1.6."""
    bus = {**NOMINAL, **PACKS[chemistry], "chemistry": chemistry}
    bus["curb_mass_kg"] *= rng.uniform(0.85, 1.15)
    bus["rrc_n_per_kn"] = rng.uniform(4.5, 7.5)
    bus["cda_m2"] *= rng.uniform(0.8, 1.2)
    bus["axle_loss_frac"] = rng.uniform(0.015, 0.035)
    bus["motor_loss_scale"] = rng.uniform(0.8, 1.3)
    bus["aux_base_w"] = rng.uniform(2500.0, 8500.0)
    bus["capacity_ah"] *= rng.uniform(0.9, 1.1)
    scale = rng.uniform(0.6, 1.6)
    for key in ("r0_ohm", "r1_ohm", "r2_ohm"):
        bus[key] *= scale
    return bus


# -- the hidden effects ----------------------------------------------------------------------
def draw_effect(hidden: str | None, rng: np.random.Generator, plan: pd.DataFrame,
                chemistry: str) -> tuple[dict, dict]:
    """The hidden effect's values and the day options (start SoC, charger stop SoC), with
    this source's own spreads (names shared with ``cases.py`` where the truth record reads
    them)."""
    stop = rng.uniform(0.84, 0.90) if chemistry == "LFP" else rng.uniform(0.80, 0.87)
    day = {"soc0_frac": rng.uniform(0.6, stop), "charge_stop_frac": stop}
    ph: dict[str, float] = {}
    if hidden in ("cabin_heating", "cabin_cooling"):
        heating = hidden == "cabin_heating"
        ph = {"ua_w_per_k": rng.uniform(280.0, 520.0),
              "fresh_air_kg_per_s": rng.uniform(0.25, 0.5),
              "door_air_m3_per_s": rng.uniform(0.3, 0.9),
              "solar_area_m2": rng.uniform(2.5, 5.5),
              "setpoint_degc": rng.uniform(16.0, 20.0) if heating else rng.uniform(22.0, 25.0),
              "heat_pump_w": rng.uniform(8e3, 14e3),
              "cooling_max_w": 24e3, "fans_w": rng.uniform(300.0, 700.0)}
    elif hidden == "regen_soc_limit":
        top = 0.985 if chemistry == "LFP" else 0.97
        day = {"soc0_frac": rng.uniform(top - 0.05, top), "charge_stop_frac": top}
        ph = {"derate_soc_frac": rng.uniform(0.80, 0.92)}
    elif hidden == "cold_battery":
        ph = {"start_offset_k": rng.uniform(0.0, 15.0),
              "pack_heat_capacity_j_per_k": rng.uniform(1.3e6, 2.3e6),
              "pack_ha_w_per_k": rng.uniform(70.0, 220.0)}
        ph["pack_temp0_degc"] = float(plan["ambient_degc"].iloc[0]) + ph["start_offset_k"]
    elif hidden == "passenger_mass":
        ph = {"passenger_mass_kg": rng.uniform(65.0, 85.0)}
    elif hidden == "aux_schedule":
        rise, set_ = _SEASONS[plan.attrs["climate"]]["sun_h"]
        ph = {"lights_w": rng.uniform(800.0, 2000.0),
              "lights_on_h": set_ + rng.uniform(-0.25, 0.25),
              "lights_off_h": rise + rng.uniform(0.0, 0.5)}
    elif hidden == "air_compressor":
        ph = {"compressor_w": rng.uniform(4e3, 8e3), "delivery_nl_per_s": rng.uniform(5.0, 10.0),
              "brake_nl": rng.uniform(4.0, 8.0), "door_nl": rng.uniform(6.0, 12.0),
              "kneel_nl": rng.uniform(10.0, 20.0), "leak_nl_per_s": rng.uniform(0.1, 0.3),
              "cut_in_nl": rng.uniform(60.0, 120.0)}
    elif hidden == "battery_chiller":
        ph = {"chiller_capacity_w": rng.uniform(10e3, 20e3), "chiller_cop": rng.uniform(2.5, 3.5),
              "chiller_on_degc": rng.uniform(26.0, 28.0),
              "pack_heat_capacity_j_per_k": rng.uniform(1.5e6, 2.2e6),
              "pack_ha_w_per_k": rng.uniform(20.0, 40.0)}
    elif hidden == "dragging_brake":
        # a misadjusted brake: a constant drag and a viscous part from the pad's rubbing
        ph = {"drag_n": rng.uniform(150.0, 400.0),
              "drag_n_per_mps": rng.uniform(10.0, 30.0)}
    elif hidden == "capacity_step":
        ph = {"capacity_loss_frac": rng.uniform(0.08, 0.15),
              "resistance_growth_frac": rng.uniform(0.10, 0.30)}
    return {k: float(v) for k, v in ph.items()}, {k: float(v) for k, v in day.items()}


def hvac_power_w(ph: dict, heating: bool, ambient_degc: float, solar_w_per_m2: float,
                 door_open: int, passengers: float) -> tuple[float, float]:
    """The steady-state cabin: electric power [W] of the HVAC and the heat it moves [W]
    (> 0 heats) to hold the setpoint this second."""
    conductance = (ph["ua_w_per_k"] + ph["fresh_air_kg_per_s"] * AIR_CP_J_PER_KG_K
                   + AIR_DENSITY_KG_PER_M3 * AIR_CP_J_PER_KG_K * ph["door_air_m3_per_s"]
                   * door_open)
    need = (conductance * (ph["setpoint_degc"] - ambient_degc)
            - ph["solar_area_m2"] * solar_w_per_m2 - PASSENGER_HEAT_W * passengers)
    if heating and need > 0.0:
        capacity = ph["heat_pump_w"] * float(np.interp(ambient_degc, HEAT_PUMP_AMBIENT_DEGC,
                                                       HEAT_PUMP_CAPACITY_FRAC))
        from_pump = min(need, capacity) if ambient_degc >= HEAT_PUMP_AMBIENT_DEGC[0] else 0.0
        cop = float(np.interp(ambient_degc, HEAT_PUMP_AMBIENT_DEGC, HEAT_PUMP_COP))
        return ph["fans_w"] + from_pump / cop + (need - from_pump), need
    if not heating and need < 0.0:
        moved = max(need, -ph["cooling_max_w"])
        cop = float(np.interp(ambient_degc, COOLING_AMBIENT_DEGC, COOLING_COP))
        return ph["fans_w"] - moved / cop, moved
    return ph["fans_w"], 0.0


# -- the day ---------------------------------------------------------------------------------
def wheel_step(bus: dict, state: dict, acc: float) -> dict:
    """One 1 s step backwards from the speed change: from ``state["v"]`` [m/s] at ``acc``
    [m/s^2], the road-load forces over the step's mean speed, the force the wheel needs, the
    motor's share of it (all of it in traction; in braking the regenerative fraction within
    the motor's and the pack's limits, ``state["regen_room_w"]`` the DC power the pack and the
    loads can take) and the DC power, axle and motor+inverter losses [W]."""
    v0 = state["v"]
    mass = state["mass"]
    v_end = v0 + acc * DT_S
    v_mid = 0.5 * (v0 + v_end)
    moving = v_mid > 0.05
    r_wheel, ratio = bus["wheel_radius_m"], bus["axle_ratio"]
    f_roll = bus["rrc_n_per_kn"] / 1000.0 * mass * GRAVITY_MPS2 * state["cos"] if moving else 0.0
    f_air = 0.5 * AIR_DENSITY_KG_PER_M3 * bus["cda_m2"] * v_mid * v_mid
    f_grade = mass * GRAVITY_MPS2 * state["sin"] if moving else 0.0
    drag = state["drag"]
    f_drag = drag[0] + drag[1] * v_mid if drag is not None and moving else 0.0
    f_wheel = state["m_red"] * acc + f_roll + f_air + f_grade + f_drag
    f_motor = f_wheel
    if f_wheel < 0.0:  # braking: the motor's share, then its and the pack's limits
        fade = min(max((v_mid - bus["regen_fade_low_mps"])
                       / (bus["regen_fade_high_mps"] - bus["regen_fade_low_mps"]), 0.0), 1.0)
        f_motor = max(f_wheel * fade, -mass * bus["regen_decel_mps2"],
                      -motor_torque_max_nm(bus, v_mid / r_wheel * ratio) * ratio / r_wheel,
                      -bus["regen_power_w"] / max(v_mid, 0.1))
    p_dc, p_axle, p_motor = dc_power_w(bus, f_motor, v_mid)
    room = state["regen_room_w"]
    while p_dc < -room and f_motor < -1.0:  # the pack takes what it can; the friction
        # brakes the rest
        f_motor = f_motor * room / -p_dc * 0.999 if room > 0.0 else 0.0
        p_dc, p_axle, p_motor = dc_power_w(bus, f_motor, v_mid)
    return {"v_end": v_end, "v_mid": v_mid, "f_roll": f_roll, "f_air": f_air,
            "f_grade": f_grade, "f_drag": f_drag, "f_wheel": f_wheel, "f_motor": f_motor,
            "p_dc": p_dc, "p_axle": p_axle, "p_motor": p_motor}


def simulate(plan: pd.DataFrame, bus: dict, effect: str | None = None,
             physical: dict | None = None, *, soc0_frac: float = 0.8,
             charge_stop_frac: float = 0.9) -> pd.DataFrame:
    """The backward-facing run of a plan (1 s steps); returns the clean 1 Hz trace.

    Columns: ``time_s, clock_h, speed_mps, accel_mps2, soc_frac, battery_current_a,
    battery_voltage_v, ocv_v``, powers ``p_battery_w, p_wheel_w`` (the force the wheel needs
    times the step's mean speed), ``p_drive_dc_w, p_aux_w, p_hidden_w, p_force_w,
    p_charger_w``, cumulative energies ``e_*_j`` (wheel, road, grade, force, kinetic,
    friction, axle and motor+inverter losses, DC drive, auxiliaries, hidden, charger,
    battery, OCV and battery losses), ``pack_temp_degc, cabin_temp_degc, cv_phase,
    derated`` (the pack's floor cut traction), ``trace_miss_mps`` (plan speed less driven),
    ``p_discharge_max_w, p_charge_max_w`` and the plan's ``grade_frac, altitude_m,
    passengers, door_open, ambient_degc, plugged, charging, charger_kw, distance_m``.
    """
    if effect is not None and effect not in HIDDEN:
        raise ValueError(f"unknown hidden effect {effect!r}; known: {HIDDEN}")
    ph = dict(physical or {})
    n = len(plan)
    v_plan = plan["speed_target_mps"].to_numpy(float)
    grade = plan["grade_frac"].to_numpy(float) if effect == "road_grade" else np.zeros(n)
    pax = plan["passengers"].to_numpy(float)
    pax_mass = pax * ph["passenger_mass_kg"] if effect == "passenger_mass" else np.zeros(n)
    door = plan["door_open"].to_numpy(int)
    plugged = plan["charging"].to_numpy(int)
    charger_w = 1000.0 * plan["charger_kw"].to_numpy(float)
    ambient = plan["ambient_degc"].to_numpy(float)
    solar = plan["solar_w_per_m2"].to_numpy(float)
    clock = plan["clock_h"].to_numpy(float)

    chem = bus["chemistry"]
    soc_x, ocv_y = ocv_table(chem)
    cells = bus["cells_series"]
    q_ah = bus["capacity_ah"]
    r_scale = 1.0
    if effect == "capacity_step":
        q_ah *= 1.0 - ph["capacity_loss_frac"]
        r_scale = 1.0 + ph["resistance_growth_frac"]
    v_max = cells * bus["cell_v_max"]
    decay1, decay2 = math.exp(-DT_S / TAU1_S), math.exp(-DT_S / TAU2_S)
    r_wheel, ratio = bus["wheel_radius_m"], bus["axle_ratio"]
    j_red = (bus["wheels_inertia_kg_m2"] + bus["motor_inertia_kg_m2"] * ratio ** 2) / r_wheel ** 2
    rrc = bus["rrc_n_per_kn"] / 1000.0
    thermal = effect in ("cold_battery", "battery_chiller")
    pack_temp = ph["pack_temp0_degc"] if effect == "cold_battery" else 25.0
    chiller_on = False
    air_deficit_nl = 0.0
    compressor_on = False
    door_before = braking_before = False
    hvac = effect in ("cabin_heating", "cabin_cooling")

    names = ("speed_mps", "accel_mps2", "soc_frac", "battery_current_a", "battery_voltage_v",
             "ocv_v", "p_battery_w", "p_wheel_w", "p_drive_dc_w", "p_aux_w", "p_hidden_w",
             "p_force_w", "p_charger_w", "pack_temp_degc", "cabin_temp_degc", "cv_phase",
             "derated", "trace_miss_mps", "p_discharge_max_w", "p_charge_max_w", "distance_m",
             "altitude_m")
    rec = {k: np.zeros(n) for k in names}
    energy_names = ("wheel", "road", "grade", "force", "kinetic", "friction", "axle_loss",
                    "motor_loss", "drive_dc", "aux", "hidden", "charger", "battery", "ocv",
                    "battery_loss")
    e = dict.fromkeys(energy_names, 0.0)
    erec = {k: np.zeros(n) for k in energy_names}

    soc, v1_v, v2_v = soc0_frac, 0.0, 0.0
    v = 0.0
    dist = 0.0
    altitude = float(plan["altitude_m"].iloc[0])
    charging_done = False
    for k in range(n):
        mass = bus["curb_mass_kg"] + pax_mass[k]
        m_red = mass + j_red
        cos_t = 1.0 / math.sqrt(1.0 + grade[k] ** 2)
        sin_t = grade[k] * cos_t
        r_factor = resistance_factor(pack_temp, soc) * r_scale
        r0 = bus["r0_ohm"] * r_factor
        ocv = cells * float(np.interp(soc, soc_x, ocv_y))
        emf = ocv - v1_v - v2_v
        v_min = cells * (bus.get("cell_v_min_cold", bus["cell_v_min"]) if pack_temp <= 0.0
                         else bus["cell_v_min"])
        p_dis_max = max(v_min * (emf - v_min) / r0, 0.0)
        i_charge_max = min(bus["max_charge_c"] * q_ah, max((v_max - emf) / r0, 0.0))
        p_charge_max = i_charge_max * (emf + r0 * i_charge_max)
        p_regen_max = p_charge_max
        if effect == "regen_soc_limit":  # the BMS's regen allowance (the motor's regen power
            # at SoC_d) falls linearly to 0 at a full pack
            p_regen_max = min(p_charge_max, bus["regen_power_w"] * min(max(
                (1.0 - soc) / (1.0 - ph["derate_soc_frac"]), 0.0), 1.0))

        # -- loads on the DC bus -----------------------------------------------------------
        p_aux = bus["aux_base_w"]
        p_hidden = 0.0
        cabin = float("nan")
        if hvac:
            p_hvac, _ = hvac_power_w(ph, effect == "cabin_heating", ambient[k], solar[k],
                                     door[k], pax[k])
            p_hidden += p_hvac
            cabin = ph["setpoint_degc"]
        elif effect == "aux_schedule":
            hour = clock[k] % 24.0
            if hour < ph["lights_off_h"] or hour >= ph["lights_on_h"]:
                p_hidden += ph["lights_w"]
        if effect == "air_compressor":
            if door[k] and not door_before:
                air_deficit_nl += ph["door_nl"] + ph["kneel_nl"]
            door_before = bool(door[k])
            air_deficit_nl += ph["leak_nl_per_s"] * DT_S
            if air_deficit_nl >= ph["cut_in_nl"]:
                compressor_on = True
            if compressor_on:
                air_deficit_nl -= ph["delivery_nl_per_s"] * DT_S
                p_hidden += ph["compressor_w"]
                if air_deficit_nl <= 0.0:
                    air_deficit_nl, compressor_on = 0.0, False
        if effect == "battery_chiller":
            if pack_temp >= ph["chiller_on_degc"]:
                chiller_on = True
            elif pack_temp <= ph["chiller_on_degc"] - 3.0:
                chiller_on = False
            if chiller_on:
                p_hidden += ph["chiller_capacity_w"] / ph["chiller_cop"]

        # -- the step's speed: the trace, where the vehicle can follow it --------------------
        target = v_plan[min(k + 1, n - 1)]
        stopped = target <= 0.0 and v <= 0.05
        f_res0 = (rrc * mass * GRAVITY_MPS2 * cos_t if v > 0.05 else 0.0) \
            + 0.5 * AIR_DENSITY_KG_PER_M3 * bus["cda_m2"] * v * v + mass * GRAVITY_MPS2 * sin_t
        w_motor = v / r_wheel * ratio
        f_full = motor_torque_max_nm(bus, max(w_motor, 1.0)) * ratio / r_wheel \
            * (1.0 - bus["axle_loss_frac"])
        a_max = (f_full - f_res0) / m_red
        a = 0.0 if stopped else min((target - v) / DT_S, a_max)
        if v + a * DT_S < 0.0:
            a = -v / DT_S

        state = {"v": v, "mass": mass, "m_red": m_red, "cos": cos_t, "sin": sin_t,
                 "drag": (ph["drag_n"], ph["drag_n_per_mps"]) if effect == "dragging_brake"
                 else None, "regen_room_w": p_regen_max + p_aux + p_hidden}
        s = wheel_step(bus, state, a)
        derated = 0.0
        if s["p_dc"] + p_aux + p_hidden > p_dis_max and s["f_wheel"] > 0.0:
            # the pack's floor: the acceleration that uses what it can give (bisection)
            low, high = min(-f_res0 / m_red, a), a
            for _ in range(30):
                mid = 0.5 * (low + high)
                if wheel_step(bus, state, mid)["p_dc"] + p_aux + p_hidden > p_dis_max:
                    high = mid
                else:
                    low = mid
            a = low
            s = wheel_step(bus, state, a)
            derated = 1.0

        braking = s["f_wheel"] - s["f_motor"] < -1.0  # the friction brakes apply
        if effect == "air_compressor" and braking and not braking_before:
            air_deficit_nl += ph["brake_nl"]  # the brake chambers fill from the reservoir
        braking_before = braking

        # -- charger and battery -----------------------------------------------------------
        p_ch = 0.0
        cv = 0.0
        if plugged[k] and not charging_done:
            if soc >= charge_stop_frac:
                charging_done = True
            else:
                p_ch = max(min(charger_w[k], p_charge_max + p_aux + p_hidden + s["p_dc"]), 0.0)
                cv = float(p_ch < charger_w[k] and (v_max - emf) / r0 < bus["max_charge_c"]
                           * q_ah)
        if not plugged[k]:
            charging_done = False
        p_batt = s["p_dc"] + p_aux + p_hidden - p_ch
        disc = emf * emf - 4.0 * r0 * p_batt
        current = (emf - math.sqrt(disc)) / (2.0 * r0) if disc > 0.0 else emf / (2.0 * r0)
        v_term = emf - r0 * current
        loss = r0 * current * current + (v1_v + v2_v) * current

        # -- record this second, then step the states -------------------------------------
        v_mid = s["v_mid"]
        f_fric = s["f_wheel"] - s["f_motor"]
        kinetic1 = 0.5 * m_red * s["v_end"] ** 2
        e["wheel"] += s["f_wheel"] * v_mid * DT_S
        e["road"] += (s["f_roll"] + s["f_air"]) * v_mid * DT_S
        e["grade"] += s["f_grade"] * v_mid * DT_S
        e["force"] += s["f_drag"] * v_mid * DT_S
        e["kinetic"] = kinetic1  # the bus starts standing
        e["friction"] += -f_fric * v_mid * DT_S
        e["axle_loss"] += s["p_axle"] * DT_S
        e["motor_loss"] += s["p_motor"] * DT_S
        e["drive_dc"] += s["p_dc"] * DT_S
        e["aux"] += p_aux * DT_S
        e["hidden"] += p_hidden * DT_S
        e["charger"] += p_ch * DT_S
        e["battery"] += p_batt * DT_S
        e["ocv"] += ocv * current * DT_S
        e["battery_loss"] += loss * DT_S
        for key in energy_names:
            erec[key][k] = e[key]
        vals = {"speed_mps": v, "accel_mps2": a, "soc_frac": soc, "battery_current_a": current,
                "battery_voltage_v": v_term, "ocv_v": ocv, "p_battery_w": p_batt,
                "p_wheel_w": s["f_wheel"] * v_mid, "p_drive_dc_w": s["p_dc"], "p_aux_w": p_aux,
                "p_hidden_w": p_hidden, "p_force_w": s["f_drag"] * v_mid, "p_charger_w": p_ch,
                "pack_temp_degc": pack_temp, "cabin_temp_degc": cabin, "cv_phase": cv,
                "derated": derated, "trace_miss_mps": v_plan[k] - v,
                "p_discharge_max_w": p_dis_max, "p_charge_max_w": p_charge_max}
        for key, val in vals.items():
            rec[key][k] = val
        r1 = bus["r1_ohm"] * r_factor
        r2 = bus["r2_ohm"] * r_factor
        v1_v = v1_v * decay1 + r1 * (1.0 - decay1) * current
        v2_v = v2_v * decay2 + r2 * (1.0 - decay2) * current
        soc -= current * DT_S / (3600.0 * q_ah) * (1.0 if current > 0.0
                                                    else bus["coulombic_efficiency"])
        if thermal:
            cool = ph["chiller_capacity_w"] if effect == "battery_chiller" and chiller_on \
                else 0.0
            pack_temp += (loss - ph["pack_ha_w_per_k"] * (pack_temp - ambient[k]) - cool) \
                * DT_S / ph["pack_heat_capacity_j_per_k"]
        dist += v_mid * DT_S
        altitude += v_mid * sin_t * DT_S
        rec["distance_m"][k], rec["altitude_m"][k] = dist, altitude  # at the step's end, as
        # the cumulative energies
        v = s["v_end"]
    trace = pd.DataFrame({"time_s": plan["time_s"].to_numpy(float), "clock_h": clock, **rec})
    for key in energy_names:
        trace[f"e_{key}_j"] = erec[key]
    trace["grade_frac"] = grade
    trace["passengers"] = (pax if effect == "passenger_mass" else np.zeros(n)).astype(int)
    trace["door_open"] = door
    trace["ambient_degc"] = ambient
    trace["plugged"] = plugged
    trace["charging"] = ((plugged == 1) & (trace["p_charger_w"] > 0.0)).astype(int)
    trace["charger_kw"] = np.where(trace["charging"] == 1, charger_w / 1000.0, 0.0)
    trace.attrs.update(plan.attrs)
    return trace


# -- the cases ------------------------------------------------------------------------------
def cases(n_per_effect: int = 10, n_control: int = 30,
          seed: int = bench_cases.DEFAULT_SEED) -> list[bench_cases.Case]:
    """This source's single days: the truth simulator's case list (same seeds, so the same
    route days and weather), every hidden effect of it."""
    return [dataclasses.replace(c, case_id=f"backward_{c.case_id}")
            for c in bench_cases.cases(n_per_effect, n_control, seed)]


def buses(n_per_condition: int = 5, n_control: int = 4,
          seed: int = bench_cases.DEFAULT_SEED) -> list[bench_cases.Bus]:
    """The multi-day buses of this source's conditions (:data:`MULTI_DAY`)."""
    return [dataclasses.replace(b, bus_id=f"backward_{b.bus_id}")
            for b in bench_cases.buses(n_per_condition, n_control, seed + 7, MULTI_DAY)]


def bus_days(bus: bench_cases.Bus) -> list[bench_cases.Case]:
    """The service days of a bus (:func:`benchmarks.truth.cases.bus_days`)."""
    return bench_cases.bus_days(bus)


def bus_truth(bus: bench_cases.Bus, records: list[dict]) -> dict:
    """The truth record of a multi-day bus (:func:`benchmarks.truth.cases.bus_truth`)."""
    return bench_cases.bus_truth(bus, records, SOURCE, MULTI_DAY)


MIN_SOC_FRAC = 0.10


def day_trace(case: bench_cases.Case) -> tuple[pd.DataFrame, dict, dict, dict, pd.DataFrame]:
    """The plan, bus, hidden effect's values, day options and clean trace of a case (the
    day re-run with 450 kW chargers at both terminals where the drawn ones leave the pack
    below ``MIN_SOC_FRAC``, as an operator would plan it)."""
    plan_ss, base_ss, phys_ss, _ = bench_cases._streams(case)
    bus = draw_base(np.random.default_rng(base_ss), case.chemistry)
    full = {"charger_kw": 450.0, "charger_terminals": (0, 1)}
    for chargers in ((full,) if case.hidden == "regen_soc_limit" else ({}, full)):
        plan = route_day(np.random.default_rng(plan_ss), case.hours, case.start_clock_h,
                         case.route, climate=case.climate, date=case.date, **chargers)
        ph, day = draw_effect(case.hidden, np.random.default_rng(phys_ss), plan, case.chemistry)
        if case.bus_seed is not None and case.hidden is not None:  # the bus's own values
            first = draw_effect(case.hidden, np.random.default_rng(
                np.random.SeedSequence(case.bus_seed).spawn(4)[2]), plan, case.chemistry)[0]
            ph.update({k: v for k, v in first.items() if k not in bench_cases.DAY_LEVEL})
        trace = simulate(plan, bus, case.hidden if case.active else None, ph, **day)
        if trace["soc_frac"].min() >= MIN_SOC_FRAC:
            return plan, bus, ph, day, trace
    raise RuntimeError(f"{case.case_id}: the bus cannot finish its day "
                       f"(SoC {100 * trace['soc_frac'].min():.1f} %)")


def generate(case: bench_cases.Case, current_voltage: bool = False,
             oracle: bool = False) -> tuple[pd.DataFrame, dict]:
    """The degraded log and the truth record of a case (the layout of ``cases.generate``):
    ``current_voltage`` keeps the pack's current and voltage in the log (a BMS log, the rest
    unchanged), ``oracle`` adds ``logged_load_kw``, the hidden effect's own power."""
    plan, bus, ph, day, trace = day_trace(case)
    acting = case.hidden if case.active else None
    without = trace if acting is None else simulate(plan, bus, None, {}, **day)
    log = bench_cases.day_log(case, trace, without, bus, current_voltage, oracle)
    truth = bench_cases.record(case, plan, bus, ph, day, trace, without, list(log.columns),
                               SOURCE)
    truth["derated_s"] = int(trace["derated"].sum())
    truth["trace_miss_max_mps"] = round(float(trace["trace_miss_mps"].max()), 3)
    return log, truth


def main(argv: list[str] | None = None) -> None:
    bench_cases.cli(sys.modules[__name__], argv, "truth_backward.json")


if __name__ == "__main__":
    main()
