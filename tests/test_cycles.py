"""Shipped cycles and the service-day generator."""

from __future__ import annotations

import numpy as np
import pytest

from ebus_env.config import Service
from ebus_env.cycles import CYCLES, load_cycle, service_day
from ebus_env.errors import ConfigError
from tests.conftest import DT


@pytest.mark.parametrize("name,metres,mean_kmh", [("sort1", 520, 12.6), ("sort2", 920, 18.6),
                                                   ("sort3", 1450, 26.3)])
def test_sort_cycles_match_the_published_lengths(name, metres, mean_kmh):
    cycle = load_cycle(name)
    assert cycle.distance_km * 1000 == pytest.approx(metres, rel=0.03)
    # SORT 3's published mean speed depends on an uncertain stop time (docs/physics.md §8.1)
    assert cycle.mean_speed_kmh == pytest.approx(mean_kmh, rel=0.03 if name != "sort3" else 0.15)


def test_every_shipped_cycle_loads():
    for name in CYCLES:
        cycle = load_cycle(name)
        assert cycle.time_s[0] == 0 and np.all(np.diff(cycle.time_s) > 0)
        assert np.all(cycle.speed_kmh >= 0) and cycle.distance_km > 0.5
    composite = load_cycle("sort123")
    parts = sum(load_cycle(n).distance_km for n in ("sort1", "sort2", "sort3"))
    assert composite.distance_km == pytest.approx(parts)
    assert load_cycle("vecto_urban_13m").grade_frac is not None
    assert any("prepended" in n for n in load_cycle("london").notes)


def test_bad_cycle_file(tmp_path):
    path = tmp_path / "c.csv"
    path.write_text("time_s,speed_kmh\n0,0\n1,\n2,3\n")
    with pytest.raises(ConfigError, match="'speed_kmh' has missing"):
        load_cycle(str(path))


def test_a_cycle_cut_from_a_longer_record_starts_at_its_own_start(tmp_path):
    path = tmp_path / "cut.csv"
    path.write_text("time_s,speed_kmh\n3600,30\n3601,30\n3602,30\n3700,30\n3710,0\n3720,0\n")
    cycle = load_cycle(str(path))
    assert cycle.time_s.tolist() == [0, 1, 2, 100, 110, 120]
    assert cycle.duration_s == 120 and cycle.distance_km < 1.0  # not an hour at 30 km/h
    assert any("time starts at 3600 s; shifted" in n for n in cycle.notes)


def test_service_day_layovers_and_length():
    service = Service(layover_every_min=30, layover_min=5, layover_charger_kw=300)
    day = service_day("sort2", 4.0, DT, service, ambient_degc=-3.0)
    assert day.n_steps == int(4 * 3600 / DT)
    connected = day.channels["charger_connected"]
    starts = np.flatnonzero(np.diff(connected) > 0)
    assert 6 <= len(starts) <= 7  # about every 35 min (30 min driving + 5 min layover)
    assert np.all(day.channels["charger_rating_w"][connected > 0] == 300e3)
    assert np.all(day.channels["speed_ref_mps"][connected > 0] == 0)
    assert np.all(day.channels["ambient_degc"] == -3.0)
    assert day.channel("time_of_day_h")[0] == service.start_time_h


def test_scaling_to_a_mean_speed():
    cycle = load_cycle("sort2")
    fast = cycle.scaled(25.0)
    assert fast.mean_speed_kmh == pytest.approx(25.0)
    assert fast.duration_s == cycle.duration_s
    day = service_day(cycle, 1.0, DT, Service(charge_at_layovers=False, layover_min=0),
                      mean_speed_kmh=25.0)
    assert day.distance_m / 1000 == pytest.approx(25.0, rel=0.01)


def test_passenger_profile_over_the_day():
    service = Service(start_time_h=6.0, passenger_profile={6: 10, 8: 80, 10: 20})
    day = service_day("sort2", 4.0, DT, service)
    pax = day.channels["passenger_count"]
    clock = day.channel("time_of_day_h")
    assert pax[0] == 10 and pax[np.argmin(np.abs(clock - 8.0))] == pytest.approx(80, abs=0.1)
    assert pax[np.argmin(np.abs(clock - 9.0))] == pytest.approx(50, abs=0.1)
