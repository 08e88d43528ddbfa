"""Where the bench keeps a generated day: file names shared by the bench's runner and the
ceiling (which must not import the model under test).

A day is generated once, its whole log (the pack's current and voltage and the oracle column)
in ``<source>-<case_id>.g<GENERATION>.full.csv.gz`` and its truth record in
``... .truth.json``; a case cut shorter than the whole bench's day (a smoke or CI day) is kept
under its own name, with its hours and start in it.
"""

from __future__ import annotations

import json
from pathlib import Path

GENERATION = 2
"""The truth sources' generation, in the cached days' file names: raised whenever a source's
physics or logs change, so that a cache folder never serves a day made by older code."""


def day_paths(folder: Path, source: str, case) -> tuple[Path, Path]:
    """The whole log's and the truth record's paths of a case's day in ``folder``."""

    def paths(stem):
        return (folder / f"{stem}.g{GENERATION}.full.csv.gz",
                folder / f"{stem}.g{GENERATION}.truth.json")

    log_path, truth_path = paths(f"{source}-{case.case_id}")
    if truth_path.exists():
        cached = json.loads(truth_path.read_text())
        if (cached["start_clock_h"], cached["hours"]) != (case.start_clock_h, case.hours):
            log_path, truth_path = paths(f"{source}-{case.case_id}-{case.hours:g}h-from-"
                                         f"{case.start_clock_h:g}h")
    return log_path, truth_path
