"""A model per bus that tunes itself as its data come in.

* **Window re-fit** (while the bus runs its day): once ``refit_every_min`` of new data have
  come, the bus's estimate is refined on its day so far from its last fit: the step the
  windowed tuning of :mod:`ebus_env.calibration.windowed` makes after each window (a few
  Levenberg-Marquardt iterations from the previous estimate on all data up to the window's
  end), freeing what changes from day to day (:data:`WINDOW_FREE`). A bus with no fit yet
  gets the windowed tuning's first window, a global iSOPT search.
* **Cross-day fit** (when a day is finished): the bus-to-bus parameters
  (:data:`CROSS_DAY_FREE`: the diagnosis's, :data:`ebus_env.diagnostics.ladder.NUISANCE`, in
  its search ranges, with the capacity fade and the pack's charge acceptance) are fitted on the
  bus's last ``cross_days`` finished days together: by a global iSOPT search the first time,
  then by Levenberg-Marquardt from the bus's last values (the first fit finds the pack's
  cells, the later ones the fade since: :data:`FADE`). Where the days' logs give the
  charger's rating and the bus charges at it (:data:`MIN_RATED_SOC_PCT`), the share of it the
  charger delivers is fitted with them: a rating stated on the grid side delivers the
  charger's efficiency of it, and held at all of it the fit would bend the pack's capacity
  and resistance to the SoC's slower rise.
  The SoC at which the bus's charger sessions end by themselves, the pack's charge ceiling
  (:func:`charge_ceiling`), is read from the same days.

Each fit is stored with the time it was made and the interval of data it used, so a bus's
parameter history (capacity fade as RCD, auxiliary base load, rolling resistance, drivetrain
efficiency) is the sequence of its fits.
"""

from __future__ import annotations

import json
import tempfile
import time
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import sqlalchemy as sa

from ebus_env.calibration.problem import CHARGER_SHARE, logs_rating
from ebus_env.twin.store import fits, service_days

if TYPE_CHECKING:
    from ebus_env.model.model import Model
    from ebus_env.profile import Profile

WINDOW_FREE = ("passenger_load.load_frac", "cabin_hvac.setpoint_degc",
               "auxiliaries.base_power_w", "regen_cutoff.cutoff_speed_mps")
"""The window re-fit's free parameters: what changes from day to day and within one
(passengers, the cabin's setpoint, the loads, the regenerative braking's cut-off)."""
CROSS_DAY_FREE = ("vehicle_body.curb_mass_kg", "rolling_resistance.rolling_coef",
                  "auxiliaries.base_power_w", "efficiency_map.gearbox_efficiency",
                  "rint_battery.cell_capacity_ah", "rint_battery.cell_resistance_mohm",
                  "regen_cutoff.max_decel_mps2", "static_rcd.rcd_frac",
                  "rint_battery.max_charge_c_rate", "cccv_taper.cv_soc_pct", CHARGER_SHARE)
"""The cross-day fit's free parameters: the bus-to-bus ones of the diagnosis
(:data:`~ebus_env.diagnostics.ladder.NUISANCE`), the capacity fade, the pack's charge
acceptance (its C-rate limit and where its CV taper starts) and the share of its stated
rating the charger delivers (only where the days charge at a logged rating:
:data:`MIN_RATED_SOC_PCT`)."""
FADE = ("rint_battery.cell_capacity_ah", "static_rcd.rcd_frac")
"""A pack's cells and its fade, which SoC data see only as their product Q (1 - RCD): the
bus's first cross-day fit finds the cells as the pack is then (its fade held), each later fit
holds them and finds the fade since (the bus page's capacity-fade history). Both free, any
split of the product fits, and the history would wander with the search."""
HISTORY = {"static_rcd.rcd_frac": "capacity fade (RCD)",
           "auxiliaries.base_power_w": "auxiliary base load",
           "rolling_resistance.rolling_coef": "rolling resistance",
           "efficiency_map.gearbox_efficiency": "drivetrain efficiency"}
MIN_PROFILE_S = 1800.0
"""Segments shorter than this (between two gaps of the data) are left out of a fit: shorter
than one window of the windowed tuning."""
WINDOW_ITERATIONS = 5
"""Levenberg-Marquardt iterations of a window re-fit (the windowed tuning's own)."""
CEILING = "rint_battery.soc_max_frac"
SESSION_END_S = 60.0
"""A charger session that ends this long [s] before the bus moves ended by itself (the BMS's
ceiling), not because the bus left."""
MIN_RATED_SOC_PCT = 10.0
"""The SoC points [%] the days' charging at the charger's logged rating must move, in the bus's
model at its last values, for the share of the rating the charger delivers to be fitted: the
share's range (:data:`~ebus_env.diagnostics.power.DELIVERED_RANGE`) then moves them by 1.7
points, 17 steps of a BMS's 0.1 %. With less it keeps its last value, as the power path keeps
it with fewer than :data:`~ebus_env.diagnostics.power_fit.MIN_RATED_BINS` bins at the rating
(a minute, which a power log resolves and a SoC log does not: the share's range moves a
minute at 150 kW by 0.2 points of a 200 kWh pack)."""


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
    """The bus's newest fitted values: its fits in order, each overlaying the ones before
    (a window fit moves only its own parameters)."""
    with twin.store.engine.connect() as conn:
        query = sa.select(fits).where(fits.c.bus_id == bus_id).order_by(fits.c.id)
        if before_t is not None:
            query = query.where(fits.c.t_to <= before_t)
        rows = conn.execute(query).all()
    values: dict[str, float] = {}
    for row in rows:
        values.update(json.loads(row.fit_values))
    return values


