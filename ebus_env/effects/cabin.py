"""Cabin thermal model with HVAC: one air node, heat pump with PTC back-up, setpoint control."""

from __future__ import annotations

from ebus_env.effects.base import Param, State, effect
from ebus_env.units import AIR_CP_J_PER_KG_K

_AIR_DENSITY_KG_PER_M3 = 1.2


@effect("cabin_hvac", sink="dc_load_w", label="cabin heating and cooling", key_params=("ua_w_per_k",),
        returns=("hvac_heat_w", "cabin_temp_degc_next"),
        drivers=("ambient_degc", "door_open", "passengers", "solar_w_per_m2"),
        handles={"cabin_setpoint_degc": "setpoint_degc"},
        params=[
    Param("setpoint_degc", 20.0, "degC", (14.0, 28.0), "Cabin setpoint T_set",
          "Hasan et al. 2023, tuned parameter; VDV 236-style comfort curves"),
    Param("deadband_k", 1.0, "K", (0.0, 5.0),
          "Half-width of the comfort band around T_set in which the HVAC idles"),
    Param("ua_w_per_k", 400.0, "W/K", (10.0, 1500.0), "Envelope conductance UA",
          "12 m: 300-500 W/K (docs/physics.md §7.2)"),
    Param("heat_capacity_j_per_k", 1.0e6, "J/K", (2.0e4, 5.0e6),
          "Effective heat capacity C of cabin air and interior", "12 m: 0.5-1.5 MJ/K"),
    Param("fresh_air_kg_per_s", 0.4, "kg/s", (0.0, 2.0), "Fresh-air mass flow m_fresh",
          "12 m: 0.3-0.6 kg/s"),
    Param("door_air_m3_per_s", 0.7, "m^3/s", (0.0, 5.0),
          "Air exchanged through open doors V_door (all doors together)",
          "10-30 % of ~70 m^3 cabin air per 20 s stop (docs/physics.md §7.2)"),
    Param("passenger_heat_w", 100.0, "W", (50.0, 150.0), "Sensible heat per person q_p",
          "70-100 W (docs/physics.md §7.2)"),
    Param("solar_area_m2", 6.0, "m^2", (0.0, 20.0),
          "Effective glazing area tau_g A_glass for solar gain", "0.4-0.6 x 10-15 m^2"),
    Param("heating_max_w", 25000.0, "W", (0.0, 80000.0), "Largest heating power (thermal)",
          "12 m 20-30 kW, 18 m 30-40 kW"),
    Param("cooling_max_w", 25000.0, "W", (0.0, 80000.0), "Largest cooling power (thermal)",
          "12 m 20-30 kW, 18 m 30-40 kW"),
    Param("heat_pump_max_w", 16000.0, "W", (0.0, 80000.0),
          "Heating power the heat pump gives before the PTC heater adds the rest"),
    Param("heat_pump_min_ambient_degc", -10.0, "degC", (-30.0, 10.0),
          "Below this ambient the heat pump is off and the PTC heater does all heating"),
    Param("cop_heat_0c", 2.45, "1", (1.0, 6.0), "Heat-pump heating COP at 0 degC",
          "COP_h = 2.45 + 0.07 T_amb (docs/physics.md §7.3)"),
    Param("cop_heat_slope_per_k", 0.07, "1/K", (0.0, 0.3), "Change of heating COP per K ambient"),
    Param("cop_cool_25c", 3.0, "1", (1.0, 8.0), "Cooling COP at 25 degC",
          "COP_c = 3.0 - 0.06 (T_amb - 25) (docs/physics.md §7.3)"),
    Param("cop_cool_slope_per_k", 0.06, "1/K", (0.0, 0.3), "Drop of cooling COP per K ambient"),
    Param("fan_power_w", 800.0, "W", (0.0, 5000.0), "HVAC fans, always on", "0.5-1.5 kW"),
    Param("control_gain_w_per_k", 3000.0, "W/K", (100.0, 50000.0),
          "Feedback gain of the HVAC controller K"),
], states=[
    State("cabin_temp_degc", "degC", "Cabin air temperature T_cab (starts preconditioned)",
          lambda p, x: p["setpoint_degc"]),
])
def cabin_hvac(cabin_temp_degc: float, ambient_degc: float, passengers: float, door_open: float,
               solar_w_per_m2: float, cabin_heat_w: float, dt_s: float, setpoint_degc: float,
               deadband_k: float, ua_w_per_k: float, heat_capacity_j_per_k: float,
               fresh_air_kg_per_s: float, door_air_m3_per_s: float, passenger_heat_w: float,
               solar_area_m2: float, heating_max_w: float, cooling_max_w: float, heat_pump_max_w: float,
               heat_pump_min_ambient_degc: float, cop_heat_0c: float, cop_heat_slope_per_k: float,
               cop_cool_25c: float, cop_cool_slope_per_k: float, fan_power_w: float,
               control_gain_w_per_k: float) -> tuple[float, float, float]:
    """Electric power of the HVAC [W], its heat into the cabin [W] and the next cabin temperature.

    One air node (docs/physics.md §7.2)::

        C dT/dt = Q_hvac + Q_pass
        Q_pass  = -(UA + m_fresh c_p + rho c_p V_door door) (T - T_amb)
                  + (n + 1) q_p + tau_g A_glass G + Q_extra

    The controller holds the cabin inside [T_set - db, T_set + db]: inside the band the HVAC
    idles; outside it, Q_hvac = -Q_pass + K (T_edge - T) cancels the passive flows and pulls the
    cabin back to the nearest edge, saturated at the heating/cooling maxima. Electric power::

        heating:  P = Q_hp / COP_h(T_amb) + Q_ptc      COP_h = clip(c_h0 + s_h T_amb, 1, 6)
        cooling:  P = |Q| / COP_c(T_amb)               COP_c = clip(c_c25 - s_c (T_amb - 25), 1, 8)

    plus the fans. The heat pump covers heating up to its maximum (and only above its minimum
    ambient); the PTC heater (COP 1) adds the rest. While the bus is on a charger, the charger
    supplies this power: that is preconditioning from the grid.
    """
    conductance = (ua_w_per_k + fresh_air_kg_per_s * AIR_CP_J_PER_KG_K
                   + _AIR_DENSITY_KG_PER_M3 * AIR_CP_J_PER_KG_K * door_air_m3_per_s * door_open)
    passive = (-conductance * (cabin_temp_degc - ambient_degc)
               + (passengers + 1.0) * passenger_heat_w
               + solar_area_m2 * solar_w_per_m2 + cabin_heat_w)
    low = setpoint_degc - deadband_k
    high = setpoint_degc + deadband_k
    heat = 0.0
    if cabin_temp_degc < low:
        heat = control_gain_w_per_k * (low - cabin_temp_degc) - passive
    elif cabin_temp_degc > high:
        heat = control_gain_w_per_k * (high - cabin_temp_degc) - passive
    if heat > heating_max_w:
        heat = heating_max_w
    elif heat < -cooling_max_w:
        heat = -cooling_max_w
    electric = fan_power_w
    if heat > 0.0:
        from_pump = 0.0
        if ambient_degc >= heat_pump_min_ambient_degc:
            from_pump = min(heat, heat_pump_max_w)
        cop = min(max(cop_heat_0c + cop_heat_slope_per_k * ambient_degc, 1.0), 6.0)
        electric += from_pump / cop + (heat - from_pump)
    elif heat < 0.0:
        cop = min(max(cop_cool_25c - cop_cool_slope_per_k * (ambient_degc - 25.0), 1.0), 8.0)
        electric += -heat / cop
    next_temp = cabin_temp_degc + (heat + passive) * (dt_s / heat_capacity_j_per_k)
    return electric, heat, next_temp
