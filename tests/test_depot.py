"""A depot's folder of CAN logger files: the logger-to-bus map, service days, bus-day logs,
and (slow) the fleet summary with each bus diagnosed over its days."""

from __future__ import annotations

import datetime

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("cantools")
pytest.importorskip("asammdf")
pytest.importorskip("can")

from ebus_env.depot.bus_days import split_depot  # noqa: E402
from ebus_env.depot.depot_run import action, run_depot  # noqa: E402
from ebus_env.depot.loggers import read_logger_map  # noqa: E402
from ebus_env.depot.sample_days import (  # noqa: E402
    DEPOT,
    LOGGERS_CSV,
    day_table,
    write_depot,
)
from ebus_env.depot.service_days import DayRule, service_days  # noqa: E402
from ebus_env.errors import ConfigError, LogError  # noqa: E402
from ebus_env.io.can_map import load_signal_map  # noqa: E402
from ebus_env.io.measured import load_log  # noqa: E402

BERLIN = load_signal_map("ebus_j1939").timezone
RESOLUTION = {"speed_kmh": 1 / 256, "soc_pct": 0.0025, "battery_current_a": 0.05,
              "battery_voltage_v": 0.05, "ambient_degc": 0.03125}


@pytest.fixture(scope="module")
def depot(tmp_path_factory):
    """The made-up depot: 4 loggers, 4 buses, 6 service days in 23 rolled files."""
    folder = tmp_path_factory.mktemp("depot") / "incoming"
    return folder, write_depot(folder)


@pytest.fixture(scope="module")
def split(depot, tmp_path_factory):
    folder, loggers = depot
    out = tmp_path_factory.mktemp("out")
    days = split_depot(folder, read_logger_map(loggers, BERLIN), load_signal_map("ebus_j1939"),
                       out)
    return days, out


def _map(tmp_path, text):
    path = tmp_path / "loggers.csv"
    path.write_text(text)
    return path


@pytest.mark.parametrize("text, match", [
    ("logger,bus_id,valid_from,valid_to\nL1,b1,2026-01-01,\n",
     "no column 'logger_id'. Did you mean 'logger'"),
    ("logger_id,bus_id,valid_from,valid_to\nL1,b1,2026-01-01,\nL1,b2,2026-01-10,\n",
     r"Rows 0 and 1 overlap in time: the logger is in two buses at once \(L1\)"),
    ("logger_id,bus_id,valid_from,valid_to\nL1,b1,2026-01-01,\nL2,b1,2026-01-05,2026-01-06\n",
     r"the bus has two loggers at once \(b1\)"),
    ("logger_id,bus_id,valid_from,valid_to\nL1,b1,2026-01-05,2026-01-05\n",
     r"valid_to \(2026-01-05\) is not after valid_from.*row 0"),
    ("logger_id,bus_id,valid_from,valid_to\nL1,b1,5th of May,\n",
     r"'5th of May' is not a date.*column 'valid_from', row 0"),
    ("logger_id,bus_id,valid_from,valid_to\nL1,,2026-01-01,\n", r"Empty cell.*column 'bus_id'"),
])
def test_a_wrong_logger_map_is_refused_naming_rows_and_fix(tmp_path, text, match):
    with pytest.raises(LogError, match=match):
        read_logger_map(_map(tmp_path, text))


def test_the_logger_map_reads_times_in_the_depots_zone(tmp_path):
    loggers = read_logger_map(_map(tmp_path, LOGGERS_CSV), BERLIN)
    moved = [i for i in loggers.of("L02")]
    assert [i.bus for i in moved] == ["bus-102", "bus-103"]
    berlin_20h = datetime.datetime(2026, 1, 14, 20, tzinfo=BERLIN).timestamp()
    assert moved[0].end_s == moved[1].start_s == berlin_20h
    assert moved[1].end_s == np.inf


