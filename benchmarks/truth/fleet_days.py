"""A small made-up fleet for the live twin to replay: several buses over several days, one of
which develops a fault on a given day. Made with the independent truth simulator
(:mod:`benchmarks.truth.sim`), so the twin's model has not made its own data.

    python -m benchmarks.truth.fleet_days --out data/twin_fleet

writes, per bus and day, ``<bus>/<date>.csv.gz`` (a degraded 1 Hz telematics log, the
columns of :mod:`benchmarks.truth.degrade`) and ``<bus>/<date>.block.json`` (the day's block:
its trips and the chargers it meets, :mod:`ebus_env.twin.schedule`), and ``fleet.json`` (the
truth: each bus's base parameters, its fault and the day it starts, each day's summary).

Each day runs the bus's route out and back from ``start`` for ``hours``; after service the bus
stands at the depot for :data:`DEPOT_MIN` minutes (its loads on, nothing charging), which is
how the twin sees that the day is over. The fault is a leaking brake-air system: the electric
compressor (the truth simulator's ``air_compressor``, a load the library has no effect for)
runs far more often than a sound one.
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


def with_depot(plan: pd.DataFrame, minutes: float) -> pd.DataFrame:
    """The plan with the bus standing at the depot for ``minutes`` after its last row."""
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


def block(plan: pd.DataFrame, bus: str, date: str) -> dict:
    """The day's block as its schedule gives it: trips (route, direction, start, end) and the
    charger sessions planned at the terminals (start, end, rated kW)."""
    start = pd.Timestamp(date)

    def clock(h):
        return (start + pd.to_timedelta(round(float(h) * 3600.0), unit="s")).isoformat()

    legs = plan["leg"].to_numpy()
    clock_h = plan["clock_h"].to_numpy()
    trips, chargers = [], []
    edges = np.flatnonzero(np.diff(legs) != 0) + 1
    for a, b in zip(np.r_[0, edges], np.r_[edges, len(legs)], strict=True):
        if legs[a] >= 0:
            trips.append({"trip": f"{plan.attrs['route']}-{len(trips) + 1}",
                          "route": plan.attrs["route"], "direction": int(legs[a] % 2),
                          "start": clock(clock_h[a]), "end": clock(clock_h[b - 1])})
    plugged = plan["charging"].to_numpy()
    on = np.flatnonzero(np.diff(np.r_[0, plugged, 0]) != 0)
    for a, b in zip(on[::2], on[1::2], strict=True):
        chargers.append({"start": clock(clock_h[a]), "end": clock(clock_h[b - 1]),
                         "power_kw": float(plan["charger_kw"].iloc[a]),
                         "site": f"terminal-{int(legs[max(a - 1, 0)] + 1) % 2}"})
    return {"bus": bus, "date": date, "trips": trips, "chargers": chargers,
            "end": clock(clock_h[-1])}


def bus_day(fb: FleetBus, day: int, seed: int = SEED):
    """The clean trace, the log, the block and the truth summary of one bus-day."""
    bus_ss, days_ss = np.random.SeedSequence([seed, int(fb.bus[-2:])]).spawn(2)
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
    summary = {"date": date, "fault": fault, "km": round(km, 3),
               "soc_start_pct": round(100 * soc0, 2),
               "soc_end_pct": round(100 * float(trace["soc_frac"].iloc[-1]), 2),
               "soc_min_pct": round(100 * float(trace["soc_frac"].min()), 2),
               "hidden_kwh": round(float(trace["e_hidden_j"].iloc[-1]) / 3.6e6, 3)}
    return trace, log, block(plan, fb.bus, date), summary, base


def write(out: str | Path, fleet=FLEET, days: int = DAYS, seed: int = SEED) -> dict:
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
    args = parser.parse_args(argv)
    write(args.out, FLEET, args.days, args.seed)


if __name__ == "__main__":
    main()
