"""Battery pack (internal-resistance model) and its ageing.

Pack of N_s cells in series and N_p in parallel::

    Q     = Q_cell N_p (1 - RCD)                               capacity [Ah]
    T     = battery_temp_degc from the battery_thermal slot    [degC]
    OCV   = N_s OCV_cell(SoC)                                  open-circuit voltage [V]
    R     = R_cell N_s / N_p k_conn f(SoC) exp(Ea/R_g (1/T - 1/T_ref)) (1 + k_R RCD)
    I     = 2 P / (OCV + sqrt(OCV^2 - 4 R P))                  current for terminal power P
    V_t   = OCV - R I
    V_cell = OCV_cell - I R / (N_s k_conn)                     a cell's voltage (BMS reading)
    dSoC  = -eta I dt / (3600 Q),  eta = eta_c if I < 0 else 1

The BMS keeps every cell within its voltage window [V_min, V_max] (docs/physics.md §5.7):

    I_dis <= (OCV_cell - V_min) N_s k_conn / R,   I_chg <= (V_max - OCV_cell) N_s k_conn / R

(docs/physics.md §5.1, §5.2, §5.3). The current formula is the usual quadratic root written
so it stays exact as R -> 0. P > 0 and I > 0 discharge.
"""

from __future__ import annotations

import math

import numpy as np

from ebus_env.effects.base import Call, Effect, Param, State, effect, register
from ebus_env.effects.tables import Table, TableData, lookup1

_GAS_CONSTANT_J_PER_MOL_K = 8.314
_T_REF_K = 298.15

_OCV_SOC_PCT = (0.0, 2.5, 5.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0, 95.0, 97.5,
                100.0)

OCV_CELL = Table(
    "ocv_cell_v", "V", "Cell open-circuit voltage over SoC [%] (x)",
    presets={
        "lfp_a123": TableData(_OCV_SOC_PCT, (
            2.900, 2.976, 3.102, 3.172, 3.208, 3.237, 3.263, 3.270, 3.275, 3.280, 3.305, 3.315,
            3.319, 3.433, 3.590), source="A123 LiFePO4, davidmcq137/JetiLuaDFM DFM-InsP/A123.lua",
            param_defaults=(("cell_voltage_min_v", 2.0), ("cell_voltage_max_v", 3.6))),
        "lfp_lw_m1b": TableData(_OCV_SOC_PCT, (
            2.010, 2.908, 3.067, 3.199, 3.239, 3.278, 3.288, 3.299, 3.310, 3.321, 3.331, 3.342,
            3.348, 3.350, 3.598), source="Lithium Werks APR18650M1B, soorajsunil/Piecewise-Battery-OCV",
            param_defaults=(("cell_voltage_min_v", 2.0), ("cell_voltage_max_v", 3.6))),
        "nmc_p42a": TableData(_OCV_SOC_PCT, (
            2.506, 2.980, 3.163, 3.331, 3.475, 3.580, 3.657, 3.743, 3.839, 3.935, 4.031, 4.085,
            4.101, 4.147, 4.193), source="Molicel INR21700-P42A, soorajsunil/Piecewise-Battery-OCV",
            param_defaults=(("cell_voltage_min_v", 2.5), ("cell_voltage_max_v", 4.2))),
        "nmc_40t": TableData(_OCV_SOC_PCT, (
            2.500, 3.013, 3.177, 3.348, 3.487, 3.588, 3.658, 3.740, 3.836, 3.932, 4.029, 4.090,
            4.110, 4.151, 4.200), source="Samsung INR21700-40T, soorajsunil/Piecewise-Battery-OCV",
            param_defaults=(("cell_voltage_min_v", 2.5), ("cell_voltage_max_v", 4.2))),
    },
    default="lfp_a123",
)

RESISTANCE_SOC = Table(
    "resistance_soc_factor", "1", "Factor f(SoC) on the cell resistance over SoC [%] (x)",
    presets={"generic": TableData((0.0, 10.0, 20.0, 90.0, 100.0), (1.5, 1.2, 1.0, 1.0, 1.1),
                                  source="docs/physics.md §5.2")},
    default="generic",
)

