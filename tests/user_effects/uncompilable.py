"""A user effect numba cannot compile: it calls a plain Python function (no @helper)."""

from ebus_env import Param, effect


def drag_of(coef_n_per_mps, speed_mps):
    return coef_n_per_mps * speed_mps


@effect("linear_drag", sink="road_force_n", drivers=("speed_mps",), params=[
    Param("coef_n_per_mps", 10.0, "N s/m", (0.0, 100.0), "Drag per speed k"),
])
def linear_drag(speed_mps, coef_n_per_mps):
    """F = k v [N], through a helper that lacks the @helper decorator."""
    return drag_of(coef_n_per_mps, speed_mps)
