"""A model per bus that tunes itself as its data come in.

* **Window re-fit** (while the bus runs its day): once ``refit_every_min`` of new data have
  come, the day so far is tuned with the windowed iSOPT of
  :mod:`ebus_env.calibration.windowed`, warm-started from the bus's last fit (its first fit
  starts with a global search), freeing :data:`WINDOW_FREE`.
* **Cross-day fit** (when a day is finished): the bus-to-bus parameters
  (:data:`CROSS_DAY_FREE`, in the diagnosis's bus-to-bus ranges,
  :data:`ebus_env.diagnostics.ladder.NUISANCE`) are fitted on the bus's last ``cross_days``
  finished days together, from its last values.

Each fit is stored with the time it was made and the interval of data it used, so a bus's
parameter history (capacity fade as RCD, auxiliary base load, rolling resistance, drivetrain
efficiency) is the sequence of its fits.
"""

from __future__ import annotations

import json
import tempfile
import time
from functools import lru_cache
from pathlib import Path

import numpy as np
import pandas as pd
import sqlalchemy as sa

from ebus_env.twin.store import fits, service_days

WINDOW_FREE = ("passenger_load.load_frac", "cabin_hvac.setpoint_degc", "static_rcd.rcd_frac",
               "cccv_taper.cv_soc_pct", "grid_charger.power_kw",
               "regen_cutoff.cutoff_speed_mps", "auxiliaries.base_power_w")
"""The window re-fit's free parameters: the paper's (without the CV decay, which a day of
opportunity charging to a stop SoC rarely shows) and the auxiliary base load."""
CROSS_DAY_FREE = ("static_rcd.rcd_frac", "auxiliaries.base_power_w",
                  "rolling_resistance.rolling_coef", "efficiency_map.gearbox_efficiency",
                  "rint_battery.cell_capacity_ah", "vehicle_body.curb_mass_kg")
HISTORY = {"static_rcd.rcd_frac": "capacity fade (RCD)",
           "auxiliaries.base_power_w": "auxiliary base load",
           "rolling_resistance.rolling_coef": "rolling resistance",
           "efficiency_map.gearbox_efficiency": "drivetrain efficiency"}
MIN_PROFILE_S = 1800.0
"""Segments shorter than this (between two gaps of the data) are left out of a fit: shorter
than one window of the windowed tuning."""


@lru_cache(maxsize=8)
def bus_model(bus_config: str, dt_s: float):
    """The compiled model every bus starts from (one per process)."""
    from ebus_env.config import load_bus

    return load_bus(bus_config).build(dt_s)


def profiles_of(frame: pd.DataFrame, dt_s: float, name: str) -> list:
    """Profiles of stored samples (``t`` UTC epoch s and canonical columns), read by the
    project's log loader (gaps longer than 10 s split the data), segments of at least
    :data:`MIN_PROFILE_S` with a SoC."""
    from ebus_env.io.measured import load_log

    if len(frame) < 2:
        return []
    table = frame.drop(columns=[c for c in frame.columns if frame[c].isna().all()])
    table = table.assign(t=pd.to_datetime(table["t"], unit="s")).rename(
        columns={"t": "timestamp"})
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"{name}.parquet"
        table.to_parquet(path, index=False)
        log = load_log(path, dt_s, gaps="split", fill="interpolate", name=name)
    return [p for p in log.profiles
            if p.duration_s >= MIN_PROFILE_S and len(p.sample_rows("soc_frac")) > 10]


def latest_values(twin, bus_id: int, before_t: float | None = None) -> dict:
    """The bus's newest fitted values: its last cross-day fit, overlaid with any window fit
    made after it."""
    with twin.store.engine.connect() as conn:
        query = sa.select(fits).where(fits.c.bus_id == bus_id).order_by(fits.c.id)
        if before_t is not None:
            query = query.where(fits.c.t_to <= before_t)
        rows = conn.execute(query).all()
    values: dict[str, float] = {}
    for row in rows:
        values.update(json.loads(row.fit_values))
    return values


def _store_fit(twin, bus_id: int, kind: str, t_from: float, t_to: float, result: dict) -> None:
    with twin.store.engine.begin() as conn:
        conn.execute(fits.insert().values(
            bus_id=bus_id, kind=kind, fitted_at=twin.clock(), t_from=t_from, t_to=t_to,
            fit_values=json.dumps(result["values"]), nrmse=result["nrmse"],
            wall_s=result["wall_s"]))