BATTERY_PARAMS = (
    Param("cells_series", 204.0, "1", (1.0, 400.0), "Cells in series N_s",
          "200 kWh LFP at ~650 V: ~203 (docs/physics.md §5.1)", whole=True),
    Param("cells_parallel", 3.0, "1", (1.0, 100.0), "Cells (strings) in parallel N_p",
          whole=True),
    Param("cell_capacity_ah", 100.0, "Ah", (0.5, 1000.0), "Nominal cell capacity Q_cell"),
    Param("cell_resistance_mohm", 1.0, "mOhm", (0.05, 50.0),
          "Cell DC resistance at 25 degC, mid SoC, R_cell", "LFP 100-300 Ah prismatic 0.3-1.0 mOhm"),
    Param("connection_factor", 1.2, "1", (1.0, 1.6), "Busbar/contactor factor k_conn",
          "docs/physics.md §5.2: 1.1-1.3"),
    Param("activation_energy_j_per_mol", 25000.0, "J/mol", (0.0, 60000.0),
          "Arrhenius activation energy Ea of the resistance", "LFP ~25 kJ/mol, NMC ~30 kJ/mol"),
    Param("coulombic_efficiency", 0.998, "1", (0.95, 1.0), "Coulombic efficiency on charge eta_c",
          "docs/physics.md §5.3"),
    Param("soc_min_frac", 0.0, "1", (0.0, 0.3),
          "SoC at which the BMS opens the pack: traction and the DC loads stop (an empty pack)"),
    Param("soc_max_frac", 1.0, "1", (0.7, 1.0), "SoC the pack is never charged past"),
    Param("max_charge_c_rate", 3.0, "1/h", (0.1, 10.0),
          "Largest charge current (regen or charger) in C", "LFP up to 3C (paper)"),
    Param("max_discharge_c_rate", 5.0, "1/h", (0.1, 20.0), "Largest discharge current in C"),
    Param("cell_voltage_min_v", 2.0, "V", (1.5, 3.5),
          "Lowest cell voltage V_min the BMS allows: discharge is derated to stay above it",
          "the OCV table's cell data sheet (docs/physics.md §5.7); A123 LFP 2.0 V"),
    Param("cell_voltage_max_v", 3.6, "V", (3.3, 4.5),
          "Highest cell voltage V_max the BMS allows: charge and regen are capped below it",
          "the OCV table's cell data sheet (docs/physics.md §5.7); A123 LFP 3.6 V"),
)


def battery_pack(capacity_factor: float, resistance_factor: float, battery_temp_degc: float,
                 cells_series: float, cells_parallel: float, cell_capacity_ah: float,
                 cell_resistance_mohm: float, connection_factor: float,
                 activation_energy_j_per_mol: float) -> tuple[float, float]:
    """Capacity Q [Ah] and resistance R_pack [Ohm] of the aged pack at its temperature, the
    latter before the SoC factor: R = R_pack f(SoC).

    Its own call because these change only with ageing and pack temperature: when both are
    constant (a thermally managed pack), the lane loop computes them, and the exponential, once
    per run instead of once per step and bus."""
    arrhenius = math.exp(activation_energy_j_per_mol / _GAS_CONSTANT_J_PER_MOL_K
                         * (1.0 / (battery_temp_degc + 273.15) - 1.0 / _T_REF_K))
    capacity_ah = cell_capacity_ah * cells_parallel * capacity_factor
    resistance_ohm = (cell_resistance_mohm * 1e-3 * cells_series / cells_parallel
                      * connection_factor * arrhenius * resistance_factor)
    return capacity_ah, resistance_ohm


