"""Fleet calibration: every log its own task, one row each, outliers by robust z-score."""

from __future__ import annotations

import shutil

import numpy as np
import pandas as pd
import pytest

from ebus_env import paths
from ebus_env.errors import ConfigError
from ebus_env.study.fleet_calibration import calibrate_fleet, flag_outliers, robust_z

BMW = paths.data("measured", "bmw_i3_tum")


def test_robust_z_by_hand():
    x = np.array([1.0, 1.1, 0.9, 1.0, 3.0])
    # median 1.0, MAD median(|0, .1, .1, 0, 2|) = 0.1
    assert robust_z(x) == pytest.approx(0.6745 * (x - 1.0) / 0.1)
    assert np.isnan(robust_z(x, [True, True, True, True, False])[4])
    assert robust_z(np.ones(4)).tolist() == [0.0] * 4  # all alike: nothing stands apart
    assert np.isnan(robust_z(x, [True, True, False, False, False])).all()  # too few


def test_outliers_only_among_the_logs_that_determine_the_parameter():
    table = pd.DataFrame({"log": list("abcde"), "r.rcd": [0.1, 0.11, 0.09, 0.1, 0.4],
                          "c.power": [50, 51, 49, 50, 500],
                          "c.power determined": [True, True, True, True, False]})
    out = flag_outliers(table, ["r.rcd", "c.power"])
    assert out["outliers"].tolist() == ["", "", "", "", "r.rcd"]
    assert out["r.rcd z"].iloc[4] == pytest.approx(0.6745 * 0.3 / 0.01)


def test_fleet_calibration_writes_one_row_per_log(tmp_path):
    logs = tmp_path / "logs"
    logs.mkdir()
    for trip in ("B02", "B03", "B16"):
        shutil.copy(BMW / f"Trip{trip}_1hz.csv", logs)
    said = []
    table = calibrate_fleet(logs, "bmw_i3", tmp_path / "fleet.csv", columns="bmw_i3_tum",
                            free=["static_rcd.rcd_frac", "cabin_hvac.setpoint_degc"],
                            population=5, iterations=3, say=said.append)
    assert table["log"].tolist() == ["TripB02_1hz.csv", "TripB03_1hz.csv", "TripB16_1hz.csv"]
    assert (table["nrmse"] < 0.1).all() and table["static_rcd.rcd_frac"].between(0, 0.5).all()
    assert {"static_rcd.rcd_frac z", "outliers"} <= set(table.columns)
    written = pd.read_csv(tmp_path / "fleet.csv", keep_default_na=False)
    assert written["log"].tolist() == table["log"].tolist() and len(said) == 4
    with pytest.raises(ConfigError, match="is an input of this command"):
        calibrate_fleet(logs, "bmw_i3", logs / "TripB02_1hz.csv", columns="bmw_i3_tum")
    # a table among the logs would be read as a log by the next run: refused before any work
    with pytest.raises(ConfigError, match="holds the input"):
        calibrate_fleet(logs, "bmw_i3", logs / "table.csv", columns="bmw_i3_tum", say=said.append)
    assert len(said) == 4 and not (logs / "table.csv").exists()
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ConfigError, match="no logs"):
        calibrate_fleet(empty, "bmw_i3", tmp_path / "x.csv")
