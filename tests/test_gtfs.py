"""The GTFS loader on made-up feeds that hold GTFS's awkward corners: times past 24:00, no
block_id, frequencies.txt, calendar exceptions, non-timepoint stops, distances in km, shapes
that do not match their stops, trips without stop times, missing files, overlapping
layovers."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest

from ebus_env.blocks import Charger
from ebus_env.errors import ConfigError
from ebus_env.gtfs import read_network_day

# three stops along a street, 1 km apart (0.009 deg of latitude is about 1 km)
STOPS = [("A", 47.600, -122.3), ("M", 47.609, -122.3), ("B", 47.618, -122.3),
         ("C", 47.700, -122.3)]


def write_feed(folder, trips, times, shapes=None, freqs=None, dates=None, calendar=True):
    """A feed folder: ``trips`` (route, service, trip, block, shape), ``times`` (trip, stop,
    arrival, departure, dist)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "agency.txt").write_text("agency_id,agency_name,agency_url,agency_timezone\n"
                                       "X,Test,http://x,UTC\n")
    (folder / "routes.txt").write_text("route_id,route_short_name,route_type\nR1,1,3\n"
                                       "R2,2,3\n")
    (folder / "stops.txt").write_text("stop_id,stop_name,stop_lat,stop_lon\n" + "".join(
        f"{s},{s},{lat},{lon}\n" for s, lat, lon in STOPS))
    (folder / "trips.txt").write_text("route_id,service_id,trip_id,block_id,shape_id\n" + "".join(
        ",".join(map(str, t)) + "\n" for t in trips))
    seq: dict = {}
    lines = []
    for trip, stop, arr, dep, dist in times:
        seq[trip] = seq.get(trip, 0) + 1
        lines.append(f"{trip},{arr},{dep},{stop},{seq[trip]},{dist}\n")
    (folder / "stop_times.txt").write_text(
        "trip_id,arrival_time,departure_time,stop_id,stop_sequence,shape_dist_traveled\n"
        + "".join(lines))
    if calendar:
        (folder / "calendar.txt").write_text(
            "service_id,monday,tuesday,wednesday,thursday,friday,saturday,sunday,start_date,"
            "end_date\nWK,1,1,1,1,1,0,0,20240101,20241231\n")
    if dates:
        (folder / "calendar_dates.txt").write_text(
            "service_id,date,exception_type\n" + "".join(f"{s},{d},{e}\n" for s, d, e in dates))
    if shapes:
        (folder / "shapes.txt").write_text(
            "shape_id,shape_pt_lat,shape_pt_lon,shape_pt_sequence\n" + "".join(
                f"{s},{lat},{lon},{i}\n" for i, (s, lat, lon) in enumerate(shapes)))
    if freqs:
        (folder / "frequencies.txt").write_text(
            "trip_id,start_time,end_time,headway_secs,exact_times\n" + "".join(
                ",".join(map(str, f)) + "\n" for f in freqs))
    return folder


def out_and_back(trip, start_h, block="", back=False, km=1.0):
    """A trip A -> M -> B (or back), 2 km in 8 min, distances in m (or km)."""
    stops = ["B", "M", "A"] if back else ["A", "M", "B"]
    t = [start_h * 3600 + k for k in (0, 240, 480)]
    return [(trip, s, _hms(x), _hms(x), d * km) for s, x, d in zip(stops, t, (0, 1000, 2000),
                                                                    strict=True)]


def _hms(t):
    return f"{int(t // 3600):02d}:{int(t % 3600 // 60):02d}:{int(t % 60):02d}"


def test_times_past_midnight_stay_on_the_service_day(tmp_path):
    feed = write_feed(tmp_path / "f", [("R1", "WK", "late", "b1", ""), ("R1", "WK", "early",
                                                                          "b1", "")],
                      out_and_back("early", 23.5) + out_and_back("late", 24.75, back=True))
    day = read_network_day(feed, "2024-03-12")
    (block,) = day.blocks
    assert [t.trip_id for t in block.trips] == ["early", "late"]
    assert block.trips[1].start_s == 24.75 * 3600  # 24:45:00, not 00:45 of another day
    assert block.profile().start_time_h == pytest.approx(23.5)


def test_trips_without_block_id_are_chained_with_a_minimum_layover(tmp_path):
    trips = [("R1", "WK", f"t{i}", "", "") for i in range(3)]
    times = (out_and_back("t0", 6.0) + out_and_back("t1", 6.2, back=True)  # 4 min layover
             + out_and_back("t2", 6.05, back=True))  # starts before t0 ends: another bus
    day = read_network_day(write_feed(tmp_path / "f", trips, times), "2024-03-12",
                           min_layover_s=180.0)
    chains = sorted([t.trip_id for t in b.trips] for b in day.blocks)
    assert chains == [["t0", "t1"], ["t2"]]
    assert "greedy" in day.scheduled
    day = read_network_day(write_feed(tmp_path / "g", trips, times), "2024-03-12",
                           min_layover_s=300.0)  # 4 min is too short now
    assert len(day.blocks) == 3