def test_service_days_run_between_depot_stays():
    t = np.arange(0.0, 40 * 3600.0, 1.0)
    hour = t / 3600.0
    # service 6-12 and 13:30-20 (a 1.5 h break stays inside the day), the next day from 30 h;
    # standing (speed 0) otherwise
    moving = ((hour >= 6) & (hour < 12)) | ((hour >= 13.5) & (hour < 20)) | (hour >= 30)
    speed = np.where(moving & (t % 60 < 40), 20.0, 0.0)
    days = service_days(t, speed, DayRule(stay_h=2.0, margin_min=15.0))
    assert len(days) == 2
    (a0, b0), (a1, b1) = days
    assert a0 == pytest.approx(6 * 3600 - 900) and b0 == pytest.approx(20 * 3600 - 21 + 900,
                                                                      abs=1)
    assert a1 == pytest.approx(30 * 3600 - 900)
    # a 1.5 h stay with stay_h 1: two days
    assert len(service_days(t, speed, DayRule(stay_h=1.0, margin_min=15.0))) == 3
    assert service_days(t, np.zeros_like(t)) == []
    with pytest.raises(ConfigError, match="less than half a depot stay"):
        DayRule(stay_h=1.0, margin_min=40.0)


def test_the_depot_folder_becomes_one_canonical_log_per_bus_and_service_day(split):
    days, out = split
    found = sorted((d.bus, d.first) for d in days.days)
    assert found == [("bus-101", "2026-01-14T06:00:00+01:00"),
                     ("bus-101", "2026-01-15T06:30:00+01:00"),
                     ("bus-102", "2026-01-14T06:00:00+01:00"),  # logger L02
                     ("bus-102", "2026-01-15T06:00:00+01:00"),  # logger L03, BLF files
                     ("bus-103", "2026-01-15T07:00:00+01:00"),  # L02 after it moved
                     ("bus-104", "2026-01-14T22:30:00+01:00")]  # past midnight
    assert all(not f.problem for f in days.files) and len(days.files) == 23
    for k, planned in enumerate(DEPOT):
        day = next(d for d in days.days if d.bus == planned.bus and
                   d.first.startswith(planned.date))
        truth = day_table(planned.case, date=planned.date, start_h=planned.start_h,
                          hours=planned.hours, seed=k)
        written = pd.read_csv(day.path)
        assert written["timestamp"].tolist() == truth["timestamp"].tolist(), planned
        for column, step in RESOLUTION.items():
            assert np.abs(written[column] - truth[column]).max() <= step / 2 + 1e-6, column
    late = load_log(next(d.path for d in days.days if d.bus == "bus-104"))
    assert late.profile.date == datetime.date(2026, 1, 14)
    assert late.profile.duration_s == pytest.approx(2.5 * 3600, abs=1)  # 9000 rows
    counted = pd.DataFrame([f.row(days.files[0].path.parents[1], load_signal_map(
        "ebus_j1939")) for f in days.files])
    # the DM1 frames the DBC lacks: one a second, counted in each file
    assert counted["unknown_id_frames"].sum() == sum(int(d.hours * 3600) for d in DEPOT)


def test_a_file_that_spans_the_moment_a_logger_moved_is_cut_there(depot, tmp_path):
    folder, _ = depot
    moved = LOGGERS_CSV.replace("2026-01-14T20:00", "2026-01-14T07:00")
    days = split_depot(folder, read_logger_map(_map(tmp_path, moved), BERLIN),
                       load_signal_map("ebus_j1939"), tmp_path / "out")
    on_14th = {d.bus: d for d in days.days if d.first.startswith("2026-01-14")
               and d.bus in ("bus-102", "bus-103")}
    assert on_14th["bus-102"].first == "2026-01-14T06:00:00+01:00"
    assert on_14th["bus-102"].hours == pytest.approx(1.0)
    assert on_14th["bus-103"].first == "2026-01-14T07:00:00+01:00"
    split_files = [f for f in days.files if len(f.buses) == 2]
    assert [f.buses for f in split_files] == [["bus-102", "bus-103"]]


