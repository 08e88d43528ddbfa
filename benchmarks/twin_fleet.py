"""A made-up fleet for the live twin to replay: several buses over several days, one of which
develops a fault on a given day. Made with the independent truth simulator
(:mod:`benchmarks.truth.sim`), so the twin's model has not made its own data.

    python -m benchmarks.twin_fleet --out data/twin_fleet              # the shipped fleet
    python -m benchmarks.twin_fleet --out DIR --random 25 --seed 7     # a larger one (bench)

writes, per bus and day, ``<bus>/<date>.csv.gz`` (a degraded 1 Hz telematics log, the
columns of :mod:`benchmarks.truth.degrade`) and ``<bus>/<date>.block.json`` (the day's block
in the hand-written form of :mod:`ebus_env.blocks`: its trips as the King County route
directions they drive, ``kc7_out``..., at the times the bus kept, and the terminal chargers
it meets, on the local clock of the logs' time stamps, its ``timezone``), and ``fleet.json``
(the truth: each bus's base parameters, its fault and the day it starts, each day's
summary).

Each day runs the bus's route out and back from ``start`` for ``hours``, ending with its last
whole trip; after service the bus stands at the depot for :data:`DEPOT_MIN` minutes (its
loads on, nothing charging), which is how the twin sees that the day is over. The fault is a
leaking brake-air system: the electric compressor (the truth simulator's ``air_compressor``, a
load the library has no effect for) runs far more often than a sound one.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from benchmarks.truth.cases import _atomic_write, log_bytes
from benchmarks.truth.days import route_day
from benchmarks.truth.degrade import degrade
from benchmarks.truth.sim import simulate
from benchmarks.truth.vehicles import draw_base

SEED = 20260505
FIRST_DATE = "2025-05-05"
DEPOT_MIN = 45.0
LEAK = {"compressor_w": 6000.0, "fill_bar_per_s": 0.05, "brake_bar": 0.15, "door_bar": 0.2,
        "leak_bar_per_s": 0.012, "cut_in_bar": 10.0, "cut_out_bar": 12.5}
"""The fault: a brake-air system leaking 0.012 bar/s (a sound one: 2-5e-4 bar/s), so that the
6 kW compressor runs about a quarter of the time."""
DIRECTIONS = ("out", "back")  # leg 0 (route file d0) runs A -> B, leg 1 B -> A


@dataclass(frozen=True)
class FleetBus:
    bus: str
    chemistry: str
    route: str
    charger_kw: float
    charger_terminals: tuple[int, ...]
    fault_day: int | None = None  # the first day (0, 1, ...) with the fault


FLEET = (
    FleetBus("bus-01", "LFP", "rt7", 300.0, (0,)),
    FleetBus("bus-02", "NMC", "rt44", 450.0, (0, 1)),
    FleetBus("bus-03", "LFP", "rt45", 150.0, (), fault_day=2),
    FleetBus("bus-04", "NMC", "rt7", 300.0, (0, 1)),
    FleetBus("bus-05", "LFP", "rt44", 300.0, ()),
)
DAYS = 4


def random_fleet(n: int, seed: int, first: int = 11) -> tuple[FleetBus, ...]:
    """``n`` buses drawn like the shipped ones (for the benchmark; not shipped): pack, route,
    terminal chargers (none for about a third: depot charging only) and, for about one in
    five, the brake-air leak from day 2 or 3 on. Named ``bus-11``, ``bus-12``..."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        terminals = [(), (0,), (1,), (0, 1)][int(rng.choice(4, p=[0.35, 0.25, 0.15, 0.25]))]
        out.append(FleetBus(f"bus-{first + k:02d}", str(rng.choice(["LFP", "NMC"])),
                            str(rng.choice(["rt7", "rt44", "rt45"])),
                            float(rng.choice([150.0, 300.0, 450.0])), terminals,
                            int(rng.integers(2, 4)) if rng.random() < 0.2 else None))
    return tuple(out)


def with_depot(plan: pd.DataFrame, minutes: float) -> pd.DataFrame:
    """The plan up to the end of its last whole trip, then the bus standing at the depot for
    ``minutes`` (the trip the day's end cut short is not driven)."""
    legs = plan["leg"].to_numpy()
    if legs[-1] >= 0:  # cut inside a trip: the day ends before that trip's layover
        last = np.flatnonzero(legs == legs[-1])[0]
        plan = plan.iloc[: np.flatnonzero(legs[:last] >= 0)[-1] + 1]
    n = int(round(60.0 * minutes))
    tail = pd.DataFrame({c: np.repeat(plan[c].to_numpy()[-1:], n) for c in plan.columns})
    tail["time_s"] = plan["time_s"].iloc[-1] + 1.0 + np.arange(n)
    tail["clock_h"] = plan["clock_h"].iloc[-1] + (1.0 + np.arange(n)) / 3600.0
    for col, value in (("speed_target_mps", 0.0), ("door_open", 0), ("charging", 0),
                       ("charger_kw", 0.0), ("passengers", 0), ("grade_frac", 0.0),
                       ("leg", -2)):
        tail[col] = value
    out = pd.concat([plan, tail], ignore_index=True)
    out.attrs.update(plan.attrs)
    return out


