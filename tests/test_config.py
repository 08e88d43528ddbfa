"""Bus configs: values only, unknown keys fail with a close match, overlays merge."""

from __future__ import annotations

import pytest

from ebus_env.config import load_bus
from ebus_env.errors import ConfigError


def write(tmp_path, text, name="bus.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_shipped_buses_build_with_their_values(bus12, bus18):
    m12, m18 = bus12.build(), bus18.build()
    assert m12.params[m12.param_index("rint_battery.cells_series")] == 204
    assert m18.params[m18.param_index("grid_charger.power_kw")] == 290
    assert m12.bounds[m12.param_index("vehicle_body.curb_mass_kg")].tolist() == [12000, 14500]
    assert {e.name for e in m12.effects} >= {"aero_drag", "cabin_hvac", "rint_battery"}


def test_unknown_keys_fail_with_a_close_match(tmp_path):
    with pytest.raises(ConfigError, match="Unknown key.*'contribution'. Did you mean 'contributions'"):
        load_bus(write(tmp_path, "contribution: [aero_drag]\n"))
    with pytest.raises(ConfigError, match="Unknown parameter of effect 'aero_drag' 'drag_cof'"):
        text = "contributions: [aero_drag]\nparams: {aero_drag: {drag_cof: 0.6}}\n"
        load_bus(write(tmp_path, text)).build()
    with pytest.raises(ConfigError, match="Unknown effect 'aero_drg'"):
        load_bus(write(tmp_path, "contributions: [aero_drg]\n")).build()
    with pytest.raises(ConfigError, match="Unknown key in .*service.*'soc_start'"):
        load_bus(write(tmp_path, "service: {soc_start: 90}\n"))
    with pytest.raises(ConfigError, match="Unknown bus config '12n'. Did you mean '12m'"):
        load_bus("12n")


def test_overlay_changes_values_and_composition(tmp_path):
    overlay = write(tmp_path, "params: {aero_drag: {drag_coef: 0.6}}\nwithout: [cabin_hvac]\n",
                    "overlay.yaml")
    bus = load_bus("12m", overlays=[overlay])
    model = bus.build()
    assert model.params[model.param_index("aero_drag.drag_coef")] == 0.6
    assert model.params[model.param_index("aero_drag.frontal_area_m2")] == 7.5  # kept
    assert not model.has_effect("cabin_hvac")


def test_slot_removal_and_table_presets(bus12):
    model = bus12.without_effect("static_rcd").build()
    assert model.composition.slots["aging"] is None
    with pytest.raises(ConfigError, match="Unknown effect in bus '12m' 'headwinds'"):
        bus12.without_effect("headwinds")
    nmc = load_bus("12m", overlays=[{"tables": {"rint_battery": {"ocv_cell_v": "nmc_p42a"}}}])
    ocv = nmc.build().composition.tables[("rint_battery", "ocv_cell_v")]
    assert ocv[3 + 20] == pytest.approx(3.743)  # 50 % SoC on the 2.5 % grid
    with pytest.raises(ConfigError, match="Unknown preset of table 'ocv_cell_v' 'lfp'"):
        load_bus("12m", overlays=[{"tables": {"rint_battery": {"ocv_cell_v": "lfp"}}}]).build()


def test_bus_config_names_a_users_effect_file_beside_it(tmp_path):
    (tmp_path / "extra_load.py").write_text(
        "from ebus_env import Param, effect\n\n"
        "@effect('roof_fans', sink='dc_load_w', params=[\n"
        "    Param('fan_power_w', 300.0, 'W', (0.0, 2000.0), 'Roof fans')])\n"
        "def roof_fans(fan_power_w):\n"
        "    return fan_power_w\n")
    path = write(tmp_path, "contributions: [aero_drag, rolling_resistance]\n"
                           "with: [extra_load.py:roof_fans]\n"
                           "params: {roof_fans: {fan_power_w: 450}}\n")
    model = load_bus(path).build()
    assert model.has_effect("roof_fans")
    assert model.params[model.param_index("roof_fans.fan_power_w")] == 450.0