def test_files_of_unknown_loggers_and_times_outside_an_installation_are_listed(depot,
                                                                                 tmp_path):
    folder, _ = depot
    partial = "logger_id,bus_id,valid_from,valid_to\nL01,bus-101,2026-01-15,\n" \
              "L02,bus-102,2026-01-01,\n"
    days = split_depot(folder, read_logger_map(_map(tmp_path, partial), BERLIN),
                       load_signal_map("ebus_j1939"), tmp_path / "out")
    problems = {f.path.relative_to(folder).as_posix(): f.problem for f in days.files}
    assert "not in the logger map" in problems["L03/00000001.blf"]
    assert "frames outside every installation of logger L01" in problems["L01/00000001.mf4"]
    assert {d.bus for d in days.days} == {"bus-101", "bus-102"}
    assert [d.first[:10] for d in days.days if d.bus == "bus-101"] == ["2026-01-15"]


def test_a_depot_run_refuses_an_unknown_domain_before_reading_a_file(tmp_path):
    with pytest.raises(ConfigError, match="domain='windows'.*Fix: soc"):
        run_depot(tmp_path / "nowhere", tmp_path / "loggers.csv", tmp_path / "out",
                  domain="windows")


def test_action_from_the_diagnosis():
    assert action("ambient_battery", "voltage") == "workshop"
    assert action(None, "noise") == "ok"
    assert action(None, "outside library") == "watch"
    assert action(None, "a status of a later version") == "watch"
    assert action(None, "too few windows") == "no diagnosis"


def test_the_depot_command_without_diagnosis_writes_the_days_and_the_summary(depot, tmp_path):
    from typer.testing import CliRunner

    from ebus_env.cli import app

    folder, loggers = depot
    out = tmp_path / "report"
    result = CliRunner().invoke(app, ["depot", str(folder), "--map", str(loggers), "--out",
                                      str(out), "--no-diagnose"])
    assert result.exit_code == 0, result.output
    assert "4 buses, 6 service days from 23 files" in result.output
    summary = pd.read_csv(out / "summary.csv")
    assert summary["bus"].tolist() == ["bus-101", "bus-102", "bus-103", "bus-104"]
    assert set(summary["action"]) == {"no diagnosis"}
    assert (out / "index.html").read_text().count("bus-10") >= 4
    inside = CliRunner().invoke(app, ["depot", str(folder), "--map", str(loggers), "--out",
                                      str(folder / "report")])
    assert inside.exit_code == 2 and "inside the depot folder" in inside.output


@pytest.mark.slow
@pytest.mark.parametrize("domain", ["soc", "power"])
def test_a_depot_run_names_the_bus_with_a_cold_pack_for_the_workshop(tmp_path, domain):
    """Two buses over two service days each: bus-102's pack is cold (not thermally managed,
    parked outdoors at -4 degC), bus-101 has nothing wrong. The diagnosis of each bus over
    its days, in SoC windows or from the logged power second by second, sends bus-102 to the
    workshop, naming the pack, and bus-101 nowhere; each bus's report is written."""
    folder = tmp_path / "incoming"
    loggers = write_depot(folder, days=DEPOT[:4])
    run = run_depot(folder, loggers, tmp_path / "report", domain=domain)
    by_bus = {b.bus: b for b in run.buses}
    assert set(by_bus) == {"bus-101", "bus-102"}
    assert by_bus["bus-102"].action == "workshop"
    assert by_bus["bus-102"].verdict == "ambient_battery"
    assert by_bus["bus-101"].action != "workshop"
    assert [b.bus for b in run.workshop] == ["bus-102"]
    summary = pd.read_csv(run.summary)
    assert summary.iloc[0]["bus"] == "bus-102" and summary.iloc[0]["days_diagnosed"] == 2
    assert (tmp_path / "report" / "buses" / "bus-102.html").is_file()
    html = run.html.read_text()
    assert "1 of 2 buses need a workshop visit: bus-102 (ambient_battery)" in html
