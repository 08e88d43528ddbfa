"""Drivetrain: motor torque/power envelope, gearbox, and motor + inverter losses.

Wheel and motor are linked by the overall ratio i and the wheel radius r::

    omega = v i / r                                   motor speed [rad/s]
    T_m   = F r / (i eta_g)      (F >= 0, motoring)   motor torque [N m]
    T_m   = F r eta_g / i        (F <  0, generating)

Two implementations of the ``drivetrain`` slot share the envelope (``limits``) and differ in how
they turn shaft power into DC-bus power (``power``):

* ``efficiency_map``: P_el = T_m omega + P_loss(T_m, omega), the loss read from a torque x speed
  map (motoring and generating quadrants) normalised by peak torque and top motor speed;
* ``constant_efficiency``: P_el = P_m / eta_m when motoring, P_m eta_m when generating.
"""

from __future__ import annotations

import math

import numpy as np

from ebus_env.effects.base import Call, Effect, Param, helper, register
from ebus_env.effects.tables import Table, TableData, TableValue, lookup2

MOTOR_PARAMS = (
    Param("wheel_radius_m", 0.48, "m", (0.2, 0.7), "Dynamic wheel radius r",
          "275/70R22.5 tyre; TransitBus 0.5 m (docs/physics.md §4.4)"),
    Param("gear_ratio", 5.67, "1", (1.0, 30.0), "Overall ratio motor : wheel, i",
          "TransitBus 5.67 (central motor)"),
    Param("gearbox_efficiency", 0.96, "1", (0.85, 1.0), "Gearbox + final drive efficiency eta_g",
          "TransitBus 0.95; docs/physics.md §4.4: 0.95-0.97"),
    Param("peak_power_kw", 200.0, "kW", (10.0, 800.0), "Motor peak mechanical power P_max",
          "Volvo 7900 E 200 kW; Solaris Urbino 12 160-250 kW"),
    Param("peak_torque_nm", 2800.0, "N m", (50.0, 10000.0), "Motor peak torque T_max",
          "Siemens 1DB2016 class central motor (docs/physics.md §4.4)"),
    Param("regen_power_kw", 200.0, "kW", (0.0, 800.0),
          "Largest generating (regenerative) shaft power P_gen"),
    Param("max_motor_speed_rpm", 3000.0, "rpm", (500.0, 25000.0),
          "Top motor speed omega_max (normalises the loss map's speed axis)"),
)

_MIN_SPEED_MPS = 0.1  # below this the power limit is evaluated at 0.1 m/s (torque limit rules)


def limits(speed_mps: float, wheel_radius_m: float, gear_ratio: float, gearbox_efficiency: float,
           peak_power_kw: float, peak_torque_nm: float, regen_power_kw: float) -> tuple[float, float]:
    """Largest traction and regenerative-braking forces at the wheels [N], both >= 0::

        F_trac = min(T_max i eta_g / r, P_max eta_g / v)
        F_gen  = min(T_max i / (r eta_g), P_gen / (eta_g v))
    """
    inv_v = 1.0 / max(speed_mps, _MIN_SPEED_MPS)
    traction = min(peak_torque_nm * gear_ratio * gearbox_efficiency / wheel_radius_m,
                   peak_power_kw * 1e3 * gearbox_efficiency * inv_v)
    regen = min(peak_torque_nm * gear_ratio / (wheel_radius_m * gearbox_efficiency),
                regen_power_kw * 1e3 / gearbox_efficiency * inv_v)
    return traction, regen


@helper
def _shaft(motor_force_n: float, speed_mps: float, wheel_radius_m: float, gear_ratio: float,
           gearbox_efficiency: float) -> tuple[float, float]:
    """Motor torque [N m] and speed [rad/s] for a wheel force and vehicle speed."""
    omega = speed_mps * (gear_ratio / wheel_radius_m)
    if motor_force_n >= 0.0:
        torque = motor_force_n * (wheel_radius_m / (gear_ratio * gearbox_efficiency))
    else:
        torque = motor_force_n * (wheel_radius_m * gearbox_efficiency / gear_ratio)
    return torque, omega


def map_power(motor_force_n: float, speed_mid_mps: float, wheel_radius_m: float, gear_ratio: float,
              gearbox_efficiency: float, peak_torque_nm: float, max_motor_speed_rpm: float,
              loss_map: np.ndarray) -> float:
    """DC-bus power of the motor + inverter [W]: P_el = T_m omega + P_loss(T_m, omega), with
    P_loss = L(T_m / T_max, omega / omega_max) T_max omega_max read from ``loss_map``.
    No torque, no loss: the inverter is off when the motor is not asked for torque."""
    torque, omega = _shaft(motor_force_n, speed_mid_mps, wheel_radius_m, gear_ratio,
                           gearbox_efficiency)
    if torque == 0.0:
        return 0.0
    omega_max = max_motor_speed_rpm * (math.pi / 30.0)
    loss = lookup2(loss_map, torque * (1.0 / peak_torque_nm), omega * (1.0 / omega_max))
    return torque * omega + loss * (peak_torque_nm * omega_max)


