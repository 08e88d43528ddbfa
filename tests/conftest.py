"""Shared fixtures: bus configs, built models (compiled once per session) and profiles."""

from __future__ import annotations

import numpy as np
import pytest

from ebus_env.config import load_bus
from ebus_env.cycles import service_day
from ebus_env.profile import Profile

DT = 0.1


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Run the modules that hold slow tests first, those with most of them first, each module's
    tests together and in their order: two workers then share the long tests from the start,
    and the suite ends on short ones, not on one worker's long tail."""
    def module(item: pytest.Item) -> str:
        return item.nodeid.split("::")[0]

    slow: dict[str, int] = {}
    for item in items:
        slow[module(item)] = slow.get(module(item), 0) + bool(item.get_closest_marker("slow"))
    items.sort(key=lambda item: -slow[module(item)])  # stable: keeps the order within


def constant_profile(speed_mps: float, seconds: float, dt_s: float = DT, **channels) -> Profile:
    """Accelerate smoothly to ``speed_mps`` (1 m/s^2), then hold it."""
    n = int(round(seconds / dt_s))
    t = np.arange(n) * dt_s
    v = np.minimum(t * 1.0, speed_mps)
    data = {"speed_ref_mps": v}
    for name, value in channels.items():
        data[name] = np.broadcast_to(np.asarray(value, float), (n,)).copy()
    return Profile(data, dt_s, f"{speed_mps} m/s")


def standing_profile(seconds: float, dt_s: float = DT, **channels) -> Profile:
    n = int(round(seconds / dt_s))
    data = {"speed_ref_mps": np.zeros(n)}
    for name, value in channels.items():
        data[name] = np.broadcast_to(np.asarray(value, float), (n,)).copy()
    return Profile(data, dt_s, "standing")


@pytest.fixture(scope="session")
def bus12():
    return load_bus("12m")


@pytest.fixture(scope="session")
def bus18():
    return load_bus("18m")


@pytest.fixture(scope="session")
def model12(bus12):
    model = bus12.build()
    model.compile()
    return model


@pytest.fixture(scope="session")
def model12_nohvac(bus12):
    return bus12.without_effect("cabin_hvac").build()


@pytest.fixture(scope="session")
def sort2_day(bus12):
    return service_day("sort2", 13.5, DT, bus12.service)


@pytest.fixture(scope="session")
def sort2_hour(bus12):
    return service_day("sort2", 1.0, DT, bus12.service)
