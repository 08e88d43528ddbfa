"""Fleet calibration (``ebus calibrate --fleet logs_dir/``): every bus-day log calibrated as its
own task, one row of fitted parameters per log (the fleet's digital twin), outliers flagged.

A parameter is flagged on a log when its robust z-score (Iglewicz and Hoaglin, *How to Detect
and Handle Outliers*, ASQC 1993, sec. 3.3) exceeds 3.5::

    z = 0.6745 (x - median(x)) / MAD,   MAD = median(|x - median(x)|)

(0.6745 makes the MAD a standard deviation for normal data.) The scores are taken over the logs
that determine the parameter (the calibration's determinacy: a charging parameter on a log
without charging wanders within its bounds and says nothing about the bus); a parameter that
they all fit alike (MAD = 0) flags nothing. The fit's NRMSE is scored too: a log that the
model fits far worse than the others' points to a bus (or a logger) that differs.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pandas as pd

from ebus_env import paths
from ebus_env.errors import ConfigError
from ebus_env.io.log_reading import logs_in
from ebus_env.outputs import atomic

Z_LIMIT = 3.5


def fleet_logs(logs_dir: str | Path) -> list[Path]:
    """The logs of a folder (CSV, gzipped CSV, Parquet), sorted by name."""
    folder = paths.here_or_shipped(logs_dir)
    if not folder.is_dir():
        raise ConfigError(f"--fleet {folder}: not a folder; give the folder of bus-day logs.")
    return logs_in([folder], "--fleet")


def calibrate_log(path: Path, bus: str, columns: str | None, free: list[str] | None,
                  seed: int, population: int | None, iterations: int | None) -> dict:
    """One log's task: build the bus, fit it with iSOPT, return its row."""
    from ebus_env.calibration import ISOPTSettings, calibrate
    from ebus_env.config import load_bus
    from ebus_env.io.measured import load_log

    model = load_bus(bus).build()
    profiles = load_log(path, model.dt_s, columns=columns).profiles
    settings = ISOPTSettings(seed=seed, **({"population": population} if population else {}),
                             **({"iterations": iterations} if iterations else {}))
    t0 = time.perf_counter()
    result = calibrate(model, profiles, free, settings=settings)
    determined = {f"{p} determined": result.determinacy[p].status != "not determined"
                  if p in result.determinacy else False for p in result.free}
    return {"log": path.name, "bus": bus, "nrmse": result.fit["nrmse"],
            "rmse_pct": result.fit["rmse_pct"], "wall_time_s": time.perf_counter() - t0,
            **result.values, **determined}


def robust_z(values: np.ndarray, use: np.ndarray | None = None) -> np.ndarray:
    """Robust z-scores 0.6745 (x - median) / MAD, median and MAD over ``values[use]``
    (default all); NaN outside ``use``, 0 where MAD = 0."""
    values = np.asarray(values, float)
    use = np.ones(len(values), bool) if use is None else np.asarray(use, bool)
    z = np.full(len(values), np.nan)
    if use.sum() < 3:  # too few to tell an outlier from the rest
        return z
    median = np.median(values[use])
    mad = np.median(np.abs(values[use] - median))
    z[use] = 0.0 if mad == 0.0 else 0.6745 * (values[use] - median) / mad
    return z


def flag_outliers(table: pd.DataFrame, params: list[str]) -> pd.DataFrame:
    """Add ``<param> z`` columns (over the logs that determine it, ``<param> determined``;
    NaN elsewhere) and ``outliers``: the parameters whose |z| > Z_LIMIT."""
    table = table.copy()
    flags = [[] for _ in range(len(table))]
    for p in params:
        use = table.get(f"{p} determined", pd.Series(True, index=table.index)).to_numpy(bool)
        z = robust_z(table[p].to_numpy(), use)
        table[f"{p} z"] = z
        for i in np.flatnonzero(np.abs(np.nan_to_num(z)) > Z_LIMIT):
            flags[i].append(p)
    table["outliers"] = [", ".join(f) for f in flags]
    return table