def constant_power(motor_force_n: float, speed_mid_mps: float, wheel_radius_m: float, gear_ratio: float,
                   gearbox_efficiency: float, motor_efficiency: float) -> float:
    """DC-bus power with one motor + inverter efficiency eta_m [W]:
    P_el = P_m / eta_m (motoring), P_m eta_m (generating)."""
    torque, omega = _shaft(motor_force_n, speed_mid_mps, wheel_radius_m, gear_ratio,
                           gearbox_efficiency)
    shaft_w = torque * omega
    if shaft_w >= 0.0:
        return shaft_w * (1.0 / motor_efficiency)
    return shaft_w * motor_efficiency


# -- the default loss map --------------------------------------------------------------------
def loss_model_map(base_speed_frac: float = 0.3, copper: float = 0.04, iron: float = 0.004,
                   eddy: float = 0.002, constant: float = 0.001, n_torque: int = 41,
                   n_speed: int = 21) -> TableData:
    """Normalised loss map of a generic PMSM + inverter from a loss model.

    With tau = T/T_max, s = omega/omega_max, s_b the base speed (P_max = T_max omega_b) and the
    loss in units of P_max::

        P_loss / P_max = c_cu tau^2 + c_fe (s/s_b) + c_ed (s/s_b)^2 + c_0

    (copper, hysteresis, eddy-current + windage, and switching/constant terms), returned in
    units of T_max omega_max (multiply by s_b). The defaults give 94-96 % near the base point
    and 85-90 % at light load, typical of traction PMSMs with SiC/IGBT inverters (docs/physics.md §4.2).
    """
    tau = np.linspace(-1.0, 1.0, n_torque)
    s = np.linspace(0.0, 1.0, n_speed)
    t, w = np.meshgrid(tau, s, indexing="ij")
    r = w / base_speed_frac
    loss = base_speed_frac * (copper * t**2 + iron * r + eddy * r**2 + constant)
    return TableData(tuple(tau), tuple(s), tuple(map(tuple, loss)),
                     source="loss model, docs/physics.md §4.2")


def efficiency_to_loss(data: TableData) -> TableData:
    """Turn an efficiency map eta(tau, s) into the normalised loss map the model reads:
    L = |tau s| (1/eta - 1) when motoring (tau > 0), |tau s| (1 - eta) when generating."""
    tau = np.asarray(data.x, dtype=float)
    s = np.asarray(data.y, dtype=float)
    eta = np.asarray(data.z, dtype=float)
    if np.any(eta <= 0.0) or np.any(eta > 1.0):
        raise ValueError("efficiency map values must lie in (0, 1].")
    shaft = np.abs(np.outer(tau, s))
    loss = np.where(tau[:, None] >= 0.0, shaft * (1.0 / eta - 1.0), shaft * (1.0 - eta))
    return TableData(data.x, data.y, tuple(map(tuple, loss)), source=data.source)


class LossMapTable(Table):
    """The loss map; a config may give either losses or, more commonly, efficiencies
    (``{x: torque_frac, y: speed_frac, z: efficiency, kind: efficiency}``)."""

    def resolve(self, value: TableValue = None) -> TableData:
        if isinstance(value, dict) and value.get("kind") == "efficiency":
            rest = {k: v for k, v in value.items() if k != "kind"}
            return efficiency_to_loss(super().resolve(rest))
        if isinstance(value, dict) and value.get("kind", "loss") == "loss":
            value = {k: v for k, v in value.items() if k != "kind"}
        return super().resolve(value)


LOSS_MAP = LossMapTable(
    "loss_map", "1 (W per T_max omega_max)",
    "Motor + inverter loss over torque fraction T/T_max in [-1, 1] (x) and speed fraction "
    "omega/omega_max in [0, 1] (y)",
    presets={"generic_pmsm": loss_model_map()}, default="generic_pmsm",
)

efficiency_map = register(Effect(
    name="efficiency_map",
    slot="drivetrain",
    calls={"limits": Call(limits, ("traction_force_max_n", "regen_force_max_n")),
           "power": Call(map_power, ("motor_power_w",))},
    params=MOTOR_PARAMS,
    tables=(LOSS_MAP,),
    drivers=("speed_mps", "motor_force_n"),
    refines="constant_efficiency",
    label="motor losses over torque and speed",
    doc=__doc__,
))

constant_efficiency = register(Effect(
    name="constant_efficiency",
    slot="drivetrain",
    calls={"limits": Call(limits, ("traction_force_max_n", "regen_force_max_n")),
           "power": Call(constant_power, ("motor_power_w",))},
    params=MOTOR_PARAMS + (
        Param("motor_efficiency", 0.90, "1", (0.5, 1.0),
              "Motor + inverter efficiency eta_m, motoring and generating",
              "TransitBus converter 0.97 x motor ~0.93"),
    ),
    drivers=("speed_mps", "motor_force_n"),
    doc=__doc__,
))
