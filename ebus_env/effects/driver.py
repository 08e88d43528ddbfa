"""Forward-facing driver: PI tracking of the reference speed."""

from __future__ import annotations

from ebus_env.effects.base import Param, State, effect


@effect("pi_driver", slot="driver", returns=("driver_integral_m_next",), params=[
    Param("kp_per_s", 1.5, "1/s", (0.1, 10.0), "Proportional gain K_p on the speed error"),
    Param("ki_per_s2", 0.3, "1/s^2", (0.0, 5.0), "Integral gain K_i on the distance error"),
    Param("integral_limit_m", 2.0, "m", (0.0, 50.0),
          "Clamp of the integral (distance) error, so an infeasible stretch does not wind up"),
], states=[
    State("driver_integral_m", "m", "Integral of the speed error (distance behind, clamped)",
          lambda p, x: 0.0),
])
def pi_driver(speed_ref_mps: float, accel_ref_mps2: float, speed_mps: float, max_speed_mps: float,
              effective_mass_kg: float, road_force_n: float, driver_integral_m: float, dt_s: float,
              kp_per_s: float, ki_per_s2: float, integral_limit_m: float) -> tuple[float, float]:
    """Wheel force the driver asks for to follow the reference speed.

    The target is the reference capped at the vehicle's top speed. With the reference
    acceleration a_ff as feed-forward and the road load F_road compensated::

        e  = v_target - v
        E  = clip(E + e dt, -E_max, E_max)
        a  = min(a_ff + K_p e + K_i E, (v_max - v) / dt)      (speed governor)
        F  = m_eff a + F_road

    Standing with a zero target, the driver holds the bus on the brakes (F = 0, E reset).
    The motor and brake limits are applied afterwards by the model; when they bind, the bus
    falls behind the reference and ``distance_behind_m`` in the trace says by how much.
    """
    v_target = min(speed_ref_mps, max_speed_mps)
    v_target_next = min(speed_ref_mps + accel_ref_mps2 * dt_s, max_speed_mps)
    if v_target <= 0.0 and v_target_next <= 0.0 and speed_mps <= 0.01:
        return 0.0, 0.0
    accel_ff = (v_target_next - v_target) * (1.0 / dt_s)
    error = v_target - speed_mps
    integral = driver_integral_m + error * dt_s
    if integral > integral_limit_m:
        integral = integral_limit_m
    elif integral < -integral_limit_m:
        integral = -integral_limit_m
    accel_cmd = accel_ff + kp_per_s * error + ki_per_s2 * integral
    # the speed governor: never past the top speed, even when catching up
    accel_cmd = min(accel_cmd, (max_speed_mps - speed_mps) * (1.0 / dt_s))
    return effective_mass_kg * accel_cmd + road_force_n, integral