def calibrate_fleet(logs_dir: str | Path, bus: str = "12m", out: str | Path = "fleet_params.csv",
                    *, columns: str | None = None, free: str | list[str] | None = None,
                    seed: int = 0, population: int | None = None,
                    iterations: int | None = None, use_ray: bool = False,
                    address: str | None = None, workers: int | None = None,
                    say=print) -> pd.DataFrame:
    """Calibrate every log of ``logs_dir`` on its own and write the per-log parameter table
    to ``out`` (``ebus calibrate --fleet``).

    In this process the logs run one after the other (each calibration already uses every
    core); on Ray one task per log.

    Parameters
    ----------
    logs_dir
        The folder of bus-day logs (``*.csv``, ``*.csv.gz``, ``*.parquet``).
    bus
        Bus config name or path.
    out
        The table: CSV, or Parquet by its suffix; refused inside ``logs_dir``.
    columns
        Column map preset of the logs.
    free
        Free parameters by qualified name (a list or comma list; default: the paper's).
    seed, population, iterations
        iSOPT's seed, population and iterations.
    use_ray, address
        One Ray task per log: a local runtime, or the cluster at ``host:port`` (which
        implies ``use_ray``).
    workers
        CPUs of a local Ray runtime.
    say
        Told each log's fit as it finishes.

    Returns
    -------
    pandas.DataFrame
        One row per log: NRMSE, fitted values, which the log determines, robust z-scores and
        the outliers.
    """
    from ebus_env.bus_choice import split_names
    from ebus_env.inputs import check
    from ebus_env.outputs import TABLE_SUFFIXES, check_folder, check_output
    from ebus_env.study.backends import map_tasks

    free = split_names([free] if isinstance(free, str) else free) or None
    use_ray = use_ray or address is not None

    for name, value in (("population", population), ("iterations", iterations)):
        if value is not None:
            check(name, value, f"--{name}")
    logs = fleet_logs(logs_dir)
    # before any work: a table among the logs would be read as a log by the next run
    out = check_output(Path(out), "--out", TABLE_SUFFIXES, inputs=logs)
    check_folder(out.parent, "--out", inputs=logs)
    say(f"fleet calibration: {len(logs)} log(s) of {bus} {'on Ray' if use_ray else ''}".rstrip())
    rows = {}

    def done(args, row):
        rows[args[0]] = row
        say(f"  {row['log']}: NRMSE {row['nrmse']:.4f} ({row['wall_time_s']:.0f} s)")

    map_tasks(calibrate_log, [(p, bus, columns, free, seed, population, iterations)
                              for p in logs], done, use_ray=use_ray, address=address,
              workers=workers or 1)
    table = pd.DataFrame([rows[p] for p in logs])
    params = [c for c in table.columns if "." in c and " " not in c]
    table = flag_outliers(table, [*params, "nrmse"])  # and a log the model fits far worse
    with atomic(out) as tmp:
        if out.suffix == ".csv":
            table.to_csv(tmp, index=False, float_format="%.6g")
        else:
            table.to_parquet(tmp, index=False)
    return table


def print_fleet(table: pd.DataFrame, bus: str, out: str | Path, console) -> None:
    """What ``ebus calibrate --fleet`` prints of the table :func:`calibrate_fleet` wrote: the
    fitted values by log (? where the log does not determine one) with the outliers, and
    where it went."""
    from rich.table import Table

    names = [c for c in table.columns if "." in c and " " not in c]
    view = Table(title=f"fleet calibration of {bus}: fitted values (?: not determined by the "
                 f"log; outliers: robust |z| > {Z_LIMIT:g})", title_justify="left")
    for heading in ("log", "NRMSE", *[n.split(".")[-1] for n in names], "outliers"):
        view.add_column(heading)
    for _, r in table.iterrows():
        view.add_row(r["log"], f"{r['nrmse']:.4f}", *[f"{r[n]:.4g}" + (
            "" if r[f"{n} determined"] else "?") for n in names], r["outliers"])
    console.print(view)
    console.print(f"table -> {out}")