def charge_ceiling(frames: list[pd.DataFrame]) -> float | None:
    """The SoC [0-1] at which the bus's charger sessions end by themselves: the median of
    the SoC at the end of each session that ended :data:`SESSION_END_S` or more before the
    bus moved again (a BMS or charger stop SoC); None when no session did."""
    ends = []
    for frame in frames:
        if "charging" not in frame or frame["charging"].isna().all() or len(frame) < 3:
            continue
        t = frame["t"].to_numpy(float)
        on = np.nan_to_num(frame["charging"].to_numpy(float)) > 0.5
        soc = frame["soc_pct"].to_numpy(float)
        moving_t = t[frame["speed_kmh"].to_numpy(float) > 1.0]
        for i in np.flatnonzero(on[:-1] & ~on[1:]):
            k = np.searchsorted(moving_t, t[i])
            if k < len(moving_t) and moving_t[k] - t[i] >= SESSION_END_S \
                    and np.isfinite(soc[i]):
                ends.append(soc[i])
    return float(np.median(ends)) / 100.0 if ends else None


def rated_rise_pct(model: Model, profiles: Sequence[Profile], values: dict) -> float:
    """The SoC points [%] the charging at the logs' charger rating moves in ``model`` at
    ``values`` (its charger at the share of the rating it delivers, the pack not the limit):
    where the share shows in the SoC. 0 when a log charges without the rating (the charger's
    configured power sets it there, and the share would scale that too)."""
    share = model.equivalent(CHARGER_SHARE)
    if share is None:
        return 0.0
    params = model.param_vector(model.carry_over(values))
    rise_pct = 0.0
    for p in profiles:
        connected = p.channels.get("charger_connected")
        if connected is None or not np.any(connected > 0.5):
            continue
        if not logs_rating(p):
            return 0.0
        run = model.simulate_batch(p, params[None, :], record=("charger_power_w", "soc_frac"),
                                   record_every=1)
        rated_w = params[model.param_index(share)] * p.channels["charger_rating_w"]
        at = (connected > 0.5) & np.isclose(run.record("charger_power_w")[0], rated_w,
                                            rtol=1e-5)
        rise_pct += 100.0 * float(np.diff(run.record("soc_frac")[0])[at[1:]].clip(0.0).sum())
    return rise_pct


def _store_fit(twin, bus_id: int, kind: str, t_from: float, t_to: float, result: dict) -> None:
    with twin.store.engine.begin() as conn:
        conn.execute(fits.insert().values(
            bus_id=bus_id, kind=kind, fitted_at=twin.clock(), t_from=t_from, t_to=t_to,
            fit_values=json.dumps(result["values"]), nrmse=result["nrmse"],
            wall_s=result["wall_s"]))


