"""Property-based: generated logs, bus configs, command-line values and env actions.

For each: a clear error of the project's own type, or a result whose numbers are finite
(with the documented warnings); never an uncaught exception, NaN in an output, or a changed
input file. Example counts are bounded so that the fast part runs in about a minute.
"""

from __future__ import annotations

import hashlib
import json
import math
import tempfile
from pathlib import Path

import gymnasium
import numpy as np
import pandas as pd
import pytest
import yaml
from hypothesis import HealthCheck, assume, event, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

import ebus_env  # noqa: F401  (registers the envs)
from ebus_env.cli import app
from ebus_env.config import load_bus
from ebus_env.cycles import service_day
from ebus_env.errors import EbusError
from ebus_env.io.measured import load_log
from ebus_env.simulate import run_profiles
from tests.conftest import DT

ROOT = Path(__file__).resolve().parent.parent
FAST = settings(max_examples=250, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow])

# numbers a user may type: ordinary, extreme, negative, zero, not finite
numbers = st.one_of(st.floats(-1e3, 1e3), st.sampled_from([0.0, -1.0, 1e6, -1e6, 285.0]),
                    st.floats(allow_nan=True, allow_infinity=True))


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def finite(value) -> bool:
    """Every number inside a summary (nested dicts and lists) is finite."""
    if isinstance(value, dict):
        return all(finite(v) for v in value.values())
    if isinstance(value, (list, tuple)):
        return all(finite(v) for v in value)
    if isinstance(value, (float, np.floating)):
        return math.isfinite(value)
    return True


@st.composite
def logs(draw):
    """A measured log as a user might hand it over: sample period, time unit, columns,
    missing and implausible values all drawn."""
    n = draw(st.integers(2, 400))
    period = draw(st.sampled_from([0.01, 0.1, 0.5, 1.0, 2.0, 10.0, 1000.0]))
    t = np.arange(n) * period
    speed = np.clip(40 * np.sin(t / 90.0), 0, None)
    frame = pd.DataFrame({"time_s": t, "speed_kmh": speed})
    if draw(st.booleans()):
        frame["soc_pct"] = 90 - 0.001 * t * draw(st.sampled_from([1.0, 0.01, 1e3]))
    if draw(st.booleans()):
        frame["ambient_degc"] = draw(st.sampled_from([5.0, -10.0, 285.0, float("inf")]))
    if draw(st.booleans()):
        frame["extra_signal"] = draw(st.sampled_from([1.0, float("nan")]))
    rows = draw(st.lists(st.integers(0, n - 1), max_size=3))
    column = draw(st.sampled_from(list(frame.columns)))
    value = draw(numbers)
    for r in rows:  # a few cells replaced by anything: NaN, negative, huge
        frame.loc[r, column] = value
    return frame


@FAST
@given(frame=logs(), gaps=st.sampled_from(["error", "split", "hold", "interpolate"]),
       fill=st.sampled_from(["error", "interpolate"]))
def test_generated_logs_load_to_finite_profiles_or_fail_clearly(model12, frame, gaps, fill):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "log.csv"
        frame.to_csv(path, index=False)
        before = digest(path)
        try:
            log = load_log(path, DT, gaps=gaps, fill=fill)
        except EbusError:
            event("refused")
            assert digest(path) == before
            return
        event("loaded")
        assert digest(path) == before
        for profile in log.profiles:
            for name, channel in profile.channels.items():
                assert np.isfinite(channel).all(), name
        run = run_profiles(model12, log.profiles, record=False,
                           soc_start=None if "soc_pct" in frame else 0.9)
        figures = {k: v for k, v in run.summary.items() if k != "kwh_per_km"}  # 0 km: NaN
        assert finite(figures), figures


service_values = st.one_of(numbers, st.sampled_from(["12 t", None, [1, 2], True]))


@FAST
@given(key=st.sampled_from(["soc_start_pct", "ambient_degc", "start_time_h",
                            "layover_every_min", "layover_min", "layover_charger_kw"]),
       value=service_values,
       mass=st.one_of(st.floats(10_000, 16_000), st.sampled_from(["13 t", None, [1], "1.3e4"])))
def test_generated_bus_configs_load_or_fail_clearly(key, value, mass):
    data = yaml.safe_load((ROOT / "configs/bus/12m.yaml").read_text())
    data["service"][key] = value
    data["params"]["vehicle_body"]["curb_mass_kg"] = mass
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "bus.yaml"
        path.write_text(yaml.safe_dump(data))
        before = digest(path)
        try:
            bus = load_bus(path)
            day = service_day("sort2", 0.2, DT, bus.service)
        except EbusError as exc:
            event("refused")
            assert str(path) in str(exc) or "service" in str(exc) or "hours" in str(exc)
            return
        finally:
            assert digest(path) == before
        event("loaded")
        for name, channel in day.channels.items():
            if name != "charger_rating_w":  # NaN there means: the charger's own power
                assert np.isfinite(channel).all(), name


