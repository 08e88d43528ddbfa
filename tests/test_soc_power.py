"""A SoC-only log read as a coarse power log: the charge its SoC counts in each window, through
the power path (in-family days of the project's own model; the out-of-family checks are the
truth bench's)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ebus_env.diagnostics import hidden
from ebus_env.diagnostics.power import logs_power
from ebus_env.diagnostics.soc_power import WINDOW_S, as_power_logs, logs_soc, window_missing_w
from ebus_env.io.measured import load_log
from ebus_env.synthetic import synthetic_log

BASE_W = "auxiliaries.base_power_w"


def soc_day(tmp_path, name: str, effect: str | None = None, hours: float = 4.0,
            step_pct: float = 0.1, **params):
    """A SoC-only log of a hidden-effect case (``effect`` None: the baseline bus), its first
    ``hours``, with the logged bus's own ``params``; the case and its profiles."""
    name = {None: "control", "cabin_hvac": "cabin_heating"}.get(effect, effect)
    case = replace(hidden.case(name), hours=hours)
    profile, _ = hidden.day_profile(case)
    truth = hidden.baseline_bus(case) if effect is None else hidden.true_bus(case)
    frame = synthetic_log(truth.build(hidden.DT_S), profile, params=params or None,
                          soc_start=case.soc_start, soc_step_pct=step_pct, seed=1)
    frame = frame.drop(columns=["battery_current_a", "battery_voltage_v", "grade_frac"],
                       errors="ignore")
    path = tmp_path / f"{name}.csv"
    frame.to_csv(path, index=False)
    return case, load_log(path).profiles


def test_the_soc_count_gives_a_missing_load_window_by_window(tmp_path):
    """A bus whose auxiliaries draw 4 kW more than the model's: each window's missing power,
    from the SoC's count alone, is those 4 kW (the SoC unquantised: what is left is the
    model's own count against the log's, a few watts)."""
    case, profiles = soc_day(tmp_path, "more_aux", step_pct=0.0)
    model = hidden.baseline_bus(case).build(hidden.DT_S)
    base_w = model.params[model.param_index(BASE_W)]
    _, logged = soc_day(tmp_path, "more_aux_logged", step_pct=0.0, **{BASE_W: base_w + 4e3})
    assert logs_soc(logged[0]) and not logs_power(logged[0])
    model_wv, missing_w = window_missing_w(model, logged[0], model.params)
    every = int(round(1.0 / hidden.DT_S))  # model steps a logged second
    plugged = logged[0].channel("charger_connected")[::every][:len(missing_w)] > 0.5
    per = int(WINDOW_S)
    windows = [missing_w[a] for a in range(0, len(missing_w) - per + 1, per)
               if not plugged[a:a + per].any()]
    assert len(windows) >= 20
    assert np.median(windows) == pytest.approx(4e3, rel=0.03)
    assert np.percentile(np.abs(np.asarray(windows) - 4e3), 90) < 150.0
    # the copy carries the count as a current and the model's voltage, for the power path
    copy = as_power_logs(model, logged, model.params)[0]
    assert logs_power(copy) and not logs_power(logged[0])
    power_w = (copy.measured["battery_current_a"] * copy.measured["battery_voltage_v"])[::every]
    assert power_w[:per].mean() == pytest.approx(model_wv[:per, 0].mean() + missing_w[0],
                                                 rel=1e-4)


@pytest.mark.slow
def test_a_soc_only_day_in_the_power_domain_names_its_effect_and_a_control_day_nothing(
        tmp_path):
    """The power path on SoC-only logs (0.1 % SoC steps): a cold day's cabin heating is named
    in 5-min windows; the same bus without it gets no verdict."""
    from ebus_env.diagnostics import diagnose

    case, profiles = soc_day(tmp_path, "heating", "cabin_hvac", hours=4.0)
    d = diagnose(hidden.baseline_bus(case), profiles, domain="power")
    assert d.domain == "power" and d.verdict == "cabin_hvac"
    case, quiet = soc_day(tmp_path, "quiet", None, hours=4.0)
    q = diagnose(hidden.baseline_bus(case), quiet, domain="power")
    assert q.verdict is None
