"""An out-of-tree effect, as a user writes one: a steady headwind."""

from ebus_env import Param, effect


@effect("headwind", sink="road_force_n", drivers=("speed_mps",), params=[
    Param("wind_speed_mps", 4.0, "m/s", (0.0, 15.0), "Mean headwind speed w"),
    Param("cda_m2", 5.25, "m^2", (1.0, 10.0), "Drag area c_d A"),
])
def headwind(speed_mps, wind_speed_mps, cda_m2):
    """Extra drag of a headwind on a moving bus: F = 1/2 rho c_d A ((v + w)^2 - v^2) [N]."""
    if speed_mps <= 0.0:
        return 0.0
    return 0.5 * 1.2 * cda_m2 * ((speed_mps + wind_speed_mps) ** 2 - speed_mps**2)
