"""The out-of-family truth bench in CI: a small fixed subset of its days (1 day per effect and
3 controls, 4 h each, from each truth source), diagnosed calibrated on the bench's baseline
bus. Each day must get the outcome the bench reaches on it; the days the diagnosis gets
wrong are marked as expected failures with the verdict it gives (strict: a fix shows)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

bench = pytest.importorskip("bench_diagnose", reason="benchmarks/bench_diagnose.py not found")

WRONG = {
    # (source, case): the outcome the diagnosis reaches instead of the right one
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
            marks = [pytest.mark.xfail(strict=True, reason=f"the diagnosis says "
                                       f"{WRONG[(source, case.case_id)]}")] \
                if (source, case.case_id) in WRONG else []
            out.append(pytest.param(source, case, marks=marks, id=f"{source}-{case.case_id}"))
    return out


def right(row: dict) -> bool:
    """The bench's criterion for a day: the library effect named; no verdict on a control
    day; 'no library effect' with the right operating mode for a load outside the library."""
    if row["expected"] is None:
        return row["verdict"] is None
    if row["expected"] == "outside_library":
        return row["status"] == "outside library" and row["clue"] == row["outside_mode"]
    return row["verdict"] == row["expected"]


@pytest.mark.slow
@pytest.mark.parametrize(("source", "case"), _jobs())
def test_truth_day_gets_the_right_outcome(source, case, tmp_path_factory):
    folder = tmp_path_factory.getbasetemp() / "truth-days"
    folder.mkdir(exist_ok=True)
    row = bench.diagnose_truth_day((source, case, str(folder)))
    assert right(row), (row["verdict"], row["status"], row["clue"], row["why"])
    if row["verdict"] and row["interval"]:
        for name, (low, high) in row["interval"].items():
            assert low <= row["estimate"][name] <= high
