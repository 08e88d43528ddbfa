"""The fixed skeleton of one forward-facing time step.

The step is a sequence of stages. ``Site`` stages call the effect that fills a slot; ``SinkSum``
stages sum the contributions of the chosen effects; ``Code`` stages are the model's own
physics, which every bus shares: force allocation between motor and friction brakes, the
longitudinal dynamics, and the battery's power limits. The code generator
(:mod:`ebus_env.model.generate`) walks this list once per model and emits one flat function.

Per step (state at t_k, inputs of row k, everything in SI)::

    loads and limits at t_k  ->  driver demand  ->  allocation + dynamics (v_k -> v_k+1)
      -> motor power at v_mid = (v_k + v_k+1)/2  ->  battery limits  ->  charger
      -> battery power = motor + loads - charger  ->  battery update (SoC_k -> SoC_k+1)
      -> the pack's heat (an unmanaged pack's temperature T_k -> T_k+1)

Powers use v_mid so that the energy balance closes exactly:
F v_mid dt = m_eff (v_k+1^2 - v_k^2)/2 + F_road v_mid dt.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba


@dataclass(frozen=True)
class Site:
    """Call the effect filling ``slot`` at call site ``call`` (only while ``when`` holds, if
    given; otherwise the slot's pass-through values stand)."""

    slot: str
    call: str = "main"
    when: str = ""


@dataclass(frozen=True)
class SinkSum:
    """Sum the contributions into ``sink``."""

    sink: str


@dataclass(frozen=True)
class Code:
    """Model code. A line ``{slot.call}`` re-emits that call (same indentation)."""

    text: str
    provides: tuple[str, ...]


@numba.njit(error_model="numpy", inline="always")
def move(wheel_force_n: float, road_force_n: float, effective_mass_kg: float, speed_mps: float,
         dt_s: float) -> tuple[float, float, float]:
    """Advance the speed one step: m_eff a = F_wheel - F_road, v_next = v + a dt.

    The bus never rolls backwards: when v_next would be negative the brakes stop it at
    zero, and the wheel force becomes the one that does exactly that.
    Returns (wheel force [N], acceleration [m/s^2], next speed [m/s]).
    """
    accel = (wheel_force_n - road_force_n) / effective_mass_kg
    speed_next = speed_mps + accel * dt_s
    if speed_next < 0.0:
        speed_next = 0.0
        accel = -speed_mps / dt_s
        wheel_force_n = effective_mass_kg * accel + road_force_n
    return wheel_force_n, accel, speed_next


_ALLOCATE = """
# -- allocate the demanded wheel force: motor (traction or regen) and friction brakes
wheel_force_n = wheel_force_demand_n
brake_floor_n = road_force_n - effective_mass_kg * max_brake_decel_mps2
if wheel_force_n < brake_floor_n:
    wheel_force_n = brake_floor_n
if wheel_force_n > traction_force_max_n:
    wheel_force_n = traction_force_max_n
if wheel_force_n > 0.0 and discharge_power_max_w <= 0.0:
    wheel_force_n = 0.0
if wheel_force_n >= 0.0:
    motor_force_n = wheel_force_n
else:
    motor_force_n = max(wheel_force_n * regen_share, -regen_force_max_n)
wheel_force_n, accel_mps2, speed_mps_next = _move(
    wheel_force_n, road_force_n, effective_mass_kg, speed_mps, dt_s)
# friction brakes only hold back: where the motor's share exceeds the wheel force (a bus that
# stops within the step needs less braking), the motor takes the whole wheel force
if motor_force_n < wheel_force_n:
    motor_force_n = wheel_force_n
friction_brake_force_n = wheel_force_n - motor_force_n
speed_mid_mps = 0.5 * (speed_mps + speed_mps_next)
"""

_BATTERY_LIMITS = """
# -- the pack cannot deliver the traction power (its cell voltage floor, a near-empty pack):
# cut traction to what it can; the driver falls behind (battery_limited flags the step). The
# motor's efficiency moves with the cut, so the cut is made once more (then within 0.01 %)
battery_limited = 0.0
if motor_power_w > 0.0 and motor_power_w + dc_load_w > discharge_power_max_w:
    battery_limited = 1.0
    motor_force_n *= max(discharge_power_max_w - dc_load_w, 0.0) / motor_power_w
    wheel_force_n, accel_mps2, speed_mps_next = _move(
        motor_force_n, road_force_n, effective_mass_kg, speed_mps, dt_s)
    speed_mid_mps = 0.5 * (speed_mps + speed_mps_next)
    {drivetrain.power}
    if motor_power_w > 0.0 and motor_power_w + dc_load_w > discharge_power_max_w:
        motor_force_n *= max(discharge_power_max_w - dc_load_w, 0.0) / motor_power_w
        wheel_force_n, accel_mps2, speed_mps_next = _move(
            motor_force_n, road_force_n, effective_mass_kg, speed_mps, dt_s)
        speed_mid_mps = 0.5 * (speed_mps + speed_mps_next)
        {drivetrain.power}
    friction_brake_force_n = wheel_force_n - motor_force_n
# -- the pack cannot accept all the regen power: the friction brakes take the rest
regen_power_max_w = charge_power_max_w + dc_load_w
if motor_power_w < 0.0 and -motor_power_w > regen_power_max_w:
    scale = max(regen_power_max_w, 0.0) / -motor_power_w
    motor_force_n *= scale
    motor_power_w *= scale
    friction_brake_force_n = wheel_force_n - motor_force_n
motor_wheel_power_w = motor_force_n * speed_mid_mps
"""

_BOOKKEEPING = """
# -- an empty pack (at soc_min_frac the BMS opens it): the DC loads stop too. The loads that
# the charger, the regen and the pack cannot carry are unserved (traction was cut above);
# with no power left in the pack the bus is stranded
unserved_load_w = max(dc_load_w - charger_power_w - max(-motor_power_w, 0.0)
                      - max(discharge_power_max_w, 0.0), 0.0)
stranded = 1.0 if unserved_load_w > 0.0 and discharge_power_max_w <= 0.0 else 0.0
battery_power_w = motor_power_w + dc_load_w - unserved_load_w - charger_power_w
"""

_AFTER_BATTERY = """
# -- kinematics and energy bookkeeping (powers over the step, W)
distance_m_next = distance_m + speed_mid_mps * dt_s
distance_ref_m_next = distance_ref_m + (speed_ref_mps + 0.5 * accel_ref_mps2 * dt_s) * dt_s
distance_behind_m = distance_ref_m - distance_m
inertia_w = effective_mass_kg * accel_mps2 * speed_mid_mps
friction_brake_w = -friction_brake_force_n * speed_mid_mps
drivetrain_loss_w = motor_power_w - motor_wheel_power_w
charger_loss_w = grid_power_w - charger_power_w
battery_chemical_w = battery_power_w - battery_shortfall_w + battery_loss_w + coulombic_loss_w
"""

STAGES = (
    Site("vehicle"),
    Site("passengers"),
    SinkSum("mass_kg"),
    Code("effective_mass_kg = mass_kg * rotational_mass_factor\n", ("effective_mass_kg",)),
    SinkSum("road_force_n"),
    SinkSum("cabin_heat_w"),
    SinkSum("dc_load_w"),
    Site("aging"),
    Site("battery_thermal"),
    Site("battery", "pack"),
    Site("battery", "state"),
    Site("charge_limit", when="charger_connected >= 0.5"),  # a protocol of the charger
    Site("driver"),
    Site("drivetrain", "limits"),
    Site("regen"),
    Code(_ALLOCATE, ("wheel_force_n", "brake_floor_n", "motor_force_n", "accel_mps2",
                     "speed_mps_next", "friction_brake_force_n", "speed_mid_mps")),
    Site("drivetrain", "power"),
    Code(_BATTERY_LIMITS, ("battery_limited", "regen_power_max_w", "scale",
                           "motor_wheel_power_w")),
    Site("charger"),
    Code(_BOOKKEEPING, ("battery_power_w", "unserved_load_w", "stranded")),
    Site("battery", "update"),
    Site("battery_thermal", "heat"),  # the pack's temperature after this step's losses
    Code(_AFTER_BATTERY, ("distance_m_next", "distance_ref_m_next", "distance_behind_m",
                          "inertia_w", "friction_brake_w", "drivetrain_loss_w", "charger_loss_w",
                          "battery_chemical_w")),
)

TEMPORARIES = {"brake_floor_n", "scale", "regen_power_max_w"}
"""Locals of the skeleton that are not worth a trace column."""
