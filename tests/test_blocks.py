"""Blocks: the hand-written form, the driver model meeting a timetable, the charger rows."""

from __future__ import annotations

import numpy as np
import pytest

from ebus_env.blocks import (
    Block,
    Charger,
    StopTime,
    Trip,
    blocks_from_dict,
    clock,
    drive_rows,
    plan,
    seconds,
)
from ebus_env.errors import ConfigError

HAND = {"blocks": [{"block_id": "45-1", "chargers": {"kc45_A": {"count": 1, "power_kw": 300}},
                    "depot": {"count": 2, "power_kw": 100},
                    "trips": [{"trip_id": "t1", "cycle": "kc45_out", "start": "23:10"},
                              {"trip_id": "t2", "cycle": "kc45_back", "start": "24:05"}]}]}


def timetable_trip(times_s, distances_m, trip_id="g1", start_stop="A", end_stop="B"):
    stops = tuple(StopTime(f"S{i}", t, t, d) for i, (t, d) in enumerate(
        zip(times_s, distances_m, strict=True)))
    return Trip(trip_id, "R", times_s[0], times_s[-1], start_stop, end_stop,
                distances_m[-1] - distances_m[0], stops)


def test_times_past_midnight_and_the_clock_round_trip():
    assert seconds("25:05:30", "x") == 25 * 3600 + 5 * 60 + 30
    assert seconds("06:00", "x") == 6 * 3600
    assert clock(seconds("26:59:59", "x")) == "26:59:59"
    with pytest.raises(ConfigError, match="HH:MM"):
        seconds("6h", "trips[0].start")


def test_a_hand_written_block_runs_past_midnight_and_charges_at_its_terminal():
    (block,) = blocks_from_dict(HAND)
    assert block.trips[1].start_s > 86400.0  # 24:05
    (lay,) = block.layovers()
    assert lay.stop_id == "kc45_B" and lay.charger is None  # the charger is at kc45_A
    p = block.profile()
    assert p.start_time_h == pytest.approx(23 + 10 / 60)
    assert p.distance_m == pytest.approx(block.distance_m, rel=0.01)
    assert p.channel("charger_connected").sum() == 0.0  # no layover at kc45_A
    # the same block turning at kc45_B with a charger there: connected only on that layover
    charged = Block("c", block.trips, {"kc45_B": Charger(1, 300.0)})
    rows = charged.profile().channel("charger_connected")
    t = charged.start_s + 0.1 * np.arange(len(rows))
    assert rows.sum() > 0 and set(np.unique(rows)) == {0.0, 1.0}
    assert (t[rows > 0] >= lay.start_s).all() and (t[rows > 0] < lay.end_s).all()


def test_overlapping_layovers_and_missing_deadheads_are_reported_not_driven():
    data = {"blocks": [{"block_id": "x", "trips": [
        {"trip_id": "a", "cycle": "kc45_out", "start": "06:00"},
        {"trip_id": "b", "cycle": "kc45_back", "start": "06:10"},
        {"trip_id": "c", "cycle": "sort2", "start": "09:00", "start_stop": "elsewhere"}]}]}
    (block,) = blocks_from_dict(data)
    problems = block.problems()
    assert any("overlap" in p and "trip b" in p for p in problems)
    assert any("no deadhead" in p and "trip c" in p for p in problems)
    with pytest.raises(ConfigError, match="overlap"):
        block.profile()


def test_a_bad_hand_written_trip_names_its_place():
    with pytest.raises(ConfigError, match=r"blocks\[0\]\.trips\[0\]: missing 'start'"):
        blocks_from_dict({"blocks": [{"trips": [{"trip_id": "a", "cycle": "sort2"}]}]})
    with pytest.raises(ConfigError, match=r"trips\[0\]: ends at"):
        blocks_from_dict({"blocks": [{"trips": [{"trip_id": "a", "cycle": "kc45_out",
                                                 "start": "06:00", "end": "06:05"}]}]})