def battery_state(soc_frac: float, bms_open: float, charger_connected: float, capacity_ah: float,
                  pack_resistance_ohm: float, dt_s: float, cells_series: float, connection_factor: float,
                  coulombic_efficiency: float, soc_min_frac: float, soc_max_frac: float,
                  max_charge_c_rate: float, max_discharge_c_rate: float, cell_voltage_min_v: float,
                  cell_voltage_max_v: float, ocv_cell_v: np.ndarray,
                  resistance_soc_factor: np.ndarray) -> tuple[float, float, float, float, float]:
    """OCV [V], resistance [Ohm] and the current/power limits of this step.

    Charge current: the C-rate, no further than ``soc_max_frac`` within the step, and no cell
    above V_max. Discharge current: the C-rate, no cell below V_min, and never beyond the
    maximum-power current OCV / 2R; zero at or below ``soc_min_frac``. A cell sees the pack's
    current through its share of the resistance without the busbars and contactors,
    R / (N_s k_conn). While the BMS holds an emptied pack open, off a charger, nothing flows
    (no regen either)."""
    soc_pct = 100.0 * soc_frac
    ocv_cell = lookup1(ocv_cell_v, soc_pct)
    ocv_v = cells_series * ocv_cell
    resistance_ohm = pack_resistance_ohm * lookup1(resistance_soc_factor, soc_pct)
    amps_per_volt = cells_series * connection_factor / resistance_ohm  # cell voltage -> current
    headroom_a = max(soc_max_frac - soc_frac, 0.0) * (
        3600.0 * capacity_ah / (coulombic_efficiency * dt_s))
    charge_a = min(max_charge_c_rate * capacity_ah, headroom_a,
                   max(cell_voltage_max_v - ocv_cell, 0.0) * amps_per_volt)
    isolated = bms_open > 0.5 and charger_connected < 0.5
    if isolated:
        charge_a = 0.0
    charge_w = charge_a * (ocv_v + resistance_ohm * charge_a)
    discharge_w = 0.0
    if soc_frac > soc_min_frac and not isolated:
        discharge_a = min(max_discharge_c_rate * capacity_ah, 0.5 * ocv_v / resistance_ohm,
                          max(ocv_cell - cell_voltage_min_v, 0.0) * amps_per_volt)
        discharge_w = discharge_a * (ocv_v - resistance_ohm * discharge_a)
    return ocv_v, resistance_ohm, charge_a, charge_w, discharge_w


def battery_update(battery_power_w: float, soc_frac: float, bms_open: float, charger_connected: float,
                   ocv_v: float, resistance_ohm: float, capacity_ah: float, dt_s: float,
                   cells_series: float, connection_factor: float, coulombic_efficiency: float,
                   soc_min_frac: float) -> tuple[float, float, float, float, float, float, float, float]:
    """Current [A], terminal voltage [V], next SoC, ohmic loss [W], coulombic loss [W], the
    power the pack could not deliver [W] (> 0 only beyond its maximum power OCV^2 / 4R), a
    cell's voltage as the BMS reads it [V] and whether the BMS holds the pack open next: from
    the step that empties it (SoC at ``soc_min_frac``) off a charger, until a charger
    connects."""
    disc = ocv_v * ocv_v - 4.0 * resistance_ohm * battery_power_w
    shortfall_w = 0.0
    if disc < 0.0:
        disc = 0.0
        shortfall_w = battery_power_w - ocv_v * ocv_v / (4.0 * resistance_ohm)
    current_a = 2.0 * (battery_power_w - shortfall_w) / (ocv_v + math.sqrt(disc))
    voltage_v = ocv_v - resistance_ohm * current_a
    ohmic_w = resistance_ohm * current_a * current_a
    if current_a < 0.0:
        eta = coulombic_efficiency
        coulombic_w = (1.0 - eta) * ocv_v * -current_a
    else:
        eta = 1.0
        coulombic_w = 0.0
    soc_next = soc_frac - eta * current_a * (dt_s / (3600.0 * capacity_ah))
    cell_v = (ocv_v - resistance_ohm * current_a / connection_factor) / cells_series
    off_charger = charger_connected < 0.5
    open_next = 1.0 if off_charger and (bms_open > 0.5 or soc_next <= soc_min_frac) else 0.0
    return current_a, voltage_v, soc_next, ohmic_w, coulombic_w, shortfall_w, cell_v, open_next


