"""Shipped King County routes driven as cycles: distance, limits, stops and grade."""

import numpy as np
import pytest

from ebus_env.errors import EbusError
from ebus_env.routes import load_route


@pytest.fixture(scope="module")
def route():
    return load_route("kc45_out")


def test_route_cycle_covers_the_route_within_the_limits(route):
    cycle = route.cycle(dwell_s=20.0)
    v = cycle.speed_kmh / 3.6
    distance_m = float(np.sum(0.5 * (v[1:] + v[:-1]) * np.diff(cycle.time_s)))
    assert distance_m == pytest.approx(route.length_m, rel=0.01)
    assert cycle.speed_kmh.max() <= route.speed_limit_kmh.max() + 1e-6
    # the bus accelerates no harder than planned (1 m/s^2, sampled at 1 s)
    assert np.max(np.diff(v)) <= 1.0 + 1e-6
    # it stands at the stops: at least 20 s per stop that is not a duplicate point
    standing_s = float(np.sum(cycle.speed_kmh < 0.1))
    assert standing_s >= 20.0 * 0.8 * len(np.unique(np.round(route.stops_m, -1)))


def test_route_grade_integrates_to_the_climb(route):
    cycle = route.cycle()
    v = cycle.speed_kmh / 3.6
    dist = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(cycle.time_s))])
    climb_m = float(np.sum(np.diff(dist) * cycle.grade_frac[1:]))
    # grade from smoothed elevation: end-to-end height difference is kept
    assert climb_m == pytest.approx(route.elevation_m[-1] - route.elevation_m[0], abs=5.0)
    alt = route.altitude_along(cycle)
    assert alt[0] == pytest.approx(route.elevation_m[0]) and abs(alt[-1] - route.elevation_m[-1]) < 2


def test_unknown_route_names_the_choices():
    with pytest.raises(EbusError, match="kc45_out"):
        load_route("kc99")