def test_the_driver_meets_a_feasible_timetable_at_every_stop():
    times = [6 * 3600.0, 6 * 3600 + 90.0, 6 * 3600 + 200.0, 6 * 3600 + 330.0]
    dists = [0.0, 400.0, 900.0, 1500.0]
    block = Block("g", (timetable_trip(times, dists),))
    rows = drive_rows(block, 0, int(round((times[-1] - times[0]) / 0.1)) + 1, 0.1)
    t = times[0] + 0.1 * np.arange(len(rows["speed_ref_mps"]))
    for when, where in zip(times[1:], dists[1:], strict=True):
        i = int(round((when - times[0]) / 0.1))
        assert rows["distance_m"][i] == pytest.approx(where, abs=1.0)  # there on time
        assert rows["speed_ref_mps"][i] == 0.0
    # distance from speed matches the stop spacing (the trapezoids are consistent)
    assert np.sum(rows["speed_ref_mps"]) * 0.1 == pytest.approx(1500.0, rel=2e-3)
    assert rows["speed_ref_mps"].max() <= 50 / 3.6 + 1e-9
    assert plan(block).late_s <= 1e-6
    assert (np.diff(rows["speed_ref_mps"]) / 0.1 <= 1.0 + 1e-6).all()  # the driver's a
    assert t[-1] == pytest.approx(times[-1])


def test_a_timetable_too_tight_for_the_speed_limit_runs_late_and_says_so():
    times = [0.0, 30.0]  # 1 km in 30 s: 120 km/h
    block = Block("g", (Trip("g1", "R", 0.0, 30.0, "A", "B", 1000.0,
                             (StopTime("A", 0, 0, 0), StopTime("B", 30, 30, 1000.0)),
                             speed_limit=(np.array([0.0, 1000.0]), np.array([40.0, 40.0]))),))
    p = plan(block)
    assert p.v.max() == pytest.approx(40 / 3.6)
    assert p.late_s > 60.0  # about 1000 m / 11 m/s + the ramps - 30 s
    assert times[1] < p.t0[0] + p.t_acc[0] + p.t_cruise[0] + p.t_dec[0]


def test_charging_on_a_layover_raises_the_soc_the_model_predicts():
    from ebus_env import load_bus

    (block,) = blocks_from_dict(HAND)
    model = load_bus("12m").build()
    plain = model.simulate(block.profile(), soc_start=0.8, record=False).final_state
    charged = Block("c", block.trips, {"kc45_B": Charger(1, 300.0)})
    more = model.simulate(charged.profile(), soc_start=0.8, record=False).final_state
    soc = model.state_names.index("soc_frac")
    assert more[soc] > plain[soc] + 0.01


def test_a_gtfs_like_block_round_trips_through_the_hand_written_form(tmp_path):
    import json

    from ebus_env.blocks import blocks_to_dict, load_blocks

    times = [6 * 3600.0, 6 * 3600 + 90.0, 6 * 3600 + 200.0]
    trip = Trip("g1", "R", times[0], times[-1], "S0", "S2", 900.0,
                tuple(StopTime(f"S{i}", t, t + (30 if i == 1 else 0), d) for i, (t, d) in
                      enumerate(zip(times, (0.0, 400.0, 900.0), strict=True))),
                altitude=(np.array([0.0, 900.0]), np.array([10.0, 28.0])))
    (hand,) = blocks_from_dict(HAND)
    blocks = [Block("g", (trip,), {"S2": Charger(2, 150.0)}, Charger(4, 100.0)), hand]
    path = tmp_path / "blocks.json"
    path.write_text(json.dumps(blocks_to_dict(blocks)))
    again = load_blocks(path)
    assert blocks_to_dict(again) == blocks_to_dict(blocks)
    for a, b in zip(blocks, again, strict=True):
        np.testing.assert_array_equal(a.profile().stacked(("speed_ref_mps", "grade_frac")),
                                      b.profile().stacked(("speed_ref_mps", "grade_frac")))
    with pytest.raises(ConfigError, match=r"stops\[1\]: give stop_id"):
        blocks_from_dict({"blocks": [{"trips": [{"trip_id": "x", "stops": [
            {"stop_id": "a", "arrival": "06:00", "distance_m": 0}, {"stop_id": "b"}]}]}]})
