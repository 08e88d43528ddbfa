"""Regenerative braking: which share of the braking force the motor may take."""

from __future__ import annotations

from ebus_env.effects.base import Param, effect


@effect("regen_cutoff", slot="regen", label="regen cutoff at low speed", drivers=("speed_mps",), params=[
    Param("cutoff_speed_mps", 1.5, "m/s", (0.0, 5.0),
          "Speed below which regenerative braking is off, v_cut", "Hasan et al. 2023"),
    Param("max_share", 1.0, "1", (0.1, 1.0),
          "Largest share of the braking force the motor takes above v_cut (blending)",
          "Simple bus models recover 0.4-0.5 of braking energy (docs/physics.md §4.3)"),
])
def regen_cutoff(speed_mps, cutoff_speed_mps, max_share):
    """Motor share of braking: ``max_share`` above the cutoff speed, 0 below it.

    The motor's generating torque/power limits and the battery's charge acceptance cap the
    regenerative force further; the friction brakes take the rest.
    """
    if speed_mps > cutoff_speed_mps:
        return max_share
    return 0.0


@effect("regen_soc_limit", slot="regen", label="regen derated at high SoC", drivers=("speed_mps", "soc_frac"),
        key_params=("derate_soc_pct",), refines="regen_cutoff", params=[
    Param("cutoff_speed_mps", 1.5, "m/s", (0.0, 5.0),
          "Speed below which regenerative braking is off, v_cut", "Hasan et al. 2023"),
    Param("max_share", 1.0, "1", (0.1, 1.0),
          "Largest share of the braking force the motor takes above v_cut"),
    Param("derate_soc_pct", 90.0, "%", (50.0, 99.9),
          "SoC above which the BMS derates regeneration, reaching zero at 100 %"),
])
def regen_soc_limit(speed_mps, soc_frac, cutoff_speed_mps, max_share, derate_soc_pct):
    """Regenerative braking with the cutoff speed of ``regen_cutoff``, derated by the BMS at
    high SoC: share = max_share * min(1, (100 - SoC) / (100 - SoC_derate)) (SoC in %)."""
    if speed_mps <= cutoff_speed_mps:
        return 0.0
    headroom = (100.0 - 100.0 * soc_frac) / (100.0 - derate_soc_pct)
    return max_share * min(1.0, max(headroom, 0.0))