rint_battery = register(Effect(
    name="rint_battery",
    slot="battery",
    calls={
        "pack": Call(battery_pack, ("capacity_ah", "pack_resistance_ohm")),
        "state": Call(battery_state, ("ocv_v", "resistance_ohm", "charge_current_max_a",
                                      "charge_power_max_w", "discharge_power_max_w")),
        "update": Call(battery_update, ("battery_current_a", "battery_voltage_v", "soc_frac_next",
                                        "battery_loss_w", "coulombic_loss_w",
                                        "battery_shortfall_w", "cell_voltage_v",
                                        "bms_open_next")),
    },
    params=BATTERY_PARAMS,
    tables=(OCV_CELL, RESISTANCE_SOC),
    states=(State("soc_frac", "1", "State of charge", lambda p, x: 0.9),
            State("bms_open", "1", "1 while the BMS holds an emptied pack open (until a "
                  "charger connects)", lambda p, x: 0.0)),
    drivers=("battery_current_a", "soc_frac"),
    doc=__doc__,
))


@effect("static_rcd", slot="aging", label="battery ageing", params=[
    Param("rcd_frac", 0.0, "1", (0.0, 0.3), "Relative capacity degradation RCD",
          "Hasan et al. 2023, tuned parameter (< 25 %)"),
    Param("resistance_growth", 1.5, "1", (0.0, 3.0),
          "Resistance growth per unit RCD, k_R: R = R_0 (1 + k_R RCD)", "docs/physics.md §5.5: 1-2"),
])
def static_rcd(rcd_frac: float, resistance_growth: float) -> tuple[float, float]:
    """Static ageing: capacity factor 1 - RCD and resistance factor 1 + k_R RCD."""
    return 1.0 - rcd_frac, 1.0 + resistance_growth * rcd_frac


# -- battery temperature (the battery_thermal slot) ------------------------------------------
@effect("managed_temperature", slot="battery_thermal", label="managed pack temperature", params=[
    Param("temperature_degc", 25.0, "degC", (-30.0, 60.0),
          "Pack temperature T held by the thermal management"),
])
def managed_temperature(temperature_degc: float) -> float:
    """A thermally managed pack: constant temperature T [degC]."""
    return temperature_degc


def pack_temperature(cell_temp_degc: float) -> float:
    """The pack's temperature over this step: its state."""
    return cell_temp_degc


def pack_heat(cell_temp_degc: float, ambient_degc: float, battery_loss_w: float, dt_s: float,
              time_constant_h: float, heat_capacity_j_per_k: float) -> float:
    """The pack's temperature after the step: its lumped heat balance
    C dT/dt = Q - hA (T - T_amb), with Q the step's ohmic loss and hA = C / tau."""
    rate_k_per_s = ((ambient_degc - cell_temp_degc) / (3600.0 * time_constant_h)
                    + battery_loss_w / heat_capacity_j_per_k)
    return cell_temp_degc + rate_k_per_s * dt_s


ambient_battery = register(Effect(
    name="ambient_battery",
    slot="battery_thermal",
    calls={"main": Call(pack_temperature, ("battery_temp_degc",)),
           "heat": Call(pack_heat, ("cell_temp_degc_next",))},
    params=(
        Param("time_constant_h", 3.0, "h", (0.1, 48.0),
              "Time constant tau = C / hA of the pack temperature following the ambient"),
        Param("initial_offset_k", 0.0, "K", (-20.0, 30.0),
              "Pack temperature above ambient at the start of the run"),
        Param("heat_capacity_j_per_k", 2.0e6, "J/K", (5.0e4, 5.0e7),
              "Heat capacity C of the pack: its mass times the cells' specific heat",
              "~1.8 t of LFP pack x 1.1 kJ/(kg K) (Forgez et al. 2010); docs/physics.md §5.6"),
    ),
    states=(State("cell_temp_degc", "degC", "Pack temperature without thermal management",
                  lambda p, x: x.get("ambient_degc", 20.0) + p["initial_offset_k"]),),
    drivers=("ambient_degc",),
    key_params=("initial_offset_k",),
    # how fast the pack follows the air and warms by its losses sets the form of its
    # resistance over a day: C / hA of a pack in its enclosure, from a ventilated one's
    # hour and a half to a still one's half a day
    shape_params={"time_constant_h": (1.5, 6.0, 12.0)},
    refines="managed_temperature",
    label="cold battery resistance",
    doc="""A pack without thermal management: it follows the ambient, warmed by its losses.

C dT/dt = R I^2 - (C / tau) (T - T_amb): a cold day raises the pack's resistance (Arrhenius),
and driving and charging warm it and lower it again. It starts ``initial_offset_k`` above the
first ambient (the state's initial value).""",
))
