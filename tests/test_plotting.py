"""Trace plots: a readable window of a long run, the reference visible, the vehicle named."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from ebus_env.plotting import plot_trace


def _result(duration_h: float, name: str = "bmw_i3"):
    t_s = np.arange(0.0, duration_h * 3600.0, 1.0)
    speed = 10.0 * (1 + np.sin(t_s / 60.0))
    traces = {"speed_mps": 0.98 * speed, "speed_ref_mps": speed,
              "battery_power_w": 2e4 * np.cos(t_s / 60.0), "grid_power_w": np.zeros_like(t_s),
              "dc_load_w": np.full_like(t_s, 3e3), "soc_frac": 0.9 - 1e-6 * t_s,
              "ambient_degc": np.full_like(t_s, 5.0), "cabin_temp_degc": np.full_like(t_s, 20.0)}
    return SimpleNamespace(time_s=t_s, trace=traces.__getitem__, record_every=1,
                           model=SimpleNamespace(name=name, trace_names=list(traces)),
                           profile=SimpleNamespace(name="a day", measured={}))


@pytest.mark.parametrize(("duration_h", "speed_span"), [(13.5, 20.0), (0.5, 0.5)])
def test_speed_shows_a_readable_window_and_the_reference_over_the_vehicle(duration_h,
                                                                           speed_span):
    fig = plot_trace(_result(duration_h))
    speed_ax, _, soc_ax, _ = fig.axes
    lines = {ln.get_label(): ln for ln in speed_ax.get_lines()}
    assert set(lines) == {"bmw_i3", "reference"}  # the config's name, not "bus"
    x = lines["bmw_i3"].get_xdata()
    # a long run: its first 20 min, in minutes; a short one: all of it, in hours
    assert x[-1] == pytest.approx(speed_span, abs=0.02)
    assert soc_ax.get_lines()[0].get_xdata()[-1] == pytest.approx(duration_h, abs=0.01)
    ref, veh = lines["reference"], lines["bmw_i3"]
    drawn = speed_ax.get_lines()
    assert drawn.index(ref) > drawn.index(veh) and ref.get_linestyle() == "--"
    assert ref.get_linewidth() < veh.get_linewidth()  # the vehicle's line shows around it
