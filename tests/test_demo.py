"""The main job (`ebus demo`) runs on bundled data and writes its report."""

from __future__ import annotations

import json

import pytest

from ebus_env.demo import _tables, run_demo
from ebus_env.units import with_unit
from tests.test_diagnostics import check_recalibration


@pytest.mark.slow
def test_demo_writes_a_self_contained_report(tmp_path):
    page = run_demo(tmp_path)
    html = page.read_text()
    assert html.count("src=\"data:image/png;base64,") == 8 and "data-plots-rendered=\"0/8\"" in html
    assert "12m bus" in html and "BMW i3 trip B16" in html
    numbers = json.loads((tmp_path / "summary.json").read_text())
    assert 0.8 < numbers["12m_sort2_day"]["kwh_per_km"] < 1.6
    assert numbers["18m_sort2_day"]["kwh_per_km"] > numbers["12m_sort2_day"]["kwh_per_km"]
    day = numbers["12m_sort2_day"]  # the simulation's own time, the build's apart
    assert day["wall_time_no_trace_s"] > 0 and day["build_s"] > 0 and day["wall_time_s"] > 0
    assert "simulation wall time, no trace recorded" in html
    assert numbers["bmw_i3_B16"]["soc_rmse_pct"] > 0
    calibrated = numbers["bmw_i3_calibration"]
    assert calibrated["nrmse"] < 0.5 * numbers["bmw_i3_B16"]["soc_nrmse"]
    assert "validation" in calibrated and "calibrated with iSOPT on trip B16" in html
    # diagnosis: the car without heating, and a day with the heating hidden, then added
    assert numbers["diagnosis_bmw_i3_without_heating"]["verdict"] == "cabin_hvac"
    # the cabin added and re-calibrated: the truth's error, the pack and base load back
    check_recalibration("cabin_heating", numbers["diagnosis_hidden_cabin_heating"])
    for name in ("bmw_i3_without_heating", "hidden_cabin_heating"):
        assert (tmp_path / f"{name}.html").stat().st_size > 10_000


def test_dimensionless_values_print_without_a_unit():
    figures, _ = _tables({"soc_nrmse": 0.0991, "kwh_per_km": 1.112, "breakdown_kwh": {}})
    assert figures.rows == [["consumption", "1.112", "kWh/km"],
                            ["SoC NRMSE (range-normalised)", "0.099", ""]]
    assert with_unit("0.1234", "1") == "0.1234" and with_unit("27.47", "degC") == "27.47 degC"
