"""The out-of-family truth bench in CI: a small fixed subset of its days (1 day per effect and
3 controls, the last 4 h of each day, from each truth source), diagnosed calibrated on the
bench's baseline bus. On every day the diagnosis may abstain, but never names a wrong effect
(and names none on a control day or for a load outside the library); on the days of
``NAMED_RIGHT`` the bench's run named the hidden effect, and must go on naming it."""

from __future__ import annotations

import importlib.util
import sys
from dataclasses import replace
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

bench = pytest.importorskip("bench_diagnose", reason="benchmarks/bench_diagnose.py not found")

NAMED_RIGHT = {
    # (source, case_id) the bench's smoke run named right (docs/validation.md)
    ("truthsim", "road_grade_00"), ("truthsim", "cabin_heating_00"),
    ("truthsim", "regen_soc_limit_00"),
}


def _available(source: str) -> str:
    """Why a truth source cannot run here ('' when it can)."""
    if importlib.util.find_spec("benchmarks.truth") is None:
        return "benchmarks/truth is not in this checkout"
    if source == "fastsim" and importlib.util.find_spec("fastsim") is None:
        return "fastsim is not installed (pip install 'fastsim>=3')"
    return bench.truth_module(source)[1]


def _jobs():
    out = []
    for source in bench.SOURCES:
        why = _available(source)
        if why:
            out.append(pytest.param(source, None, marks=pytest.mark.skip(reason=why),
                                    id=f"{source}-unavailable"))
            continue
        for case in bench.truth_cases(source, smoke=True):
            out.append(pytest.param(source, case, id=f"{source}-{case.case_id}"))
    return out


@pytest.mark.slow
@pytest.mark.parametrize(("source", "case"), _jobs())
def test_truth_day_gets_no_wrong_verdict(source, case, tmp_path_factory):
    folder = tmp_path_factory.getbasetemp() / "truth-days"
    folder.mkdir(exist_ok=True)
    row = bench.diagnose_truth_day((source, case, str(folder)), ladder=False)  # verdicts only
    expected = row["expected"] if row["expected"] != "outside_library" else None
    assert row["verdict"] in (None, expected), (row["verdict"], row["why"])
    if (source, case.case_id) in NAMED_RIGHT:
        assert row["verdict"] == expected, (row["status"], row["why"])
    for name, (low, high) in row["interval"].items():
        assert low <= row["estimate"][name] <= high
    if row["energy_kwh"] is not None:  # the named effect's energy over the day
        low, high = row["energy_interval_kwh"]
        assert low <= row["energy_kwh"] <= high


def test_a_part_of_the_bench_is_its_first_days():
    """``--per-effect N --controls M`` runs the whole bench's first N days of each effect and
    first M control days: the same days (same seeds), not a new draw."""
    if _available("truthsim"):
        pytest.skip(_available("truthsim"))
    whole = bench.truth_cases("truthsim", smoke=False)
    part = bench.truth_cases("truthsim", smoke=False, per_effect=2, controls=3)
    effects = {c.hidden for c in whole if c.hidden is not None}
    assert len(part) == 2 * len(effects) + 3
    assert all(c in whole for c in part)
    for hidden in effects | {None}:
        first = [c for c in whole if c.hidden == hidden][:3 if hidden is None else 2]
        assert [c for c in part if c.hidden == hidden] == first


def test_a_cut_day_and_its_whole_day_are_cached_apart(tmp_path, monkeypatch):
    """The smoke run's cut days share their case ids with the whole bench's days: in one
    cache folder each must still read back its own log, and neither is made twice."""
    import numpy as np
    import pandas as pd

    if _available("truthsim"):
        pytest.skip(_available("truthsim"))
    made = []

    class Source:  # a stand-in truth source: a standing bus, as long as the case
        @staticmethod
        def generate(case):
            made.append(case.hours)
            n = int(round(case.hours * 3600))
            log = pd.DataFrame({"time_s": np.arange(n, dtype=float), "speed_kmh": 0.0,
                                "soc_pct": 80.0})
            return log, {"start_clock_h": case.start_clock_h, "hours": case.hours}

    day = bench.truth_cases("truthsim", smoke=False)[0]
    monkeypatch.setattr(bench, "truth_module", lambda source: (Source, ""))
    whole = replace(day, start_clock_h=8.0, hours=0.1)
    cut = replace(day, start_clock_h=8.05, hours=0.05)
    for case in (whole, cut, whole, cut):
        profiles, truth = bench.truth_day("truthsim", case, tmp_path)
        assert (truth["hours"], truth["start_clock_h"]) == (case.hours, case.start_clock_h)
        assert sum(p.duration_s for p in profiles) == pytest.approx(case.hours * 3600, abs=2)
    assert made == [0.1, 0.05]
    assert not list(tmp_path.glob("*.tmp"))
