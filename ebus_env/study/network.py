"""A timetable's network day: every block through the bus model at 10 Hz, the terminals'
plugs shared, the depot planned three ways, one row of results per depot plan.

A block drives its timetable (:mod:`ebus_env.blocks`): whether it finds a plug at a terminal
does not change when it drives, only how much it charges. So each terminal's plugs are
shared over the timetable's layovers before the physics runs, by the site step's rule
(:func:`ebus_env.envs.charging_site.share_plugs`: first come, first served; on a 1-s grid),
and then every block runs on its own through the model's compiled loop, blocks split over
threads. The blocks of a day are coupled through the chargers: the unit of parallel work
across processes (Ray) is a day or a scenario, never a block.

Each block starts the day at ``soc_start_pct``. Its SoC is recorded every second: the lowest,
when and where, the end SoC, and when the pack ran empty away from a charger (the model's
``stranded_at``: its BMS opened at ``soc_min_frac``): from there on the bus is stranded, its
day ends there and its remaining trips are not served. The depot then gives each bus what its
block needs on the next day plus ``reserve_soc_pct`` (``E_b = (min(soc_max, used_b + reserve)
- soc_end_b) x the pack's kWh per unit SoC``), planned by :mod:`ebus_env.study.depot_plan`.
Load curves are folded onto one day (a trip past 24:00 loads the next morning's hour: the
same day repeated).
"""

from __future__ import annotations

import json
import math
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numba
import numpy as np

from ebus_env.blocks import Block, Charger, drive_rows, plan, where
from ebus_env.envs.batch import ambient_degc, passengers
from ebus_env.envs.charging_site import share_plugs
from ebus_env.errors import ConfigError
from ebus_env.model.results import battery_energy_j
from ebus_env.study import depot_plan
from ebus_env.study.costs import add_costs
from ebus_env.units import J_PER_KWH

DT_S = 0.1
DAY_S = 86400
RECORD = ("grid_power_w", "soc_frac")  # sampled every second
EVERY = 10  # rows (1 s at 10 Hz)
COARSE = 100  # rows between evaluations of the day's ambient and passenger load (10 s)


@dataclass
class BlockDay:
    """One block's day: figures per block (kWh, km, SoC in [0, 1])."""

    block_id: str
    trips: int
    distance_km: float
    discharged_kwh: float
    net_kwh: float
    soc_end: float
    lowest_soc: float
    lowest_at_s: float
    lowest_where: str
    empty_at_s: float  # NaN: never ran empty
    not_served: list
    terminal_kwh: float
    arrive_s: float
    depart_next_s: float
    layover_charger_h: float  # time on layovers at stops with a charger


@numba.njit(cache=True, nogil=True)
def _day_rows(mean_degc, amplitude_k, capacity, base, peak, hour0, dt_s, ambient, people,
              fill):
    """Ambient [degC] and, where ``fill`` (no trip count), passengers by hour, row by row."""
    for i in range(len(ambient)):
        hour = (hour0 + i * dt_s / 3600.0) % 24.0
        ambient[i] = ambient_degc(mean_degc, amplitude_k, hour)
        if fill[i]:
            people[i] = passengers(capacity, base, peak, hour)


def _share_terminals(blocks: list[Block], efficiency: float) -> tuple[dict, float, float]:
    """Each terminal's plugs shared over the blocks' layovers on a 1-s grid: per block, the
    (start s, 1-s ratings [W], NaN without a plug) of each terminal it lays over at; and the
    bus-seconds on a plug and those that asked for one."""
    visits: dict[str, list] = {}
    for i, block in enumerate(blocks):
        for lay in block.layovers():
            if lay.charger is not None and lay.duration_s > 0:
                visits.setdefault(lay.stop_id, []).append((i, lay))
    out: dict[int, list] = {}
    held = wanted = 0.0
    for seen in visits.values():
        charger: Charger = seen[0][1].charger
        t0 = int(math.floor(min(lay.start_s for _, lay in seen)))
        t1 = int(math.ceil(max(lay.end_s for _, lay in seen)))
        buses = sorted({i for i, _ in seen})
        row = {b: k for k, b in enumerate(buses)}
        connected = np.zeros((len(buses), t1 - t0))
        for i, lay in seen:
            connected[row[i], int(math.ceil(lay.start_s)) - t0:int(math.floor(lay.end_s)) - t0] = 1
        rating = np.where(connected > 0, 1e3 * charger.power_kw, np.nan)
        plugged, shared = share_plugs(connected, rating, np.full(len(buses), efficiency),
                                      charger.count)
        held += float(plugged.sum())
        wanted += float(connected.sum())
        for i in buses:
            out.setdefault(i, []).append((t0, shared[row[i]]))
    return out, held, wanted


