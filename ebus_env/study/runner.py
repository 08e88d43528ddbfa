"""One scenario of a study: every line's buses through each seeded day at one site.

The buses are the environments' compiled batches (:class:`ebus_env.envs.batch.BusBatch`, one
per line) at one :class:`ebus_env.envs.charging_site.ChargingSite`, the site step that
``EBusFleet-v0`` takes too: each decision the terminal's plugs and grid limit are shared row
by row at 10 Hz (first come, first served at a busy charger, ratings scaled together to the
site limit). After service the depot recharges
every bus to its start SoC on the depot chargers, behind the same site limit. All scenarios
see the same days (common random numbers), so differences between them are not noise.
"""

from __future__ import annotations

import importlib
import math
import threading

import numba
import numpy as np

from ebus_env.envs.batch import ELAPSED_ROWS, OUT, BusBatch
from ebus_env.envs.charging_site import ChargingSite
from ebus_env.envs.common import ACTIONS, physical
from ebus_env.errors import ConfigError
from ebus_env.study.costs import add_costs
from ebus_env.study.scenarios import Scenario
from ebus_env.study.study_file import StudySpec

SPEED_CAP = [a.name for a in ACTIONS].index("speed_cap_kmh")
DISTANCE_KM, EMPTY = OUT.index("distance_km"), OUT.index("empty")


_BUILD = threading.Lock()  # models are built (compiled or loaded) one at a time
# Idle batches of finished scenarios, by (env config, buses): a later scenario with the same
# line config (most of a study's grid: only the charger rating and decision_s reach the bus
# config) takes one instead of building its model again. Every day resets all its buses.
_IDLE: dict[tuple[str, int], list[BusBatch]] = {}
MAX_IDLE = 64


def take_batch(cfg, n: int) -> BusBatch:
    """A batch of ``n`` buses of the env config ``cfg``: an idle one, else a new one."""
    with _BUILD:
        idle = _IDLE.get((repr(cfg), n))
        return idle.pop() if idle else BusBatch(cfg, n)


def forget_batches() -> None:
    """Drop the idle batches (a new study reads its bus and cycle files afresh)."""
    with _BUILD:
        _IDLE.clear()


