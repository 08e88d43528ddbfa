"""Road-load forces at the wheels: aerodynamic drag, rolling resistance, road grade.

Each returns a force [N] that resists motion (> 0) and is summed into ``road_force_n``.
Grade alpha comes from ``grade_frac`` = tan(alpha): sin(alpha) = g / sqrt(1 + g^2),
cos(alpha) = 1 / sqrt(1 + g^2).

Effects run in the compiled loop: divisions by values that do not change within a run are
written as multiplications by their reciprocal, which the compiler then computes once.
"""

from __future__ import annotations

import math

from ebus_env.effects.base import Param, effect
from ebus_env.units import GRAVITY_MPS2


@effect("aero_drag", sink="road_force_n", label="aerodynamic drag", drivers=("speed_mps",), params=[
    Param("drag_coef", 0.70, "1", (0.2, 1.0), "Drag coefficient c_d",
          "ADVISOR 0.79, sidrobus 0.6, TransitBus 0.65 (docs/physics.md §2.5)"),
    Param("frontal_area_m2", 7.5, "m^2", (1.0, 10.0), "Frontal area A",
          "ADVISOR RTS06 7.90, Orion VI 7.24 m^2"),
    Param("air_density_kg_per_m3", 1.2, "kg/m^3", (1.0, 1.4), "Air density rho", "ADVISOR 1.23"),
])
def aero_drag(speed_mps: float, drag_coef: float, frontal_area_m2: float,
              air_density_kg_per_m3: float) -> float:
    """Aerodynamic drag in still air: F = 1/2 rho c_d A v^2 [N]."""
    return 0.5 * air_density_kg_per_m3 * drag_coef * frontal_area_m2 * speed_mps * speed_mps


@effect("rolling_resistance", sink="road_force_n", label="rolling resistance",
        drivers=("mass_kg", "speed_mps"), params=[
    Param("rolling_coef", 0.008, "1", (0.003, 0.02), "Rolling-resistance coefficient C_rr",
          "ADVISOR 0.008 (Bosch); WVU 0.0094; SwRI 0.01"),
])
def rolling_resistance(speed_mps: float, mass_kg: float, grade_frac: float, rolling_coef: float) -> float:
    """Rolling resistance while moving: F = m g C_rr cos(alpha) [N] for v > 0, else 0
    (a standing bus is held by its brakes, not by rolling resistance)."""
    if speed_mps <= 0.0:
        return 0.0
    return mass_kg * GRAVITY_MPS2 * rolling_coef * (1.0 / math.sqrt(1.0 + grade_frac * grade_frac))


@effect("road_grade", sink="road_force_n", label="road grade", drivers=("grade_frac",))
def road_grade(mass_kg: float, grade_frac: float) -> float:
    """Weight component along the road: F = m g sin(alpha) [N] (> 0 uphill)."""
    return mass_kg * GRAVITY_MPS2 * grade_frac * (1.0 / math.sqrt(1.0 + grade_frac * grade_frac))