def test_a_trip_at_another_stop_gets_a_deadhead_when_there_is_time(tmp_path):
    times = out_and_back("t0", 6.0) + [("t1", s, _hms(7 * 3600 + k), _hms(7 * 3600 + k), d)
                                       for s, k, d in (("C", 0, 0), ("B", 600, 9000))]
    trips = [("R1", "WK", "t0", "", ""), ("R1", "WK", "t1", "", "")]
    (block,) = read_network_day(write_feed(tmp_path / "f", trips, times), "2024-03-12").blocks
    kinds = [(t.trip_id, t.revenue) for t in block.trips]
    assert kinds == [("t0", True), ("deadhead B->C", False), ("t1", True)]
    dead = block.trips[1]
    assert dead.passengers == 0.0 and dead.distance_m > 9000.0  # 9 km straight x detour
    assert not block.problems()


def test_frequencies_expand_into_departures(tmp_path):
    feed = write_feed(tmp_path / "f", [("R1", "WK", "f1", "", "")], out_and_back("f1", 6.0),
                      freqs=[("f1", "06:00:00", "07:00:00", 900, 1)])
    day = read_network_day(feed, "2024-03-12")
    starts = sorted(t.start_s for b in day.blocks for t in b.trips if t.revenue)
    assert starts == [6 * 3600 + 900 * k for k in range(4)]  # 06:00, 06:15, 06:30, 06:45
    assert any("frequencies.txt" in n for n in day.notes)


def test_calendar_exceptions_remove_and_add_services(tmp_path):
    trips = [("R1", "WK", "wk", "", ""), ("R2", "HOL", "hol", "", "")]
    feed = write_feed(tmp_path / "f", trips, out_and_back("wk", 6) + out_and_back("hol", 7),
                      dates=[("WK", 20240704, 2), ("HOL", 20240704, 1)])
    workday = read_network_day(feed, "2024-07-03")
    holiday = read_network_day(feed, "2024-07-04")
    assert [t.trip_id for b in workday.blocks for t in b.trips] == ["wk"]
    assert [t.trip_id for b in holiday.blocks for t in b.trips] == ["hol"]
    with pytest.raises(ConfigError, match="no service runs on 2024-07-06"):
        read_network_day(feed, "2024-07-06")  # a Saturday


def test_stops_without_times_are_interpolated_by_distance(tmp_path):
    times = out_and_back("t0", 6.0)
    times[1] = ("t0", "M", "", "", 500)  # not a timepoint, a quarter of the way
    day = read_network_day(write_feed(tmp_path / "f", [("R1", "WK", "t0", "", "")], times),
                           "2024-03-12")
    mid = day.blocks[0].trips[0].stops[1]
    assert mid.arrival_s == pytest.approx(6 * 3600 + 480 * 500 / 2000)
    assert any("interpolated" in n for n in day.notes)


def test_shape_distances_in_km_are_recognised(tmp_path):
    feed = write_feed(tmp_path / "f", [("R1", "WK", "t0", "", "")],
                      out_and_back("t0", 6.0, km=0.001))
    day = read_network_day(feed, "2024-03-12")
    assert day.blocks[0].trips[0].distance_m == pytest.approx(2000.0)
    assert any("read in km" in n for n in day.notes)


def test_a_shape_that_misses_its_stops_is_said_and_replaced_by_the_stops(tmp_path):
    times = [(trip, s, a, d, "") for trip, s, a, d, _ in out_and_back("t0", 6.0)]
    far = [("S1", 47.6, -122.2), ("S1", 47.62, -122.2)]  # 7 km east of the stops
    near = [("S2", 47.6, -122.3), ("S2", 47.62, -122.3)]
    for shape, says in ((far, True), (near, False)):
        feed = write_feed(tmp_path / shape[0][0], [("R1", "WK", "t0", "", shape[0][0])], times,
                          shapes=shape)
        day = read_network_day(feed, "2024-03-12")
        assert any("does not match" in n for n in day.notes) == says
        assert day.blocks[0].trips[0].distance_m == pytest.approx(2000.0, rel=0.01)


def test_trips_without_stop_times_are_listed_not_driven(tmp_path):
    trips = [("R1", "WK", "t0", "", ""), ("R1", "WK", "ghost", "", "")]
    day = read_network_day(write_feed(tmp_path / "f", trips, out_and_back("t0", 6.0)),
                           "2024-03-12")
    assert "ghost" in day.trips_not_served and day.trips == 1
    assert any("no stop times" in n for n in day.notes)


