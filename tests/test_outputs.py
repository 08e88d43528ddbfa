"""Outputs never destroy inputs; they are checked before the run and written whole."""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ebus_env.cli import app
from ebus_env.errors import ConfigError
from ebus_env.outputs import atomic, check_output

ROOT = Path(__file__).resolve().parent.parent
TRIP = ROOT / "data/measured/bmw_i3_tum/TripB03_1hz.csv"
runner = CliRunner()


def invoke(*args):
    result = runner.invoke(app, [str(a) for a in args], catch_exceptions=False)
    return result.exit_code, result.output


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def day(tmp_path) -> Path:
    path = tmp_path / "day.csv"
    shutil.copy(TRIP, path)
    return path


@pytest.mark.parametrize("option", ["--out", "--json"])
def test_simulate_refuses_to_overwrite_its_measured_log(day, option):
    before = digest(day)
    code, out = invoke("simulate", "--bus", "bmw_i3", "--columns", "bmw_i3_tum",
                       "--measured", day, option, day)
    assert code == 2
    assert "is an input of this command" in out and option in out
    assert digest(day) == before


def test_simulate_refuses_an_output_that_is_the_input_by_another_name(day, tmp_path):
    (tmp_path / "sub").mkdir()
    link = tmp_path / "link.csv"
    os.symlink(day, link)
    before = digest(day)
    for target in (tmp_path / "sub" / ".." / "day.csv", link):
        code, out = invoke("simulate", "--bus", "bmw_i3", "--columns", "bmw_i3_tum",
                           "--measured", day, "--out", target)
        assert code == 2 and "is an input" in out
    assert digest(day) == before


def test_simulate_refuses_to_overwrite_its_bus_config_and_user_effects(tmp_path):
    bus = tmp_path / "my_bus.yaml"
    shutil.copy(ROOT / "configs/bus/12m.yaml", bus)
    effects = tmp_path / "crosswind.py"  # an effect name of its own: the registry is global
    effects.write_text((ROOT / "tests/user_effects/headwind.py").read_text()
                       .replace('"headwind"', '"crosswind_copy"'))
    before = digest(effects)
    code, out = invoke("simulate", "--bus", bus, "--hours", "0.1", "--json", bus)
    assert code == 2 and "is an input" in out
    code, out = invoke("simulate", "--hours", "0.1", "--with", f"{effects}:crosswind_copy",
                       "--plot", effects)
    assert code == 2 and "is an input" in out
    assert digest(effects) == before


def test_diagnose_refuses_to_overwrite_its_log(day):
    before = digest(day)
    html = day.with_suffix(".html")
    os.replace(day, html)  # a log named .html, so the suffix check alone would pass
    day = html
    code, out = invoke("diagnose", day, "--bus", "bmw_i3", "--columns", "bmw_i3_tum",
                       "--html", day)
    assert code == 2 and "is an input of this command" in out
    assert digest(day) == before


def test_diagnose_refuses_to_overwrite_its_reference_day(day):
    normal = day.with_name("normal.json")  # a reference log named like the report
    shutil.copy(day, normal)
    before = digest(normal)
    code, out = invoke("diagnose", day, "--bus", "bmw_i3", "--columns", "bmw_i3_tum",
                       "--reference", normal, "--json", normal)
    assert code == 2 and "is an input of this command" in out
    assert digest(normal) == before


def test_calibrate_refuses_to_overwrite_its_bus_config(tmp_path, day):
    bus = tmp_path / "my_bus.yaml"
    shutil.copy(ROOT / "configs/bus/bmw_i3.yaml", bus)
    before = digest(bus)
    code, out = invoke("calibrate", day, "--bus", bus, "--columns", "bmw_i3_tum",
                       "--out", bus)
    assert code == 2 and "is an input of this command" in out and "--out" in out
    assert digest(bus) == before
    code, out = invoke("calibrate", day, "--bus", bus, "--columns", "bmw_i3_tum",
                       "--history", day)
    assert code == 2 and "is an input" in out


@pytest.mark.parametrize(("option", "name", "message"), [
    ("--out", "trace.txt", "suffix '.txt'"),
    ("--plot", "x.bmp", "suffix '.bmp'"),
    ("--json", "summary.csv", "suffix '.csv'"),
])
def test_outputs_with_a_suffix_they_are_not_written_as_are_refused_before_the_run(
        tmp_path, option, name, message):
    code, out = invoke("simulate", "--hours", "0.1", option, tmp_path / name)
    assert code == 2 and message in out and "Accepted" in out
    assert "consumption" not in out  # refused before simulating
    assert not (tmp_path / name).exists()


def test_an_output_onto_a_folder_is_refused_and_a_missing_folder_is_created(tmp_path):
    code, out = invoke("simulate", "--hours", "0.1", "--json", tmp_path)
    assert code == 2 and "is a folder" in out
    target = tmp_path / "new" / "deeper" / "s.json"
    code, out = invoke("simulate", "--hours", "0.1", "--json", target)
    assert code == 0, out
    assert target.stat().st_size > 100
    assert [p.name for p in target.parent.iterdir()] == ["s.json"]  # no temporary left


def test_an_output_folder_under_a_file_is_refused(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(ConfigError, match="is a file, not a folder"):
        check_output(blocker / "s.json", "--json", (".json",))
    with pytest.raises(ConfigError, match="cannot create the folder"):
        check_output(blocker / "sub" / "s.json", "--json", (".json",))


def test_a_failed_write_leaves_the_old_file_whole(tmp_path):
    target = tmp_path / "summary.json"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("crash while writing")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["summary.json"]
    with atomic(target) as tmp:
        tmp.write_text("new")
    assert target.read_text() == "new"
    assert target.stat().st_mode & 0o777 == 0o666 & ~_umask()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