def fit_task(frames: list[pd.DataFrame], free: tuple[str, ...], start: dict, windowed: bool,
             bus_config: str, dt_s: float, seed: int = 0) -> dict | None:
    """One fit (run here or as a Ray task): the profiles of ``frames``, ``free`` parameters
    from ``start``. Returns the fitted values, the NRMSE and the wall time, or None when the
    data hold no profile long enough."""
    from ebus_env.calibration import ISOPTSettings, calibrate
    from ebus_env.calibration.windowed import WindowSettings
    from ebus_env.diagnostics.ladder import nuisance_ranges

    model = bus_model(bus_config, dt_s)
    profiles = [p for i, f in enumerate(frames) for p in profiles_of(f, dt_s, f"part{i}")]
    if not profiles or sum(p.duration_s for p in profiles) < 3600.0:
        return None
    names = [n for n in (model.equivalent(f) for f in free) if n is not None]
    bounds = {k: v for k, v in nuisance_ranges(model, profiles).items() if k in names}
    # the bus's other fitted values are held: a fit moves its own parameters only
    fixed = {k: v for k, v in start.items() if k not in names}
    t0 = time.perf_counter()
    if windowed:
        result = calibrate(model, profiles, names, bounds=bounds, windowed=True, fixed=fixed,
                           start=[start] if start else (), polish_starts=0,
                           settings=ISOPTSettings(seed=seed),
                           window_settings=WindowSettings(min_window_min=30.0))
    else:
        result = calibrate(model, profiles, names, bounds=bounds, fixed=fixed,
                           start=[start] if start else (), polish_starts=1,
                           settings=ISOPTSettings(seed=seed, iterations=8))
    return {"values": {k: float(v) for k, v in result.values.items()},
            "nrmse": float(result.fit["nrmse"]), "wall_s": time.perf_counter() - t0}


def open_day_start(twin, bus_id: int) -> float:
    """The start of the bus's open (unfinished) day: after its last finished day."""
    with twin.store.engine.connect() as conn:
        end = conn.execute(sa.select(sa.func.max(service_days.c.t_end))
                           .where(service_days.c.bus_id == bus_id)).scalar()
    return -np.inf if end is None else float(end)


def maybe_refit(twin, bus: str, settings, runner=None) -> dict | None:
    """A window re-fit of ``bus``'s open day when ``refit_every_min`` of new data came."""
    bus_id = twin.bus_id(bus)
    start = open_day_start(twin, bus_id)
    with twin.store.engine.connect() as conn:
        last_fit = conn.execute(sa.select(sa.func.max(fits.c.t_to)).where(
            fits.c.bus_id == bus_id, fits.c.kind == "window")).scalar()
    frame = twin.samples(bus, t_from=start + 1e-3 if np.isfinite(start) else -np.inf)
    if len(frame) < 2:
        return None
    t_last = float(frame["t"].iloc[-1])
    since = max(float(frame["t"].iloc[0]), last_fit or -np.inf)
    if t_last - since < 60.0 * settings.refit_every_min:
        return None
    run = runner or (lambda fn, *a: fn(*a))
    result = run(fit_task, [frame], WINDOW_FREE, latest_values(twin, bus_id), True,
                 settings.bus_config, settings.dt_s)
    if result is not None:
        _store_fit(twin, bus_id, "window", float(frame["t"].iloc[0]), t_last, result)
    return result


def cross_day_fit(twin, bus: str, day: str, settings, runner=None) -> dict | None:
    """The bus-to-bus parameters on the bus's last ``cross_days`` finished days."""
    bus_id = twin.bus_id(bus)
    with twin.store.engine.connect() as conn:
        days = conn.execute(sa.select(service_days.c.t_start, service_days.c.t_end).where(
            service_days.c.bus_id == bus_id, service_days.c.day <= day)
            .order_by(service_days.c.day.desc()).limit(settings.cross_days)).all()
    frames = [twin.samples(bus, a, b) for a, b in reversed(days)]
    run = runner or (lambda fn, *a: fn(*a))
    result = run(fit_task, frames, CROSS_DAY_FREE, latest_values(twin, bus_id), False,
                 settings.bus_config, settings.dt_s)
    if result is not None:
        _store_fit(twin, bus_id, "cross-day", float(days[-1].t_start), float(days[0].t_end),
                   result)
    return result