def test_a_block_whose_layovers_overlap_is_reported_not_driven(tmp_path):
    trips = [("R1", "WK", "t0", "b1", ""), ("R1", "WK", "t1", "b1", "")]
    times = out_and_back("t0", 6.0) + out_and_back("t1", 6.05, back=True)
    day = read_network_day(write_feed(tmp_path / "f", trips, times), "2024-03-12")
    assert day.blocks == [] and "overlap" in day.not_driven["b1"]
    assert set(day.trips_not_served) == {"t0", "t1"}


def test_mixed_blocks_are_electrified_whole_or_reported(tmp_path):
    trips = [("R1", "WK", "t0", "b1", ""), ("R2", "WK", "t1", "b1", "")]
    times = out_and_back("t0", 6.0) + out_and_back("t1", 6.5, back=True)
    feed = write_feed(tmp_path / "f", trips, times)
    whole = read_network_day(feed, "2024-03-12", routes=["1"])
    assert [t.route for t in whole.blocks[0].trips] == ["1", "2"]
    report = read_network_day(feed, "2024-03-12", routes=["1"], mixed_blocks="report")
    assert report.blocks == [] and "mixes" in report.not_driven["b1"]
    with pytest.raises(ConfigError, match=r"routes \['9'\] run no trip"):
        read_network_day(feed, "2024-03-12", routes=["9"])


def test_missing_files_and_a_zip_feed(tmp_path):
    feed = write_feed(tmp_path / "f", [("R1", "WK", "t0", "", "")], out_and_back("t0", 6.0),
                      calendar=False)
    with pytest.raises(ConfigError, match="calendar.txt or calendar_dates.txt"):
        read_network_day(feed, "2024-03-12")
    (tmp_path / "f" / "stop_times.txt").unlink()
    with pytest.raises(ConfigError, match="lacks stop_times.txt"):
        read_network_day(feed, "2024-03-12")
    with pytest.raises(ConfigError, match="does not exist"):
        read_network_day(tmp_path / "nothing.zip", "2024-03-12")
    ok = write_feed(tmp_path / "g", [("R1", "WK", "t0", "", "")], out_and_back("t0", 6.0))
    with zipfile.ZipFile(tmp_path / "g.zip", "w") as z:
        for p in ok.iterdir():
            z.write(p, p.name)
    assert read_network_day(tmp_path / "g.zip", "2024-03-12").trips == 1


def test_altitude_gives_grade_and_its_absence_is_said(tmp_path):
    feed = write_feed(tmp_path / "f", [("R1", "WK", "t0", "", "S1")], out_and_back("t0", 6.0),
                      shapes=[("S1", 47.6, -122.3), ("S1", 47.618, -122.3)])
    flat = read_network_day(feed, "2024-03-12")
    assert flat.flat_trips == 1 and any("grade zero" in n for n in flat.notes)
    alt = tmp_path / "alt.csv"
    alt.write_text("shape_id,shape_dist_traveled,altitude_m\n" + "".join(
        f"S1,{x},{10 + 0.02 * x}\n" for x in range(0, 2001, 50)))
    hill = read_network_day(feed, "2024-03-12", altitude=alt,
                            chargers={"B": Charger(1, 300.0)})
    rows = hill.blocks[0].profile().channel("grade_frac")
    moving = hill.blocks[0].profile().channel("speed_ref_mps") > 1.0
    assert hill.flat_trips == 0
    assert np.median(rows[moving]) == pytest.approx(40 / 2000, rel=0.05)  # 2 % up
    bad = tmp_path / "bad.csv"
    bad.write_text("shape_id,altitude_m\nS1,3\n")
    with pytest.raises(ConfigError, match="lacks the column"):
        read_network_day(feed, "2024-03-12", altitude=bad)


@pytest.mark.slow
def test_the_shipped_example_feed_is_what_its_builder_writes():
    """data/gtfs is regenerated by python -m ebus_env.gtfs.example_feed: no hand edits."""
    from ebus_env import paths
    from ebus_env.gtfs.example_feed import ALTITUDE, FEED, SPEED_LIMITS, build

    files = build()
    with zipfile.ZipFile(paths.data("gtfs", FEED)) as z:
        shipped = {n: z.read(n).decode() for n in z.namelist()}
    assert shipped == {n: t for n, t in files.items() if n.endswith(".txt")}
    for name in (ALTITUDE, SPEED_LIMITS):
        assert paths.data("gtfs", name).read_text() == files[name]
    day = read_network_day(paths.data("gtfs", FEED), "2024-03-12")
    routes = {t.route for b in day.blocks for t in b.trips}
    assert routes == {"45", "7", "44"} and day.trips > 300
    assert max(b.end_s for b in day.blocks) > 86400.0  # the last trips run past midnight
