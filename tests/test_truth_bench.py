"""The out-of-family truth bench in CI: a small fixed subset of its days (1 day per effect and
3 controls, the last 4 h of each day, from each truth source), diagnosed calibrated on the
bench's baseline bus. On every day the diagnosis may abstain, but never names a wrong effect
(and names none on a control day or for a load outside the library); on the days of
``NAMED_RIGHT`` the bench's run named the hidden effect, and must go on naming it."""

from __future__ import annotations

import importlib.util
import sys
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
