"""My effects: the air compressor of a bus's doors and kneeling system."""

from ebus_env import Param, State, effect


@effect("door_compressor", sink="dc_load_w", label="door and kneeling air compressor",
        drivers=("door_open",), returns=("air_debt_s_next",), params=[
    Param("power_w", 2500.0, "W", (0.0, 10000.0), "Electric power of the running compressor"),
    Param("run_per_open_s", 1.5, "s/s", (0.0, 5.0),
          "Compressor run time owed per second of open doors"),
], states=[State("air_debt_s", "s", "Compressor run time still owed", lambda p, x: 0.0)])
def door_compressor(air_debt_s, door_open, dt_s, power_w, run_per_open_s):
    """Open doors and kneeling use air; the compressor then runs at P_c until it is made up:
    debt' = r door_open - running,  P = P_c while debt > 0 [W]."""
    running = 1.0 if air_debt_s > 0.0 else 0.0
    debt = air_debt_s + (run_per_open_s * door_open - running) * dt_s
    return running * power_w, max(debt, 0.0)