class Site:
    """The buses of every line of a study under one scenario's chargers and strategy."""

    def __init__(self, spec: StudySpec, scenario: Scenario):
        self.spec, self.scenario = spec, scenario
        infra, strategy = scenario.infrastructure, scenario.strategy
        self.lines = []
        for line in spec.lines:
            batch = take_batch(spec.env_config(line, infra, strategy), line.buses)
            period_s = batch.lap_period_s / line.buses if line.headway_min is None \
                else 60.0 * line.headway_min
            batch.offsets_s = np.arange(line.buses) * period_s
            self.lines.append(batch)
        self.site = ChargingSite(self.lines, infra.terminal_chargers, infra.site_limit_kw)
        self.cfg = self.lines[0].config
        self.n = self.site.n
        self.settings = np.array([v for _, v in strategy.settings])
        self.policy = policy(strategy.policy, strategy.policy_args) if strategy.policy else None

    def close(self) -> None:
        """Leave the batches idle for a later scenario (:func:`take_batch`)."""
        with _BUILD:
            for batch in self.lines:
                if sum(map(len, _IDLE.values())) < MAX_IDLE:
                    _IDLE.setdefault((repr(batch.config), batch.n), []).append(batch)
        self.lines = []

    def day(self, day: int) -> dict:
        """Simulate one seeded day; the row of results (before costs)."""
        spec, infra, cfg = self.spec, self.scenario.infrastructure, self.cfg
        rng = np.random.default_rng([spec.days.seed, day])
        values = np.tile(self.settings, (self.n, 1))
        site = self.site
        site.reset(rng)
        # traffic: each bus's top speed that day, lowered by up to traffic_random_frac
        slow = 1.0 - rng.uniform(0.0, spec.days.traffic_random_frac, self.n)
        step_s = cfg.decision_s
        n_steps = math.ceil(cfg.service_h * 3600.0 / step_s - 1e-9)
        site_kw = np.zeros(n_steps)
        lowest_soc = np.full(self.n, cfg.soc_start_pct / 100.0)
        net_kwh = np.zeros(self.n)  # battery chemical energy, net (what the depot restores)
        discharged_kwh = np.zeros(self.n)
        distance_km = np.zeros(self.n)
        empty_left_h = np.full(self.n, np.nan)
        lines, starts = self.lines, self.site.edges[:-1]
        for k in range(n_steps):
            if self.policy is not None or k == 0:  # fixed settings: the same every decision
                if self.policy is not None:
                    values = physical(np.clip(np.asarray(self.policy.predict(
                        site.observations(), deterministic=True)[0], float).reshape(
                            self.n, len(ACTIONS)), -1, 1))
                v = values.copy()
                v[:, SPEED_CAP] = np.maximum(v[:, SPEED_CAP] * slow, ACTIONS[SPEED_CAP].low)
            site.step(v)
            site_kw[k] = site.column("grid_kwh").sum() / (step_s / 3600.0)
            ended = True
            for batch, lo in zip(lines, starts, strict=True):
                ended &= _tally(batch.out, batch.quantities, batch.obs, batch.book, lo,
                                batch.service_rows, cfg.service_h, cfg.dt_s, net_kwh,
                                discharged_kwh, distance_km, lowest_soc, empty_left_h)
            if ended:
                site_kw = site_kw[:k + 1]
                break
        dt_s = cfg.dt_s
        depot_kw, not_recharged, depot_busy_h = depot(
            np.maximum(net_kwh, 0.0) / site.efficiency, infra.depot_chargers,
            infra.depot_charger_kw, infra.site_limit_kw, step_s / 3600.0,
            24.0 - len(site_kw) * step_s / 3600.0)
        load_kw = np.concatenate([site_kw, depot_kw])
        blocks = int(900.0 // step_s)
        whole = len(load_kw) // blocks * blocks
        service_rows = cfg.service_h * 3600.0 / dt_s
        return {
            "buses": self.n,
            "distance_km": float(distance_km.sum()),
            "battery_discharged_kwh": float(discharged_kwh.sum()),
            "terminal_grid_kwh": float(site_kw.sum() * step_s / 3600.0),
            "depot_grid_kwh": float(depot_kw.sum() * step_s / 3600.0),
            "grid_kwh": float(load_kw.sum() * step_s / 3600.0),
            "site_peak_kw": float(load_kw.max()),
            "site_peak_15min_kw": float(load_kw[:whole].reshape(-1, blocks).mean(axis=1).max()),
            "lowest_soc_pct": float(100.0 * lowest_soc.min()),
            "buses_short": int(np.isfinite(empty_left_h).sum()),
            "buses_below_reserve": int((100.0 * lowest_soc < cfg.reserve_soc_pct).sum()),
            "buses_not_recharged": int(not_recharged),
            "service_hours_lost": float(np.nansum(empty_left_h)),
            "charger_utilisation": site.held_rows / (max(infra.terminal_chargers, 1)
                                                     * service_rows),
            "charger_wait_bus_h": site.waited_rows * dt_s / 3600.0,
            "depot_utilisation": depot_busy_h / max(infra.depot_chargers, 1)
            / (24.0 - cfg.service_h),
            "load_step_s": step_s,
            "site_load_kw": load_kw,
        }


@numba.njit(cache=True, nogil=True)
def _tally(out, quantities, obs, book, lo, service_rows, service_h, dt_s, net_kwh,
           discharged_kwh, distance_km, lowest_soc, empty_left_h) -> bool:
    """Add a line's decision to the day's sums per bus (the line's buses from ``lo`` of the
    site): chemical energy net and discharged [kWh], distance [km], lowest SoC, and the
    service hours left when a bus first ran empty. True when every bus has ended service."""
    ended = True
    for b in range(out.shape[0]):
        i = lo + b
        chem_kwh = quantities[b, 0]
        net_kwh[i] += chem_kwh
        discharged_kwh[i] += max(chem_kwh, 0.0)
        distance_km[i] += out[b, DISTANCE_KM]
        lowest_soc[i] = min(lowest_soc[i], obs[b, 0])
        if out[b, EMPTY] > 0.0 and math.isnan(empty_left_h[i]):
            empty_left_h[i] = max(service_h - book[b, ELAPSED_ROWS] * dt_s / 3600.0, 0.0)
        ended &= book[b, ELAPSED_ROWS] >= service_rows - 0.5
    return ended


def depot(energy_kwh: np.ndarray, chargers: int, charger_kw: float, limit_kw: float,
          step_h: float, window_h: float) -> tuple[np.ndarray, int, float]:
    """Overnight depot charging: each bus's grid energy ``energy_kwh`` on ``chargers`` plugs of
    ``charger_kw``, first come (bus order) first served, their total draw scaled to
    ``limit_kw``, in steps of ``step_h`` over ``window_h``. Returns the depot's mean power per
    step [kW], the buses not fully recharged in the window, and the plug-hours used."""
    n_steps = max(int(round(window_h / step_h)), 0)
    left = np.array(energy_kwh, float)
    load = np.zeros(n_steps)
    busy_h = 0.0
    for k in range(n_steps):
        queue = np.flatnonzero(left > 1e-9)[:chargers]
        if queue.size == 0:
            break
        scale = min(1.0, limit_kw / (queue.size * charger_kw))
        take = np.minimum(left[queue], charger_kw * scale * step_h)
        left[queue] -= take
        load[k] = take.sum() / step_h
        busy_h += queue.size * step_h
    return load, int((left > 1e-6).sum()), busy_h


def run_scenario(spec: StudySpec, scenario: Scenario, days: list[int] | None = None
                 ) -> list[dict]:
    """The ``days`` (default: every day) of ``scenario``: one row each, with the costs per
    km."""
    if spec.gtfs is not None:  # a timetable: the network's blocks (ebus_env.study.network)
        from ebus_env.study.network import network_rows

        return network_rows(spec, scenario, list(range(spec.days.count)) if days is None
                            else days)
    site = Site(spec, scenario)
    infra, costs = scenario.infrastructure, spec.costs
    rows = []
    try:
        for day in range(spec.days.count) if days is None else days:
            row = site.day(day)
            cost = costs.day(row["site_load_kw"], row["load_step_s"] / 3600.0,
                             site.cfg.start_time_h, row["site_peak_15min_kw"],
                             infra.installed_kw, row["battery_discharged_kwh"])
            add_costs(row, cost)
            rows.append({**scenario.columns(), "day": day, **row})
    finally:
        site.close()
    return rows


def policy(target: str, kwargs: dict | None = None):
    """A policy object from ``module:factory`` called with ``kwargs`` (or ``module:object``):
    anything with ``predict(obs, deterministic=True)`` returning (actions in [-1, 1] of shape
    (buses, 5), state) on ``EBus-v0`` observations, one row per bus, such as the rule baselines
    and stable-baselines3 models trained on ``EBus-v0`` (the package never imports them
    itself: the study file names them)."""
    module, _, name = target.partition(":")
    try:
        found = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as e:
        raise ConfigError(f"policy {target!r}: {e}. Give 'module:factory' of an importable "
                          "module.") from None
    made = found if hasattr(found, "predict") else found(**(kwargs or {}))
    if not hasattr(made, "predict"):
        raise ConfigError(f"policy {target!r} gives no object with predict(obs, "
                          "deterministic=True).")
    return made
