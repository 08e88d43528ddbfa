"""User effects that return what their sink does not take: numba fails in the generated loop,
on no line of theirs."""

from ebus_env import Param, State, effect

POWER = [Param("power_w", 1000.0, "W", (0.0, 10000.0), "Electric power")]


@effect("two_values", sink="dc_load_w", params=POWER)
def two_values(power_w, speed_mps):
    return power_w, speed_mps


@effect("text_value", sink="dc_load_w", params=POWER)
def text_value(power_w):
    return "power"


@effect("forgotten_state", sink="dc_load_w", params=POWER, returns=("run_s_next",),
        states=[State("run_s", "s", "Time run", lambda p, x: 0.0)])
def forgotten_state(run_s, power_w):
    return power_w


@effect("divides_by_zero", sink="dc_load_w", params=POWER)
def divides_by_zero(power_w, speed_mps):
    return power_w / (speed_mps - speed_mps)