def block(plan: pd.DataFrame, bus: str, fb: FleetBus) -> dict:
    """The day's block in the hand-written form of :mod:`ebus_env.blocks`: each trip the
    King County route direction it drives, from the time it left its terminal to the time it
    reached the other, and the terminal chargers (the stops where a leg starts). A trip that
    ran faster than its route's timetable (the speed limits, 20 s at every stop) keeps the
    route's own time."""
    from ebus_env.blocks import clock
    from ebus_env.routes import load_route

    number = plan.attrs["route"].removeprefix("rt")
    legs = plan["leg"].to_numpy()
    clock_s = plan["clock_h"].to_numpy() * 3600.0
    edges = np.flatnonzero(np.diff(legs) != 0) + 1
    trips = []
    for a, b in zip(np.r_[0, edges], np.r_[edges, len(legs)], strict=True):
        if legs[a] < 0:
            continue
        cycle = f"kc{number}_{DIRECTIONS[legs[a] % 2]}"
        start = round(float(clock_s[a]))
        end = max(round(float(clock_s[b - 1])),
                  start + int(np.ceil(load_route(cycle).cycle(dt_s=0.5).duration_s)))
        if trips and trips[-1]["_end"] > start:
            raise ValueError(f"{bus}: trip {len(trips) + 1} starts before the one before ends")
        trips.append({"trip_id": f"{plan.attrs['route']}-{len(trips) + 1}",
                      "route": number, "cycle": cycle, "start": clock(start),
                      "end": clock(end), "_end": end})
    for t in trips:
        del t["_end"]
    stops = (f"kc{number}_A", f"kc{number}_B")
    return {"timezone": plan.attrs.get("timezone", "UTC"),  # the logs' local clock
            "block_id": f"{bus} {plan.attrs['date']}", "trips": trips,
            "chargers": {stops[k]: {"count": 1, "power_kw": fb.charger_kw}
                         for k in fb.charger_terminals}}


def bus_day(fb: FleetBus, day: int, seed: int = SEED):
    """The clean trace, the log, the block and the truth summary of one bus-day."""
    bus_ss, _ = np.random.SeedSequence([seed, int(fb.bus[-2:])]).spawn(2)
    base = draw_base(np.random.default_rng(bus_ss), fb.chemistry)
    plan_ss, phys_ss, log_ss = np.random.SeedSequence(
        [seed, int(fb.bus[-2:]), day]).spawn(3)
    rng = np.random.default_rng(plan_ss)
    start_h, hours = rng.uniform(5.5, 7.0), rng.uniform(8.5, 9.5)
    plan = route_day(rng, hours, start_h, fb.route, climate="mild", charger_kw=fb.charger_kw,
                     charger_terminals=fb.charger_terminals)
    date = str((pd.Timestamp(FIRST_DATE) + pd.Timedelta(days=day)).date())
    plan.attrs["date"] = date
    plan = with_depot(plan, DEPOT_MIN)
    phys = np.random.default_rng(phys_ss)
    base["driver_preview_s"] = float(phys.uniform(1.5, 2.5))
    soc0 = float(phys.uniform(0.85, 0.95))  # charged at the depot overnight
    fault = fb.fault_day is not None and day >= fb.fault_day
    trace = simulate(plan, base, "air_compressor" if fault else None, LEAK if fault else {},
                     soc0_frac=soc0, charge_stop_frac=0.95)
    clean = trace[["time_s", "clock_h", "speed_mps", "soc_frac", "ambient_degc", "charging",
                   "charger_kw", "door_open"]].copy()
    clean.attrs.update(plan.attrs)
    log = degrade(clean, np.random.default_rng(log_ss))
    km = float(trace["distance_m"].iloc[-1]) / 1000.0
    blk = block(plan, fb.bus, fb)
    in_block = plan["leg"].to_numpy() >= -1
    soc = trace["soc_frac"].to_numpy()
    summary = {"date": date, "fault": fault, "km": round(km, 3),
               "soc_start_pct": round(100 * soc0, 2),
               "soc_end_pct": round(100 * float(soc[in_block][-1]), 2),
               "soc_min_pct": round(100 * float(soc[in_block].min()), 2),
               "hidden_kwh": round(float(trace["e_hidden_j"].iloc[-1]) / 3.6e6, 3)}
    return trace, log, blk, summary, base


def write(out: str | Path, fleet=FLEET, days: int = DAYS, seed: int = SEED,
          quiet: bool = False) -> dict:
    out = Path(out)
    record = {"seed": seed, "made_up": True, "buses": {}}
    for fb in fleet:
        folder = out / fb.bus
        folder.mkdir(parents=True, exist_ok=True)
        rows = []
        for day in range(days):
            _, log, blk, summary, base = bus_day(fb, day, seed)
            _atomic_write(folder / f"{summary['date']}.csv.gz", log_bytes(log))
            _atomic_write(folder / f"{summary['date']}.block.json",
                          (json.dumps(blk, indent=1) + "\n").encode())
            rows.append(summary)
            if not quiet:
                print(f"{fb.bus} {summary}")
        record["buses"][fb.bus] = {
            "chemistry": fb.chemistry, "route": fb.route, "charger_kw": fb.charger_kw,
            "charger_terminals": list(fb.charger_terminals),
            "fault": None if fb.fault_day is None else {
                "what": "leaking brake-air system (truth simulator's air_compressor)",
                "first_day": fb.fault_day, "physical": LEAK},
            "base": {k: (v if isinstance(v, str) else round(float(v), 6))
                     for k, v in base.items()},
            "days": rows}
    _atomic_write(out / "fleet.json", (json.dumps(record, indent=1) + "\n").encode())
    return record


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--days", type=int, default=DAYS)
    parser.add_argument("--seed", type=int, default=SEED)
    parser.add_argument("--random", type=int, default=0,
                        help="this many random buses instead of the shipped five")
    args = parser.parse_args(argv)
    fleet = random_fleet(args.random, args.seed) if args.random else FLEET
    write(args.out, fleet, args.days, args.seed)


if __name__ == "__main__":
    main()
