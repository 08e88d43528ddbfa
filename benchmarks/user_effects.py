"""The effects a user writes for the truth bench's loads and forces the library does not have.

On a day whose diagnosis says "no library effect explains it", a transit engineer who knows the
bus writes the load in the library's effect language and adds it (``ebus diagnose LOG --add
benchmarks/user_effects.py:pack_chiller``). These are that user's files: written from what such
a load does on any e-bus, with typical values for what the ladder does not fit, not from the
truth simulator's code or numbers; the ladder fits each one's power (``key_params``).
"""

from ebus_env import Param, State, effect

GRAVITY_MPS2 = 9.81


@effect("pack_chiller", sink="dc_load_w", label="pack chiller while fast charging",
        drivers=("charger_connected",), key_params=("power_w",), params=[
    Param("power_w", 5000.0, "W", (0.0, 20000.0),
          "Electric power of the chiller's compressor and pumps while the pack charges"),
])
def pack_chiller(charger_connected, power_w):
    """Fast charging heats the pack; its refrigerant chiller runs for the whole session:
    P = P_chiller while on the charger [W]."""
    return power_w if charger_connected >= 0.5 else 0.0


@effect("air_compressor", sink="dc_load_w", label="brake and door air compressor",
        drivers=("door_open", "speed_mps"), returns=("air_debt_s_next", "speed_before_mps_next"),
        key_params=("power_w",), params=[
    Param("power_w", 5000.0, "W", (0.0, 15000.0), "Electric power of the running compressor"),
    Param("run_per_open_s", 1.0, "s/s", (0.0, 5.0),
          "Compressor run time owed per second of open doors (doors, kneeling)"),
    Param("run_per_braked_mps", 1.0, "s/(m/s)", (0.0, 10.0),
          "Compressor run time owed per m/s of speed taken off by braking (brake chambers)"),
    Param("leak_duty", 0.02, "1", (0.0, 0.5), "Share of time the compressor runs for leaks"),
], states=[
    State("air_debt_s", "s", "Compressor run time still owed (< 0: run ahead)",
          lambda p, x: 0.0),
    State("speed_before_mps", "m/s", "Speed a step before", lambda p, x: 0.0),
])
def air_compressor(air_debt_s, speed_before_mps, door_open, speed_mps, dt_s, power_w,
                   run_per_open_s, run_per_braked_mps, leak_duty):
    """Doors, kneeling and brake applications use reservoir air; the governor then runs the
    compressor at P_c until it is made up::

        debt' = r_door door_open + r_brake max(-dv/dt, 0) + d_leak - running
        P = P_c while debt > 0 [W]

    A step that runs past what was owed leaves a credit (negative debt), so the run time
    equals what is owed however small each step's share of it.
    """
    running = 1.0 if air_debt_s > 0.0 else 0.0
    braked_mps = max(speed_before_mps - speed_mps, 0.0)
    debt = air_debt_s + (run_per_open_s * door_open + leak_duty - running) * dt_s \
        + run_per_braked_mps * braked_mps
    return running * power_w, debt, speed_mps


@effect("brake_drag", sink="road_force_n", label="dragging brake", drivers=("speed_mps",),
        key_params=("force_n",), params=[
    Param("force_n", 300.0, "N", (0.0, 3000.0), "Drag force of brake pads that do not release"),
])
def brake_drag(speed_mps, force_n):
    """Pads that rub on the disc while the bus rolls: F = F_drag for v > 0, else 0 [N]."""
    return force_n if speed_mps > 0.0 else 0.0


@effect("soft_tyres", sink="road_force_n", label="under-inflated tyres",
        drivers=("mass_kg", "speed_mps"), key_params=("extra_rolling_coef",), params=[
    Param("extra_rolling_coef", 0.001, "1", (0.0, 0.01),
          "Rolling-resistance coefficient the tyres add below their pressure"),
])
def soft_tyres(speed_mps, mass_kg, extra_rolling_coef):
    """Tyres below their pressure flex more and roll harder: F = m g dC_rr for v > 0 [N]."""
    return mass_kg * GRAVITY_MPS2 * extra_rolling_coef if speed_mps > 0.0 else 0.0