def fit_task(frames: list[pd.DataFrame], free: tuple[str, ...], start: dict, local: bool,
             bus_config: str, dt_s: float, seed: int = 0,
             iterations: int = WINDOW_ITERATIONS) -> dict | None:
    """One fit (run here or as a Ray task): the profiles of ``frames``, ``free`` parameters
    from ``start`` (the bus's other values held). ``local``: the windowed tuning's step,
    Levenberg-Marquardt from ``start`` (never ends worse than it); else iSOPT seeded with
    ``start``, then a polish. Returns the fitted values, the NRMSE and the wall time, or None
    when the data hold no profile long enough.

    The share of its rating a charger delivers (fitted where :func:`rated_rise_pct` reaches
    :data:`MIN_RATED_SOC_PCT`) is searched from the best fit without it, a second search
    (iSOPT keeps its best: it ends no worse than the share held): it moves the SoC only while
    the bus charges at the rating, nearly as the pack's resistance does, and one search of all
    the parameters wandered (on the shipped fleet's bus-01, two seeds of three ended 1.25-2.7
    times the NRMSE of the search without it)."""
    from ebus_env.calibration import ISOPTSettings, calibrate
    from ebus_env.calibration.local import polish
    from ebus_env.calibration.problem import CalibrationProblem
    from ebus_env.diagnostics.ladder import nuisance_ranges
    from ebus_env.diagnostics.power_fit import search_box

    model = bus_model(bus_config, dt_s)
    profiles = [p for i, f in enumerate(frames) for p in profiles_of(f, dt_s, f"part{i}")]
    if not profiles or sum(p.duration_s for p in profiles) < 3600.0:
        return None
    names = [n for n in (model.equivalent(f) for f in free) if n is not None]
    cells, fade = (model.equivalent(n) for n in FADE)
    if cells in names and fade in names:  # the first fit the cells, the later ones the fade
        names.remove(cells if local else fade)
    bounds = {k: v for k, v in nuisance_ranges(model, profiles).items() if k in names}
    t0 = time.perf_counter()
    share = model.equivalent(CHARGER_SHARE)
    if share in names:  # in the power path's range, where the days charge at a logged rating
        if rated_rise_pct(model, profiles, start) < MIN_RATED_SOC_PCT:
            names.remove(share)
        else:
            bounds[share] = search_box(model)[share]
    fixed = {k: v for k, v in start.items() if k not in names}
    if local:
        problem = CalibrationProblem(model, profiles, names, bounds, fixed)
        points, nrmse, _ = polish(problem, problem.points([start]), iterations=iterations)
        values, cost = problem.named(points[0]), float(nrmse[0])
    else:
        starts = [start] if start else []
        stages = [[n for n in names if n != share], names] if share in names else [names]
        for searched in stages:
            result = calibrate(model, profiles, searched,
                               bounds={k: v for k, v in bounds.items() if k in searched},
                               fixed=fixed, start=starts, polish_starts=1,
                               settings=ISOPTSettings(seed=seed, iterations=8))
            starts = [{**start, **result.values}]
        values, cost = result.values, float(result.fit["nrmse"])
    out = {k: float(v) for k, v in values.items()}
    if "rint_battery.max_charge_c_rate" in names:  # the cross-day fit: the pack's ceiling too
        ceiling = charge_ceiling(frames)
        if ceiling is not None:
            out[CEILING] = float(np.clip(ceiling, 0.7, 1.0))
    return {"values": out, "nrmse": cost, "wall_s": time.perf_counter() - t0}


def open_day_start(twin, bus_id: int) -> float:
    """The end of the bus's last finished day (-inf before its first)."""
    with twin.store.engine.connect() as conn:
        end = conn.execute(sa.select(sa.func.max(service_days.c.t_end))
                           .where(service_days.c.bus_id == bus_id)).scalar()
    return -np.inf if end is None else float(end)


def maybe_refit(twin, bus: str, settings, runner=None) -> dict | None:
    """A window re-fit of ``bus``'s day so far when ``refit_every_min`` of new data came."""
    from ebus_env.depot.service_days import service_days as cut_days
    from ebus_env.twin.closed_days import day_rule

    bus_id = twin.bus_id(bus)
    start = open_day_start(twin, bus_id)
    with twin.store.engine.connect() as conn:
        last_fit = conn.execute(sa.select(sa.func.max(fits.c.t_to)).where(
            fits.c.bus_id == bus_id, fits.c.kind == "window")).scalar()
    frame = twin.samples(bus, t_from=start + 1e-3 if np.isfinite(start) else -np.inf)
    if len(frame) < 2:
        return None
    t = frame["t"].to_numpy(float)
    days = cut_days(t, frame["speed_kmh"].to_numpy(float), day_rule(settings.day_end_idle_min))
    if not days:
        return None
    frame = frame[frame["t"] >= days[-1][0]]  # today's run: not the last day's depot tail
    t_last = float(frame["t"].iloc[-1])
    since = max(float(frame["t"].iloc[0]), last_fit or -np.inf)
    if t_last - since < 60.0 * settings.refit_every_min:
        return None
    run = runner or (lambda fn, *a: fn(*a))
    values = latest_values(twin, bus_id)
    result = run(fit_task, [frame], WINDOW_FREE, values, bool(values), settings.bus_config,
                 settings.dt_s)
    if result is not None:
        _store_fit(twin, bus_id, "window", float(frame["t"].iloc[0]), t_last, result)
    return result


def cross_day_fit(twin, bus: str, day: str, settings, runner=None) -> dict | None:
    """The bus-to-bus parameters on the bus's last ``cross_days`` finished days: a global
    search the first time, then refined from the bus's last values (they drift slowly: a
    pack's fade, a tyre's wear)."""
    bus_id = twin.bus_id(bus)
    with twin.store.engine.connect() as conn:
        days = conn.execute(sa.select(service_days.c.t_start, service_days.c.t_end).where(
            service_days.c.bus_id == bus_id, service_days.c.day <= day)
            .order_by(service_days.c.day.desc()).limit(settings.cross_days)).all()
        searched = conn.execute(sa.select(sa.func.count()).select_from(fits).where(
            fits.c.bus_id == bus_id, fits.c.kind == "cross-day")).scalar()
    frames = [twin.samples(bus, a, b) for a, b in reversed(days)]
    run = runner or (lambda fn, *a: fn(*a))
    result = run(fit_task, frames, CROSS_DAY_FREE, latest_values(twin, bus_id),
                 bool(searched), settings.bus_config, settings.dt_s)
    if result is not None:
        _store_fit(twin, bus_id, "cross-day", float(days[-1].t_start), float(days[0].t_end),
                   result)
    return result
