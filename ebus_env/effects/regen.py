"""Regenerative braking: which share of the braking force the motor may take.

Both implementations blend in series up to a deceleration: the motor takes its share of the
braking force up to ``m a_regen`` (the deceleration the bus's brake controller lets the motor
give on its own), and the friction brakes take the rest: the series braking strategies
simulated for a hybrid bus by Sangtarash et al. (SAE 2008-01-1561), and what a production
system measured on a brake rig does (light braking regenerative only, harder braking blended
with friction: EuroBrake 2012, paper EB2012-TM-06). The default, 5 m/s^2, is the bus's
largest braking deceleration: no limit below the brakes' own.
"""

from __future__ import annotations

from ebus_env.effects.base import Param, effect, helper


@helper
def _blended(share: float, wheel_force_demand_n: float, road_force_n: float, effective_mass_kg: float,
             max_brake_decel_mps2: float, limit_n: float) -> float:
    """``share`` of the braking force, at most the force ``limit_n`` (series blending: the
    motor brakes alone up to ``m a_regen``). The braking force is the driver's demand within
    the brakes' largest deceleration, as the force allocation takes it, so that ``a_regen`` at
    that deceleration limits nothing."""
    braking_n = -max(wheel_force_demand_n, road_force_n - effective_mass_kg * max_brake_decel_mps2)
    if braking_n * share > limit_n:
        return limit_n / braking_n
    return share


@effect("regen_cutoff", slot="regen", label="regen cutoff at low speed", drivers=("speed_mps",), params=[
    Param("cutoff_speed_mps", 1.5, "m/s", (0.0, 5.0),
          "Speed below which regenerative braking is off, v_cut", "Hasan et al. 2023"),
    Param("max_share", 1.0, "1", (0.1, 1.0),
          "Largest share of the braking force the motor takes above v_cut (blending)",
          "Simple bus models recover 0.4-0.5 of braking energy (docs/physics.md §4.3)"),
    Param("max_decel_mps2", 5.0, "m/s^2", (0.3, 5.0),
          "Largest deceleration the motor brakes at alone: harder braking goes to the friction "
          "brakes (series blending)", "Sangtarash et al., SAE 2008-01-1561"),
])
def regen_cutoff(speed_mps: float, wheel_force_demand_n: float, road_force_n: float,
                 effective_mass_kg: float, max_brake_decel_mps2: float, cutoff_speed_mps: float,
                 max_share: float, max_decel_mps2: float) -> float:
    """Motor share of braking: ``max_share`` above the cutoff speed, 0 below it, and no more
    than the deceleration limit allows, ``share <= m a_regen / |F|`` (series blending).

    The motor's generating torque/power limits and the battery's charge acceptance cap the
    regenerative force further; the friction brakes take the rest.
    """
    if speed_mps <= cutoff_speed_mps:
        return 0.0
    return _blended(max_share, wheel_force_demand_n, road_force_n, effective_mass_kg,
                    max_brake_decel_mps2, effective_mass_kg * max_decel_mps2)


@effect("regen_soc_limit", slot="regen", label="regen derated at high SoC", drivers=("speed_mps", "soc_frac"),
        key_params=("derate_soc_pct",), refines="regen_cutoff", params=[
    Param("cutoff_speed_mps", 1.5, "m/s", (0.0, 5.0),
          "Speed below which regenerative braking is off, v_cut", "Hasan et al. 2023"),
    Param("max_share", 1.0, "1", (0.1, 1.0),
          "Largest share of the braking force the motor takes above v_cut"),
    Param("max_decel_mps2", 5.0, "m/s^2", (0.3, 5.0),
          "Largest deceleration the motor brakes at alone: harder braking goes to the friction "
          "brakes (series blending)", "Sangtarash et al., SAE 2008-01-1561"),
    Param("derate_soc_pct", 90.0, "%", (50.0, 99.9),
          "SoC above which the BMS derates the regenerative charge limit, reaching zero at 100 %"),
])
def regen_soc_limit(speed_mps: float, soc_frac: float, wheel_force_demand_n: float, road_force_n: float,
                    effective_mass_kg: float, max_brake_decel_mps2: float, regen_force_max_n: float,
                    cutoff_speed_mps: float, max_share: float, max_decel_mps2: float,
                    derate_soc_pct: float) -> float:
    """Regenerative braking with the cutoff speed and blending of ``regen_cutoff``, under a
    charge limit the BMS derates near a full pack. The limit falls linearly from the drive's
    own regenerative force F_gen (its torque and P_gen, ``regen_force_max_n``) at SoC_d to zero
    at 100 %::

        |F_motor| <= F_gen * min(1, (100 - SoC) / (100 - SoC_d))      (SoC in %)

    so light braking keeps its full share until the limit falls below it, and hard braking
    loses regeneration first."""
    if speed_mps <= cutoff_speed_mps:
        return 0.0
    headroom = min(1.0, max((100.0 - 100.0 * soc_frac) / (100.0 - derate_soc_pct), 0.0))
    return _blended(max_share, wheel_force_demand_n, road_force_n, effective_mass_kg,
                    max_brake_decel_mps2,
                    min(effective_mass_kg * max_decel_mps2, headroom * regen_force_max_n))