def _one_block(block: Block, model, params, soc_start: float, day: dict, shared: list,
               capacity: float, efficiency: float) -> tuple[BlockDay, np.ndarray, np.ndarray]:
    """Run one block; its figures and its 1-s grid power [kW] (from its first row)."""
    p = plan(block)
    n = int(round((block.end_s - block.start_s) / DT_S)) + 1
    rows = drive_rows(block, 0, n, DT_S, 0.0, p)
    t = block.start_s + DT_S * np.arange(n)
    if shared:  # the terminal's share: no plug -> not connected
        on = rows["charger_connected"] > 0
        for t0, rating in shared:
            sec = np.clip(np.floor(t).astype(np.int64) - t0, 0, len(rating) - 1)
            inside = on & (t >= t0) & (t < t0 + len(rating))
            got = rating[sec]
            rows["charger_rating_w"] = np.where(inside, got, rows["charger_rating_w"])
            rows["charger_connected"] = np.where(inside & np.isnan(got), 0.0,
                                                 rows["charger_connected"])
    fill = np.ones(n, np.bool_)
    for trip in block.trips:
        if trip.passengers is not None or not trip.revenue:
            lo = int(np.ceil((trip.start_s - block.start_s) / DT_S))
            hi = int(np.ceil((trip.end_s - block.start_s) / DT_S))
            fill[max(lo, 0):max(hi, 0)] = False
    # the day's ambient and commuter loads change by the hour: evaluated every COARSE rows
    coarse = -(-n // COARSE)
    ambient, people = np.zeros(coarse), np.zeros(coarse)
    _day_rows(day["ambient_mean_degc"], day["ambient_amplitude_k"], capacity,
              day["passengers_base"], day["passengers_peak"], block.start_s / 3600.0,
              DT_S * COARSE, ambient, people, np.ones(coarse, np.bool_))
    rows["ambient_degc"] = np.repeat(ambient, COARSE)[:n]
    rows["passenger_count"] = np.where(fill, np.repeat(people, COARSE)[:n],
                                       rows["passenger_count"])
    if day["passengers_fixed"] is not None:
        rows["passenger_count"] = np.where(fill, day["passengers_fixed"],
                                           rows["passenger_count"])
    rows["time_of_day_h"] = (t / 3600.0) % 24.0
    rows["accel_ref_mps2"] = np.append(np.diff(rows["speed_ref_mps"]) / DT_S, 0.0)
    rows["door_open"] = ((rows["speed_ref_mps"] < 0.05) & (rows["charger_connected"] < 0.5)
                         ).astype(float)
    from ebus_env.signals import INPUTS

    inputs = np.stack([rows[name] if name in rows else np.full(n, INPUTS[name].default)
                       for name in model.input_names])
    first = {name: float(inputs[k, 0]) for k, name in enumerate(model.input_names)}
    states = model.initial_state(params, first, soc_start=soc_start)[None, :].copy()
    sel = np.array([model.trace_names.index(r) for r in RECORD], np.int64)
    trace = np.zeros((1, -(-n // EVERY), len(sel)), np.float32)
    acc = model.run(params[None, :], states, inputs, record_every=EVERY, record_sel=sel,
                    record_out=trace, threads=1)
    # the pack ran empty away from a charger (the model's stranded_at): the bus is stranded
    # there and its day ends (the timetable goes on without it)
    stranded_s = float(acc[0, model.accumulator_names.index("stranded_at")])
    empty = math.isfinite(stranded_s)
    if empty:
        n = min(int(stranded_s / DT_S) + 1, n)
        states = model.initial_state(params, first, soc_start=soc_start)[None, :].copy()
        trace = trace[:, :-(-n // EVERY)]
        acc = model.run(params[None, :], states, inputs[:, :n], record_every=EVERY,
                        record_sel=sel, record_out=trace, threads=1)
        t = t[:n]
    grid_w, soc = (trace[0, :, j].astype(float) for j in range(2))  # each second
    chem_kwh = float(battery_energy_j(model, acc)[1][0] / J_PER_KWH)
    empty_at = block.start_s + stranded_s if empty else math.nan
    lowest = int(np.argmin(soc))
    t_1s = t[::EVERY]
    not_served = [tr.trip_id for tr in block.trips if tr.revenue and empty
                  and tr.end_s > empty_at]
    grid_1s = grid_w / 1e3
    terminal_kwh = float(acc[0, model.accumulator_names.index("grid")] / J_PER_KWH)
    charger_h = sum(lay.duration_s for lay in block.layovers() if lay.charger) / 3600.0
    dist_km = float(states[0, model.state_names.index("distance_m")] / 1e3)
    # discharged: the net chemical energy plus what the terminals put in (throughput, for wear)
    discharged = max(chem_kwh + terminal_kwh * efficiency, 0.0)
    out = BlockDay(block.block_id, sum(tr.revenue for tr in block.trips), dist_km, discharged,
                   chem_kwh, float(soc[-1]), float(soc[lowest]), float(t_1s[lowest]),
                   where(block, float(t_1s[lowest]), p), empty_at, not_served, terminal_kwh,
                   float(block.end_s), float(block.start_s + DAY_S), charger_h)
    return out, grid_1s, soc


class NetworkStudy:
    """A timetable study's fixed part: the day's blocks, the bus model, the pack."""

    def __init__(self, network, bus, soc_start_pct: float, reserve_soc_pct: float,
                 terminals=()):
        from ebus_env.config import load_bus

        self.network, self.terminals = network, tuple(terminals)
        ends = {t.end_stop for b in network.blocks for t in b.trips}
        unknown = sorted(set(self.terminals) - ends)
        if unknown:
            raise ConfigError(f"gtfs.terminals {unknown}: no block of {network.date} lays over "
                              f"there; stops where blocks lay over include "
                              f"{', '.join(sorted(ends)[:8])}.")
        self.bus = load_bus(bus)
        self.model = self.bus.build(DT_S)
        self.params = self.model.params.copy()
        m = self.model
        self.soc_start = soc_start_pct / 100.0
        self.reserve = reserve_soc_pct / 100.0
        self.efficiency = float(self.params[m.handle("charger_efficiency")])

        def param(name, default):
            return float(self.params[m.param_names.index(name)]) if name in m.param_names \
                else default

        self.soc_max = param("rint_battery.soc_max_frac", 1.0)
        cap = [i for i, p in enumerate(m.param_names) if p.endswith(".max_passengers")]
        self.capacity = float(self.params[cap[0]]) if cap else 0.0
        # the pack's kWh per unit SoC: its charge at the OCV of the start SoC
        probe = m.initial_state(self.params, {}, soc_start=self.soc_start)[None, :].copy()
        sel = np.array([m.trace_names.index(n) for n in ("capacity_ah", "ocv_v")], np.int64)
        out = np.zeros((1, 1, 2), np.float32)
        m.run(self.params[None, :], probe, np.zeros((len(m.input_names), 2)), n_steps=1,
              record_every=1, record_sel=sel, record_out=out, threads=1)
        self.kwh_per_soc = float(out[0, 0, 0]) * float(out[0, 0, 1]) / 1e3

    def physics(self, infra, day_draw: dict, workers: int = 2):
        """Every block through the day under ``infra``'s terminal chargers: the blocks (with
        their chargers), their :class:`BlockDay` and the terminals' 1-s load [kW] folded on
        the day."""
        terminals = {s: Charger(infra.terminal_chargers, infra.terminal_charger_kw)
                     for s in self.terminals}
        blocks = [replace(b, chargers={k: v for k, v in terminals.items()
                                       if any(t.end_stop == k for t in b.trips)})
                  for b in self.network.blocks]
        shared, held_s, wanted_s = _share_terminals(blocks, self.efficiency)
        results: list = [None] * len(blocks)
        load_1s = np.zeros(DAY_S)
        lock = threading.Lock()

        def run(i):
            res, grid_1s, _ = _one_block(blocks[i], self.model, self.params, self.soc_start,
                                         day_draw, shared.get(i, []), self.capacity,
                                         self.efficiency)
            start = int(math.floor(blocks[i].start_s))
            with lock:
                np.add.at(load_1s, (start + np.arange(len(grid_1s))) % DAY_S, grid_1s)
            results[i] = res

        with ThreadPoolExecutor(max(1, workers)) as pool:
            list(pool.map(run, range(len(blocks))))
        return blocks, results, load_1s, (held_s, wanted_s)

    def row(self, physics, infra, method: str, costs) -> dict:
        """The day's row under the depot plan ``method`` (before costs)."""
        blocks, results, terminal_1s, (held_s, wanted_s) = physics
        plugs = infra.terminal_chargers * len({lay.stop_id for b in blocks
                                               for lay in b.layovers() if lay.charger})
        steps = int(DAY_S / depot_plan.STEP_S)
        terminal_15 = terminal_1s.reshape(steps, -1).mean(axis=1)
        used = np.array([self.soc_start - r.lowest_soc for r in results])
        target = np.minimum(self.soc_max, used + self.reserve)
        soc_end = np.array([r.soc_end for r in results])
        need = np.maximum(target - soc_end, 0.0) * self.kwh_per_soc
        arrive = np.array([r.arrive_s for r in results])
        depart = np.array([r.depart_next_s for r in results])
        demand_day = costs.demand_charge_per_kw_month * 12.0 / costs.operating_days_per_year
        p = depot_plan.plan(method, arrive, depart, need, infra.depot_chargers,
                            infra.depot_charger_kw, self.efficiency, infra.site_limit_kw,
                            costs.energy_price_per_kwh, demand_day, terminal_15)
        depot_15 = p.folded_kw()
        load_1s = terminal_1s + np.repeat(depot_15, int(depot_plan.STEP_S))
        load_15 = terminal_15 + depot_15
        short = p.short
        block_rows = [self._block_row(b, r, need[i], p.delivered_kwh[i], short[i])
                      for i, (b, r) in enumerate(zip(blocks, results, strict=True))]
        stranded = [(b, r) for b, r in zip(blocks, results, strict=True)
                    if not math.isnan(r.empty_at_s)]
        return {
            "blocks": len(blocks), "buses": len(blocks),
            "trips": sum(r.trips for r in results),
            "trips_not_served": sum(len(r.not_served) for r in results)
            + len(self.network.trips_not_served),
            "blocks_not_driven": len(self.network.not_driven),
            "distance_km": sum(r.distance_km for r in results),
            "battery_discharged_kwh": sum(r.discharged_kwh for r in results),
            "terminal_grid_kwh": float(terminal_1s.sum() / 3600.0),
            "depot_grid_kwh": float(depot_15.sum() * depot_plan.STEP_S / 3600.0),
            "grid_kwh": float(load_1s.sum() / 3600.0),
            "site_peak_kw": float(load_1s.max()),
            "site_peak_15min_kw": float(load_15.max()),
            "depot_peak_kw": float(depot_15.max()),
            "lowest_soc_pct": 100.0 * min(r.lowest_soc for r in results),
            "buses_short": len(stranded),
            "buses_below_reserve": int(sum(r.lowest_soc < self.reserve for r in results)),
            "buses_not_recharged": int(short.sum()),
            "service_hours_lost": float(sum((b.end_s - r.empty_at_s) / 3600.0
                                            for b, r in stranded)),
            "charger_utilisation": held_s / 3600.0 / (plugs * 24.0) if plugs else 0.0,
            "charger_wait_bus_h": (wanted_s - held_s) / 3600.0,
            "depot_utilisation": float((p.power_kw > 1e-6).sum() * depot_plan.STEP_S / 3600.0
                                       / max(infra.depot_chargers, 1) / 24.0),
            "depot_plan_status": p.status,
            "depot_plan_solve_s": p.solve_s,
            "load_step_s": 60.0,
            "site_load_kw": load_1s.reshape(-1, 60).mean(axis=1),
            "depot_load_kw": depot_15,
            "block_results": json.dumps(block_rows),
        }

    def _block_row(self, block, r: BlockDay, need_kwh, got_kwh, short) -> dict:
        feasible = math.isnan(r.empty_at_s) and r.lowest_soc >= self.reserve - 1e-9 and not short
        pack = self.kwh_per_soc
        used = (self.soc_start - r.lowest_soc) * pack
        if not math.isnan(r.empty_at_s):  # stranded: the whole block at the same rate
            used *= (block.end_s - block.start_s) / max(r.empty_at_s - block.start_s, 1.0)
        pack_needed = (used / pack + self.reserve) / self.soc_max * pack
        deficit = max(self.reserve - r.lowest_soc, 0.0) * pack + (
            used - (self.soc_start - r.lowest_soc) * pack)
        on_layovers = sum(max(lay.duration_s - PLUG_S, 0.0) for lay in block.layovers()) \
            / 3600.0 * TERMINAL_KW_FOR_ADVICE * self.efficiency
        needs = ""
        if r.lowest_soc < self.reserve - 1e-9 or not math.isnan(r.empty_at_s):
            if r.layover_charger_h == 0 and on_layovers >= deficit:
                needs = "a charger"
            elif pack_needed <= MAX_PACK_FACTOR * pack:
                needs = "a bigger pack"
            else:
                needs = "a swap"
        elif short:
            needs = "more depot charging"
        return {"block": block.block_id, "trips": r.trips, "km": round(r.distance_km, 1),
                "kwh": round(r.net_kwh, 1), "soc_end_pct": round(100 * r.soc_end, 1),
                "lowest_soc_pct": round(100 * r.lowest_soc, 1),
                "lowest_at": _clock(r.lowest_at_s), "lowest_where": r.lowest_where,
                "empty_at": "" if math.isnan(r.empty_at_s) else _clock(r.empty_at_s),
                "not_served": r.not_served, "depot_need_kwh": round(float(need_kwh), 1),
                "depot_got_kwh": round(float(got_kwh), 1), "feasible": bool(feasible),
                "pack_needed_kwh": round(pack_needed, 0), "needs": needs}


# What a block that runs below its reserve (or empty) needs, in this order: "a charger" when it
# meets none and a 300 kW plug at its layover stops (2 min to plug in and out) would cover the
# energy it lacks; "a bigger pack" when a pack of at most 1.5 x today's would do; "a swap" (a
# second bus for part of the block) otherwise.
TERMINAL_KW_FOR_ADVICE = 300.0
PLUG_S = 120.0
MAX_PACK_FACTOR = 1.5


def _clock(t_s: float) -> str:
    from ebus_env.blocks import clock

    return clock(t_s)


_STUDIES: dict[str, NetworkStudy] = {}
_PHYSICS: dict[tuple, tuple] = {}  # the last days' physics, by (study, terminals, day)
_LOCK = threading.Lock()
MAX_PHYSICS = 4


def network_study(spec) -> NetworkStudy:
    """The study's network (the feed read once per process and study file)."""
    g = spec.gtfs
    key = json.dumps(spec.raw.get("gtfs"), sort_keys=True, default=str) + spec.source
    with _LOCK:
        if key not in _STUDIES:
            _STUDIES.clear()
            _PHYSICS.clear()
            _STUDIES[key] = NetworkStudy(g.read(), g.bus, g.soc_start_pct, g.reserve_soc_pct,
                                         g.terminals)
        return _STUDIES[key]


def day_draw(spec, day: int) -> dict:
    """The seeded day: its mean ambient, and the passenger base and peak (as
    :meth:`ebus_env.envs.batch.BusBatch.reset` draws them, once for the network)."""
    from ebus_env.envs.climate import climate_of

    g, d = spec.gtfs, spec.days
    rng = np.random.default_rng([d.seed, day])
    mean, amplitude = (climate_of(spec.climate["place"]).ambient(spec.climate["month"])
                       if spec.climate else (15.0, 4.0))
    r = d.passengers_random_frac
    base = float(np.clip(g.passengers_base_frac + rng.uniform(-r, r), 0.0, 1.0))
    return {"ambient_mean_degc": mean + rng.uniform(-1, 1) * d.ambient_random_k,
            "ambient_amplitude_k": amplitude, "passengers_base": base,
            "passengers_peak": float(np.clip(g.passengers_peak_frac + rng.uniform(-r, r),
                                             base, 1.0)),
            "passengers_fixed": g.passengers}


def network_rows(spec, scenario, days: list[int], workers: int | None = None) -> list[dict]:
    """The rows of a timetable scenario (an infrastructure option with a depot plan), one
    per day, with costs. A day's physics is shared by the depot plans of one option. Its
    blocks run on ``workers`` threads (None: this task's share, :func:`default_threads`)."""
    from ebus_env.model.threads import default_threads

    workers = workers or default_threads()
    study = network_study(spec)
    infra, costs = scenario.infrastructure, spec.costs
    terminals = len(study.terminals)
    installed = terminals * infra.terminal_chargers * infra.terminal_charger_kw \
        + infra.depot_chargers * infra.depot_charger_kw
    rows = []
    for day in days:
        key = (id(study), infra.terminal_chargers,  # without a plug, the rating is moot
               infra.terminal_charger_kw if infra.terminal_chargers else 0.0, day)
        with _LOCK:
            physics = _PHYSICS.get(key)
        if physics is None:
            physics = study.physics(infra, day_draw(spec, day), workers)
            with _LOCK:
                while len(_PHYSICS) >= MAX_PHYSICS:
                    _PHYSICS.pop(next(iter(_PHYSICS)))
                _PHYSICS[key] = physics
        row = study.row(physics, infra, scenario.strategy.depot_plan, costs)
        cost = costs.day(row["site_load_kw"], row["load_step_s"] / 3600.0, 0.0,
                         row["site_peak_15min_kw"], installed, row["battery_discharged_kwh"])
        add_costs(row, cost)
        rows.append({**scenario.columns(), "day": day, **row})
    return rows
