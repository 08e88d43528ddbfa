"""The truth simulator: driving plan + base bus + one hidden effect -> clean truth trace.

Forward-facing and explicit, at ``dt_s`` = 0.5 s (output at 1 Hz). Per step:

Driver (preview tracking): it aims to reach the plan's speed ``T_p`` seconds ahead,
``a_dem = clip((v_plan(t + T_p) - v) / T_p, -2.0, 1.6) m/s^2``.

Vehicle: ``m_eff a = F_motor + F_friction - F_road - F_grade`` with the coast-down road load
``F_road = A cos(theta) + B v cos(theta) + C v^2`` (``vehicles``), ``F_grade = m g sin(theta)``
and ``m_eff = m + m_rot``. The motor gives ``F = min(F_need, F_max, P_max / v)`` in traction;
braking goes to the motor up to its power ``P_regen`` (faded linearly to zero between 3 and
1 m/s), the blending limit ``m a_regen`` and the battery's charge-current limit; the friction
brakes take the rest.

Drivetrain: fixed efficiency, ``P_dc = P_wheel / eta`` in traction, ``P_dc = eta P_wheel`` in
regeneration.

DC bus: ``P_batt = P_dc + P_aux + P_hidden - P_charger`` (> 0 discharges). On a charger the
BMS asks for ``I = min(C_max Q, (V_max - OCV + V_1) / R_0)`` (constant current, then constant
voltage) until the SoC reaches the charger's stop SoC; the charger gives at most its rated
power and also feeds the bus's loads.

Battery (one RC pair; Plett, Battery Management Systems Vol. I, 2015, Sec. 2.7)::

    V_t = OCV(SoC) - V_1 - R_0 I,      I = (E - sqrt(E^2 - 4 R_0 P_batt)) / (2 R_0), E = OCV - V_1
    V_1(t+dt) = V_1 e^{-dt/tau_1} + R_1 (1 - e^{-dt/tau_1}) I
    SoC(t+dt) = SoC - I dt / (3600 Q) * (1 if I > 0 else eta_coulomb)

Voltage window (the BMS's): the cells' terminal voltage is kept within
``[V_min(T), V_max]`` per cell (``vehicles.PACKS``: LFP 2.5-3.65 V, 2.0 V at or below 0 degC;
NMC 2.8-4.2 V). On discharge the BMS announces the most power the pack can give at the floor,
``P_dis,max = V_min (E - V_min) / R_0`` (the power at which ``V_t`` = ``V_min``), and the
vehicle controller derates traction to what is left after the loads: the motor force is cut so
that ``P_wheel / eta <= P_dis,max - P_aux - P_hidden``, the bus accelerates less and falls
behind its plan (``derated`` = 1 in the trace). On charge and regeneration the current is
capped at ``(V_max - E) / R_0`` in magnitude, so ``V_t <= V_max`` (the constant-voltage phase
of a charge, and the regen limit of a full pack). ``p_discharge_max_w`` and
``p_charge_max_w`` in the trace are the two limits, second by second.

Resistances scale with pack temperature as ``R(T) = R(25 degC) exp(k (25 - T))`` with
``k`` = 0.035 /K (x2.4 at 0 degC, x5.8 at -25 degC), inside the 2-3x rise at 0 degC reported
for Li-ion cells (Jaguemont, Boulon, Dube, Appl. Energy 164 (2016) 99-114, Sec. 3). A managed
pack stays at 25 degC; an unmanaged one is a lumped mass,
``C_p dT/dt = R_0 I^2 + V_1 I - hA (T - T_amb)``.

Cell OCV tables (cell level, pseudo-OCV at low C-rate, room temperature): the optimised
10-breakpoint look-up tables of Sunil, Pattipati, Balasingam, "Piecewise Linear Approximation
of Battery Open-Circuit Voltage Characteristics Using Dynamic Programming", IEEE Trans.
Instrum. Meas. 2025, as published in the README of github.com/soorajsunil/Piecewise-Battery-OCV
(commit 0002eb5): Lithium Werks APR-18650M1B (LFP, C/32) and Samsung INR-21700-40T (NMC,
C/20).

Hidden effects (``effect`` and its ``physical`` values) are documented in ``HIDDEN``; each
adds one load or changes one behaviour that the base bus lacks.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from benchmarks.truth.vehicles import AIR_DENSITY_KG_PER_M3, GRAVITY_MPS2

OCV_TABLES = {
    "LFP": ((0.0, 0.0033, 0.0117, 0.0267, 0.0534, 0.0885, 0.2972, 0.9833, 0.9950, 1.0),
            (2.0102, 2.4177, 2.7405, 2.9299, 3.0872, 3.1942, 3.2772, 3.3511, 3.4180, 3.5981)),
    "NMC": ((0.0, 0.0050, 0.0352, 0.0854, 0.1357, 0.2915, 0.4523, 0.8392, 0.9548, 1.0),
            (2.5000, 2.8080, 3.1179, 3.3182, 3.4193, 3.5826, 3.6941, 4.0664, 4.1121, 4.2000)),
}
RESISTANCE_PER_K = 0.035
AIR_CP_J_PER_KG_K = 1005.0
DT_S = 0.5

HIDDEN = {
    "road_grade": "the route's grade acts on the bus (the base days are flat)",
    "cabin_heating": "heat-pump + resistive heating of a lumped cabin on a cold day",
    "cabin_cooling": "vapour-compression cooling of a lumped cabin on a hot day",
    "regen_soc_limit": "the BMS derates the regenerative charge current above an SoC",
    "cold_battery": "a pack without thermal management on a cold day (resistance rises)",
    "passenger_mass": "the passengers' mass",
    "aux_schedule": "lights and demisting after dusk and before dawn",
    "air_compressor": "an electric brake-air compressor, run by its pressure governor",
    "battery_chiller": "a pack chiller that runs while the pack is fast-charged",
    "dragging_brake": "a sticking brake caliper: after each friction-brake application the "
                      "pads keep dragging, the drag fading with the distance driven",
    "capacity_step": "a weak cell group: the pack's capacity drops and its resistance rises",
}
FORCES = frozenset({"dragging_brake"})
"""Hidden effects that act as a force at the wheel (not a load on the DC bus): their power is
``p_force_w``, the drag times the speed, and their energy ``e_force_j``."""


def cell_v_min(pack: dict, temp_degc: float) -> float:
    """The BMS's discharge floor per cell [V] at the pack's temperature: the data sheet's
    cold floor at or below 0 degC where it gives one (LFP), else its floor."""
    return pack.get("cell_v_min_cold", pack["cell_v_min"]) if temp_degc <= 0.0 \
        else pack["cell_v_min"]


def traction_force_at_power(power_w: float, v: float, resist_n: float, m_eff: float,
                            dt: float) -> float:
    """The motor force [N] whose wheel power over the step, ``F v_mid`` with the step's mean
    speed ``v_mid = v + dt (F - F_resist) / (2 m_eff)``, is ``power_w`` [W] (>= 0): the
    positive root of ``k F^2 + (v - k F_resist) F - P = 0``, ``k = dt / (2 m_eff)``."""
    if power_w <= 0.0:
        return 0.0
    k = 0.5 * dt / m_eff
    b = v - k * resist_n
    return (-b + math.sqrt(b * b + 4.0 * k * power_w)) / (2.0 * k)


def ocv_cell_v(chemistry: str, soc_frac: float) -> float:
    """Cell open-circuit voltage [V] at ``soc_frac`` (linear between the table's points)."""
    x, y = OCV_TABLES[chemistry]
    return float(np.interp(soc_frac, x, y))


def heat_pump_cop(ambient_degc: float, heating: bool) -> float:
    """COP as a fixed fraction (0.4) of the Carnot COP between the evaporating and condensing
    temperatures: heating condenses at 45 degC and evaporates 10 K below ambient, cooling
    evaporates at 5 degC and condenses 15 K above ambient (second-law efficiencies of
    vapour-compression units are 0.3-0.5; ASHRAE Handbook - Fundamentals, 2017, Ch. 2)."""
    if heating:
        hot_k, cold_k = 318.15, ambient_degc + 263.15
        return max(1.0, 0.4 * hot_k / max(hot_k - cold_k, 5.0))
    cold_k, hot_k = 278.15, ambient_degc + 288.15
    return max(1.0, 0.4 * cold_k / max(hot_k - cold_k, 5.0))


def simulate(plan: pd.DataFrame, base: dict, effect: str | None = None,
             physical: dict | None = None, *, soc0_frac: float = 0.8,
             charge_stop_frac: float = 0.9) -> pd.DataFrame:
    """Run the bus through the plan; returns the clean trace at 1 Hz.

    Parameters
    ----------
    plan : the driving plan (``days.route_day``).
    base : base parameters (``vehicles.draw_base``).
    effect : one of ``HIDDEN`` or None (nothing hidden).
    physical : the hidden effect's values (see ``cases``).
    soc0_frac : true SoC at the start [-].
    charge_stop_frac : SoC at which the charger ends a session [-].

    Returns
    -------
    DataFrame: ``time_s, clock_h, speed_mps, soc_frac, battery_current_a, battery_voltage_v,
    ocv_v``, powers ``p_battery_w, p_wheel_w, p_drive_dc_w, p_aux_w, p_hidden_w,
    p_charger_w``, cumulative energies ``e_*_j``, ``cabin_temp_degc, pack_temp_degc,
    air_pressure_bar``, ``cv_phase`` (1 while the cells' voltage limit sets the charge
    current), the inputs as the bus met them (``grade_frac, altitude_m,
    passengers, door_open, ambient_degc``), ``plugged`` (under a charger), ``charging`` and
    ``charger_kw`` (while a session runs: it ends at the stop SoC) and ``distance_m``.
    """
    if effect is not None and effect not in HIDDEN:
        raise ValueError(f"unknown hidden effect {effect!r}; known: {sorted(HIDDEN)}")
    ph = dict(physical or {})
    b = base
    n_plan = len(plan)
    dt = DT_S
    n = int((n_plan - 1) / dt) + 1
    t = np.arange(n) * dt
    t_plan = plan["time_s"].to_numpy(float)
    held = np.minimum(np.searchsorted(t_plan, t, side="right") - 1, n_plan - 1)

    def lin(col: str, shift: float = 0.0) -> np.ndarray:
        return np.interp(t + shift, t_plan, plan[col].to_numpy(float))

    preview = b.get("driver_preview_s", 2.0)
    v_ahead = lin("speed_target_mps", preview)
    v_now = lin("speed_target_mps")
    grade = lin("grade_frac") if effect == "road_grade" else np.zeros(n)
    pax = (plan["passengers"].to_numpy(float)[held] if effect == "passenger_mass"
           else np.zeros(n))
    door = plan["door_open"].to_numpy(int)[held]
    plugged = plan["charging"].to_numpy(int)[held]
    charger_w = 1000.0 * plan["charger_kw"].to_numpy(float)[held]
    ambient = lin("ambient_degc")
    solar = lin("solar_w_per_m2")
    clock = lin("clock_h")

    chem = b["chemistry"]
    ocv_x, ocv_y = (np.array(a) for a in OCV_TABLES[chem])
    cells = b["cells_series"]
    q_ah = b["capacity_ah"]
    r0_25, r1_25 = b["r0_ohm"], b["r1_ohm"]
    if effect == "capacity_step":  # a weak cell group limits the string
        q_ah *= 1.0 - ph["capacity_loss_frac"]
        r0_25 *= 1.0 + ph["resistance_growth_frac"]
        r1_25 *= 1.0 + ph["resistance_growth_frac"]
    v_max = cells * b["cell_v_max"]
    i_charge_max = b["max_charge_c"] * q_ah
    decay1 = math.exp(-dt / b["tau1_s"])
    eta = b["drive_efficiency"]
    m_rot = b["rotating_mass_kg"]
    pax_kg = ph.get("passenger_mass_kg", 0.0)

    # hidden-effect switches and states
    managed = effect != "cold_battery"
    pack_temp = 25.0 if managed else ph["pack_temp0_degc"]
    hvac = effect in ("cabin_heating", "cabin_cooling")
    cabin = ph.get("setpoint_degc", 20.0)
    hvac_integral = 0.0
    if hvac:  # preconditioned at the depot: the controller starts at its steady state
        cond0 = ph["ua_w_per_k"] + ph["fresh_air_kg_per_s"] * AIR_CP_J_PER_KG_K
        hvac_integral = cond0 * (cabin - ambient[0]) - ph["solar_area_m2"] * solar[0] - 100.0
    pressure = ph.get("cut_out_bar", 12.0)
    drag_n = 0.0  # a sticking caliper's residual drag
    compressor_on = False
    braking_before = False
    door_before = False

    out_every = int(round(1.0 / dt))
    n_out = (n - 1) // out_every + 1
    names = ("speed_mps", "soc_frac", "battery_current_a", "battery_voltage_v", "ocv_v",
             "p_battery_w", "p_wheel_w", "p_drive_dc_w", "p_aux_w", "p_hidden_w",
             "p_charger_w", "e_battery_j", "e_ocv_j", "e_battery_loss_j", "e_wheel_j",
             "e_road_j", "e_grade_j", "e_friction_j", "e_kinetic_j", "e_drive_dc_j",
             "e_aux_j", "e_hidden_j", "e_charger_j", "cabin_temp_degc", "pack_temp_degc",
             "air_pressure_bar", "altitude_m", "distance_m", "accel_mps2", "cv_phase",
             "p_force_w", "e_force_j", "derated", "p_discharge_max_w", "p_charge_max_w")
    rec = {k: np.empty(n_out) for k in names}
    e = dict.fromkeys(("battery", "ocv", "battery_loss", "wheel", "road", "grade", "friction",
                       "drive_dc", "aux", "hidden", "charger", "force"), 0.0)

    v = 0.0
    soc = soc0_frac
    v1 = 0.0
    altitude = float(plan["altitude_m"].iloc[0])
    dist = 0.0
    i_batt = 0.0
    charging_done = False
    for k in range(n):
        cos_t = 1.0 / math.sqrt(1.0 + grade[k] ** 2)
        sin_t = grade[k] * cos_t
        mass = b["curb_mass_kg"] + pax[k] * pax_kg
        m_eff = mass + m_rot
        ocv = cells * float(np.interp(soc, ocv_x, ocv_y))
        r_factor = math.exp(RESISTANCE_PER_K * (25.0 - pack_temp))
        r0 = r0_25 * r_factor
        r1 = r1_25 * r_factor
        v_min = cells * cell_v_min(b, pack_temp)
        emf_now = ocv - v1
        # the BMS's discharge limit: the power at which the terminal voltage reaches V_min
        p_dis_max = max(v_min * (emf_now - v_min) / r0, 0.0)

        # -- loads that do not depend on the wheel ------------------------------------
        p_hidden = 0.0
        if hvac:
            conductance = (ph["ua_w_per_k"] + ph["fresh_air_kg_per_s"] * AIR_CP_J_PER_KG_K
                           + AIR_DENSITY_KG_PER_M3 * AIR_CP_J_PER_KG_K * ph["door_air_m3_per_s"]
                           * door[k])
            q_passive = (conductance * (ambient[k] - cabin) + ph["solar_area_m2"] * solar[k]
                         + 100.0 * (1.0 + pax[k]))
            err = ph["setpoint_degc"] - cabin
            hvac_integral += ph["ki_w_per_k_s"] * err * dt
            q_hvac = ph["kp_w_per_k"] * err + hvac_integral
            q_max = ph["heating_max_w"] if effect == "cabin_heating" else 0.0
            q_min = -ph["cooling_max_w"] if effect == "cabin_cooling" else 0.0
            if q_hvac > q_max or q_hvac < q_min:  # anti-windup: hold the integral
                hvac_integral -= ph["ki_w_per_k_s"] * err * dt
                q_hvac = min(max(q_hvac, q_min), q_max)
            if q_hvac > 0.0:
                q_hp = min(q_hvac, ph["heat_pump_max_w"]) if ambient[k] > -15.0 else 0.0
                p_hidden += q_hp / heat_pump_cop(ambient[k], True) + (q_hvac - q_hp)
            elif q_hvac < 0.0:
                p_hidden += -q_hvac / heat_pump_cop(ambient[k], False)
            p_hidden += ph["blower_w"]
            cabin += (q_passive + q_hvac) * dt / ph["heat_capacity_j_per_k"]
        elif effect == "aux_schedule":
            hour = clock[k] % 24.0
            if hour < ph["lights_off_h"] or hour >= ph["lights_on_h"]:
                p_hidden += ph["lights_w"]
        elif effect == "battery_chiller" and plugged[k] and i_batt < 0.0:
            p_hidden += ph["chiller_w"]
        if effect == "air_compressor":
            if door[k] and not door_before:  # doors and kneeling at a stop
                pressure -= ph["door_bar"]
            door_before = bool(door[k])
            pressure -= ph["leak_bar_per_s"] * dt
            if pressure < ph["cut_in_bar"]:
                compressor_on = True
            if compressor_on:
                pressure += ph["fill_bar_per_s"] * dt
                p_hidden += ph["compressor_w"]
                if pressure >= ph["cut_out_bar"]:
                    compressor_on = False
        p_aux = b["aux_base_w"]

        # -- what the battery accepts ------------------------------------------------------
        i_cv = max((v_max - ocv + v1) / r0, 0.0)
        i_accept = min(i_charge_max, i_cv)
        if effect == "regen_soc_limit":
            # the BMS's regen current limit falls from the motor's full regen current at
            # SoC_d to zero at 100 %
            derate = (1.0 - soc) / (1.0 - ph["derate_soc_frac"])
            i_regen = min(i_accept, b["regen_power_w"] / ocv * min(1.0, max(derate, 0.0)))
        else:
            i_regen = i_accept
        if soc >= 1.0:
            i_regen = i_accept = 0.0

        # -- driver and wheel -------------------------------------------------------------
        a_dem = min(max((v_ahead[k] - v) / preview, -2.0), 1.6)
        stopped = v < 0.05 and v_now[k] < 0.05 and v_ahead[k] < 0.05
        f_roll = (b["c_rr0"] * mass * GRAVITY_MPS2 * cos_t * (1.0 + b["c_rr_speed_per_mps"] * v)
                  if v > 0.01 else 0.0)
        f_aero = 0.5 * AIR_DENSITY_KG_PER_M3 * b["cda_m2"] * v * v
        f_grade = mass * GRAVITY_MPS2 * sin_t
        f_drag = drag_n + ph.get("floor_n", 0.0) if effect == "dragging_brake" and v > 0.01 \
            else 0.0
        f_need = m_eff * a_dem + f_roll + f_aero + f_grade + f_drag
        f_motor = 0.0
        f_fric = 0.0
        derated = 0.0
        v_ref = max(v, 0.5)
        if stopped:
            a_dem = 0.0
            f_need = 0.0
        elif f_need > 0.0:
            f_motor = min(f_need, b["traction_force_n"], b["traction_power_w"] / v_ref)
            # the voltage floor: traction gets what the pack can give after the loads
            f_floor = traction_force_at_power((p_dis_max - p_aux - p_hidden) * eta, v,
                                              f_roll + f_aero + f_grade + f_drag, m_eff, dt)
            if f_floor < f_motor:
                f_motor, derated = f_floor, 1.0
        else:
            fade = min(max((v - b["regen_zero_speed_mps"])
                           / (b["regen_full_speed_mps"] - b["regen_zero_speed_mps"]), 0.0), 1.0)
            p_batt_cap = i_regen * (ocv - v1 + r0 * i_regen)  # charge power at the limit
            p_regen_cap = min(b["regen_power_w"] * fade,
                              max(p_batt_cap + p_aux + p_hidden, 0.0) / eta)
            f_motor = max(f_need, -p_regen_cap / v_ref, -mass * b["regen_max_decel_mps2"])
            f_fric = f_need - f_motor
        a = 0.0 if stopped else (f_motor + f_fric - f_roll - f_aero - f_grade - f_drag) / m_eff
        v_new = 0.0 if stopped else max(v + a * dt, 0.0)
        if v_new == 0.0 and v > 0.0:
            # standing still within the step: the brakes take only what stops the bus
            a = -v / dt
            f_fric = m_eff * a - f_motor + f_roll + f_aero + f_grade + f_drag
        v_mid = 0.5 * (v + v_new)
        braking = f_fric < 0.0 or f_need < -0.5 * m_eff
        if effect == "air_compressor" and braking and not braking_before:
            pressure -= ph["brake_bar"]
        braking_before = braking
        if effect == "dragging_brake":  # the pads clamp again on each application, then fade
            drag_n *= math.exp(-v_mid * dt / ph["fade_m"])
            if f_fric < 0.0:
                drag_n = max(drag_n, ph["residual_n"])
        p_wheel = f_motor * v_mid
        p_drive = p_wheel / eta if p_wheel > 0.0 else p_wheel * eta

        # -- charger and battery ---------------------------------------------------------
        p_ch = 0.0
        cv_phase = 0.0
        if plugged[k] and not charging_done:
            if soc >= charge_stop_frac:
                charging_done = True
            else:
                p_request = p_aux + p_hidden + p_drive + i_accept * (ocv - v1 + r0 * i_accept)
                p_ch = max(min(charger_w[k], p_request), 0.0)
                # the cells' voltage, not the charger or the C-rate, sets the current
                cv_phase = float(p_request < charger_w[k] and i_cv < i_charge_max)
        if not plugged[k]:
            charging_done = False
        p_batt = p_drive + p_aux + p_hidden - p_ch
        emf = ocv - v1
        disc = emf * emf - 4.0 * r0 * p_batt
        i_batt = (emf - math.sqrt(disc)) / (2.0 * r0) if disc > 0.0 else emf / (2.0 * r0)
        v_term = emf - r0 * i_batt
        soc -= i_batt * dt / (3600.0 * q_ah) * (1.0 if i_batt > 0.0 else
                                                 b["coulombic_efficiency"])
        loss = r0 * i_batt * i_batt + v1 * i_batt
        v1 = v1 * decay1 + r1 * (1.0 - decay1) * i_batt
        if not managed:
            pack_temp += (loss - ph["pack_ha_w_per_k"] * (pack_temp - ambient[k])) * dt \
                / ph["pack_heat_capacity_j_per_k"]

        # -- bookkeeping -----------------------------------------------------------------
        e["battery"] += p_batt * dt
        e["ocv"] += ocv * i_batt * dt
        e["battery_loss"] += loss * dt
        e["wheel"] += p_wheel * dt
        e["road"] += (f_roll + f_aero) * v_mid * dt
        e["grade"] += f_grade * v_mid * dt
        e["friction"] += -f_fric * v_mid * dt
        e["drive_dc"] += p_drive * dt
        e["aux"] += p_aux * dt
        e["hidden"] += p_hidden * dt
        e["charger"] += p_ch * dt
        e["force"] += f_drag * v_mid * dt
        altitude += v_mid * sin_t * dt
        dist += v_mid * dt
        if k % out_every == 0:
            j = k // out_every
            vals = (v, soc, i_batt, v_term, ocv, p_batt, p_wheel, p_drive, p_aux, p_hidden,
                    p_ch)
            for name, val in zip(names[:11], vals, strict=True):
                rec[name][j] = val
            for name in e:
                rec[f"e_{name}_j"][j] = e[name]
            rec["e_kinetic_j"][j] = 0.5 * m_eff * v_new * v_new
            rec["cabin_temp_degc"][j] = cabin
            rec["pack_temp_degc"][j] = pack_temp
            rec["air_pressure_bar"][j] = pressure
            rec["altitude_m"][j] = altitude
            rec["distance_m"][j] = dist
            rec["accel_mps2"][j] = a
            rec["cv_phase"][j] = cv_phase
            rec["p_force_w"][j] = f_drag * v_mid
            rec["e_force_j"][j] = e["force"]
            rec["derated"][j] = derated
            rec["p_discharge_max_w"][j] = p_dis_max
            rec["p_charge_max_w"][j] = i_accept * (ocv - v1 + r0 * i_accept)
        v = v_new
    rows = held[::out_every]
    trace = pd.DataFrame({"time_s": t[::out_every], "clock_h": clock[::out_every], **rec})
    trace["grade_frac"] = grade[::out_every]
    trace["passengers"] = pax[::out_every].astype(int)
    trace["door_open"] = door[::out_every]
    # a session ends when the BMS reaches the stop SoC, though the bus stays under the mast
    trace["plugged"] = plugged[::out_every]
    trace["charging"] = ((trace["plugged"] == 1) & (trace["p_charger_w"] > 0.0)).astype(int)
    trace["charger_kw"] = np.where(trace["charging"] == 1, charger_w[::out_every] / 1000.0, 0.0)
    trace["ambient_degc"] = ambient[::out_every]
    trace["leg"] = plan["leg"].to_numpy()[rows]
    trace.attrs.update(plan.attrs)
    return trace
