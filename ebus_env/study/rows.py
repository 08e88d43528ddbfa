"""The study's results on disk: a Parquet dataset, one file per finished scenario.

``<out>/rows/<scenario key>.parquet`` holds the scenario's rows (one per day), written to a
temporary file in the same folder and renamed, so a file that exists is complete: an
interrupted study resumes by skipping the scenarios whose file is there. The folder opens in
pandas as one table: ``pd.read_parquet("study/rows")``.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import pandas as pd

from ebus_env.outputs import atomic

ROWS = "rows"


def rows_dir(out: str | Path) -> Path:
    return Path(out) / ROWS


def finished(out: str | Path) -> set[str]:
    """Keys of the scenarios whose rows are on disk."""
    folder = rows_dir(out)
    return {p.stem for p in folder.glob("*.parquet")} if folder.exists() else set()


def write_rows(out: str | Path, key: str, rows: list[dict]) -> Path:
    """Write one scenario's rows atomically (temporary file, then rename)."""
    folder = rows_dir(out)
    folder.mkdir(parents=True, exist_ok=True)
    frame = pd.DataFrame(rows)
    frame.insert(0, "scenario_key", key)
    path = folder / f"{key}.parquet"
    with atomic(path) as tmp:
        frame.to_parquet(tmp, index=False)
    return path


def read_results(out: str | Path, keys: Iterable[str] | None = None) -> pd.DataFrame:
    """The rows of the finished scenarios (those among ``keys`` only, where given: a study's
    own, without another study's rows in the same folder), in scenario then day order."""
    done = finished(out) if keys is None else finished(out) & set(keys)
    files = sorted(rows_dir(out) / f"{key}.parquet" for key in done)
    if not files:
        return pd.DataFrame()
    frame = pd.concat([pd.read_parquet(p) for p in files], ignore_index=True)
    return frame.sort_values(["scenario_key", "day"], ignore_index=True)
