"""The diagnosis pipeline reads as it runs: the stage modules' numbers, the list in
``pipeline.py``'s docstring and the order ``diagnose`` calls them in are one order, and each
stage takes the run context alone."""

from __future__ import annotations

import importlib
import inspect
import re
from pathlib import Path

from ebus_env.diagnostics import pipeline

FOLDER = Path(pipeline.__file__).parent


def stage_files() -> list[str]:
    return sorted(p.stem for p in FOLDER.glob("stage[0-9][0-9]_*.py"))


def test_the_docstring_lists_the_stages_in_the_order_diagnose_runs_them():
    listed = re.findall(r"^\s*\d+\. ``(stage\d\d_\w+)``", pipeline.__doc__, re.MULTILINE)
    called = re.findall(r"(stage\d\d_\w+)\.run\(ctx\)", inspect.getsource(pipeline.diagnose))
    numbers = [int(name[5:7]) for name in stage_files()]
    assert numbers == list(range(1, len(numbers) + 1)), "number the stages 01, 02, ... in turn"
    assert listed == stage_files() == called


def test_each_stage_runs_on_the_context_alone():
    for name in stage_files():
        run = importlib.import_module(f"ebus_env.diagnostics.{name}").run
        assert list(inspect.signature(run).parameters) == ["ctx"], name