runner = CliRunner()


@settings(max_examples=150, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(hours=st.one_of(st.sampled_from([0.1, 0.2]), numbers),
       dt=st.sampled_from(["0.1", "0.5", "0", "-1", "nan", "60"]),
       speed=st.one_of(st.none(), numbers), ambient=st.one_of(st.none(), numbers),
       soc=st.one_of(st.none(), numbers))
def test_generated_command_lines_run_or_fail_with_one_line(hours, dt, speed, ambient, soc):
    assume(not (isinstance(hours, float) and 0.2 < hours < 48))  # keep the runs short
    args = ["simulate", "--hours", str(hours), "--dt", dt]
    for option, value in (("--mean-speed-kmh", speed), ("--ambient-degc", ambient),
                          ("--soc-start-pct", soc)):
        if value is not None:
            args += [option, str(value)]
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "s.json"
        result = runner.invoke(app, [*args, "--json", str(out)])
        assert result.exception is None or isinstance(result.exception, SystemExit), (
            args, result.exception)
        assert "Traceback" not in result.output
        event("ran" if result.exit_code == 0 else "refused")
        if result.exit_code == 0:
            summary = json.loads(out.read_text())
            assert all(v is not None for k, v in summary.items() if k != "kwh_per_km"), summary
        else:
            lines = result.output.strip().splitlines()
            assert result.exit_code == 2 and lines[-1].startswith("error:"), result.output
            assert all(line.startswith(("warning:", "error:")) for line in lines), lines
            assert not out.exists()


actions = st.one_of(
    st.lists(st.floats(-1, 1, width=32), min_size=5, max_size=5),
    st.lists(st.floats(allow_nan=True, allow_infinity=True, width=32), min_size=5,
             max_size=5),
    st.lists(st.floats(-1, 1, width=32), min_size=0, max_size=7))


@pytest.fixture(scope="module")
def short_env():
    return gymnasium.make("EBus-v0", service_h=1.0, decision_s=120)


@FAST
@given(sequence=st.lists(actions, min_size=1, max_size=8), seed=st.integers(0, 2**16))
def test_generated_env_actions_step_finitely_or_fail_clearly(short_env, sequence, seed):
    short_env.reset(seed=seed)
    for action in sequence:
        try:
            obs, reward, terminated, truncated, info = short_env.step(
                np.asarray(action, np.float32))
        except EbusError:
            event("refused")
            continue
        event("stepped")
        assert np.isfinite(obs).all() and math.isfinite(reward)
        assert short_env.observation_space.contains(obs)
        if terminated or truncated:
            break


@pytest.mark.slow
@settings(max_examples=20, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**16), scale=st.floats(0.0, 1.0))
def test_whole_days_of_random_valid_actions_stay_finite(seed, scale):
    env = gymnasium.make("EBus-v0", decision_s=300)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    terminated = truncated = False
    while not (terminated or truncated):
        action = (scale * rng.uniform(-1, 1, 5)).astype(np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        assert np.isfinite(obs).all() and math.isfinite(reward)
        assert finite(info["breakdown_kwh"])


ACCEPTED = {"--out": (".parquet", ".csv"), "--json": (".json",), "--plot": (".png", ".svg", ".pdf")}


@settings(max_examples=30, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(option=st.sampled_from(sorted(ACCEPTED)),
       suffix=st.sampled_from([".parquet", ".csv", ".json", ".png", ".svg", ".pdf", ".txt",
                               ".bmp", ".CSV", ""]),
       exists=st.booleans())
def test_generated_output_paths_are_written_whole_or_refused_before_the_run(option, suffix,
                                                                             exists):
    with tempfile.TemporaryDirectory() as folder:
        target = Path(folder) / "sub" / f"result{suffix}"
        if exists:
            target.parent.mkdir()
            target.write_text("old")
        result = runner.invoke(app, ["simulate", "--hours", "0.05", option, str(target)])
        assert result.exception is None or isinstance(result.exception, SystemExit)
        if suffix.lower() in ACCEPTED[option]:
            assert result.exit_code == 0, result.output
            assert target.stat().st_size > 100
        else:
            assert result.exit_code == 2 and "Accepted" in result.output
            assert not target.exists() or target.read_text() == "old"
        if target.parent.exists():  # no temporary file left beside it
            assert [p.name for p in target.parent.iterdir()] in ([], [target.name])
