"""Service days with one hidden effect: measured-like logs to test diagnosis against the truth.

Each case drives the 12 m bus (``configs/bus/12m.yaml``) through a service day with a model
richer than the baseline by exactly one effect, then degrades the log like a real one: 1 Hz,
date-time stamps, speed at CAN resolution (0.1 km/h), ambient at 0.5 degC, SoC with BMS noise (0.02 %) and
quantised to 0.1 %, no battery current or voltage. The baseline the diagnosis starts from is
``12m`` without ``Case.without``; ``control`` hides nothing.

``python -m ebus_env.diagnostics.hidden [folder]`` writes ``<case>.csv.gz`` and
``cases.json`` (the truth) to ``data/measured/hidden``. Seeded: the files are reproducible.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from ebus_env import paths
from ebus_env.config import Service, load_bus
from ebus_env.cycles import load_cycle, service_day
from ebus_env.errors import ConfigError
from ebus_env.profile import Profile
from ebus_env.routes import load_route

OUT_DIR = paths.data("measured", "hidden")
BUS = "12m"
DT_S = 0.1
SEED = 2023
FLOAT_FORMAT = "%.6g"
DATE = "2026-01-14"  # a winter weekday: the logs carry date-times, so the time of day is known


@dataclass(frozen=True)
class Case:
    """One service day and the effect hidden in it."""

    name: str
    effect: str | None  # registry name of the hidden effect (None: control)
    without: tuple[str, ...]  # effects of 12m the baseline lacks
    truth: dict  # hidden effect's parameter values (qualified names)
    description: str
    start_h: float = 6.0
    hours: float = 8.0
    ambient_degc: tuple[float, float] = (12.0, 12.0)  # at the start and the end (linear)
    soc_start: float = 0.95
    service: dict = field(default_factory=dict)  # overrides of the bus's Service
    route: str | None = None  # King County route driven out and back (else cycle laps)
    cycles: tuple[str, ...] = ("sort2",)  # laps of each in turn, for equal parts of the day


CASES = (
    Case("road_grade", "road_grade", ("road_grade",), {},
         "King County route 45 out and back (13 km, 95 m climb each way), altitude logged; "
         "the baseline drives it flat", route="kc45"),
    Case("cabin_heating", "cabin_hvac", ("cabin_hvac",), {"cabin_hvac.ua_w_per_k": 450.0},
         "a cold day (-8 to -1 degC) with the cabin heated to 20 degC; the baseline has no HVAC",
         ambient_degc=(-8.0, -1.0)),
    Case("regen_high_soc", "regen_soc_limit", (), {"regen_soc_limit.derate_soc_pct": 85.0},
         "charged to about 98 % every two hours, the SoC swings between 98 and 75 %; above "
         "85 % the BMS derates its regenerative charge limit (linearly to zero at 100 %); the "
         "baseline regenerates fully", hours=10.0, soc_start=0.98,
         service={"layover_every_min": 120, "layover_min": 15}),
    Case("evening_auxiliaries", "aux_schedule", (), {"aux_schedule.scale": 5.0},
         "lights from 17:00 (2.5 kW, the evening_lights schedule at scale 5) on a 14:00-24:00 "
         "day; the baseline has a constant auxiliary load only", start_h=14.0, hours=10.0),
    Case("passenger_peaks", "passenger_schedule", (),
         {"passenger_schedule.base_frac": 0.1, "passenger_schedule.peak_frac": 1.0},
         "passengers from 10 % of capacity at midday to full at the commuter peaks, no "
         "passenger count in the log; the baseline carries a constant half load",
         start_h=6.0, hours=13.0),
    Case("cold_battery", "ambient_battery", (),
         {"ambient_battery.initial_offset_k": 0.0, "ambient_battery.time_constant_h": 3.0},
         "a bus parked outdoors overnight: its pack without thermal management starts at the "
         "-4 degC air and warms by its own losses, on the charger above all, while the air "
         "cools to -7 degC; its resistance (Arrhenius) falls through the morning; the "
         "baseline holds the pack at 25 degC", ambient_degc=(-4.0, -7.0)),
    Case("control", None, (), {}, "nothing hidden: the baseline is the truth"),
    Case("door_compressor", "examples/my_effects.py:door_compressor", (),
         {"door_compressor.power_w": 5000.0},
         "an effect the library lacks (the README's worked example of a user's effect): the "
         "air compressor of the doors and kneeling runs after every stop; a depot-charged bus "
         "on 2.5 h of SORT 1 (many stops) then 2.5 h of SORT 3 at 20 degC", hours=5.0,
         ambient_degc=(20.0, 20.0), cycles=("sort1", "sort3"),
         service={"charge_at_layovers": False}),
)


def case(name: str) -> Case:
    from ebus_env.errors import unknown_name

    for c in CASES:
        if c.name == name:
            return c
    raise unknown_name("hidden-effect case", name, [c.name for c in CASES])


def hidden_effect(c: Case):
    """The case's hidden effect (a registry name or a file of the project, ``file.py:Name``)."""
    from ebus_env.config import resolve_effect

    if c.effect is None:
        return None
    if ".py:" not in c.effect:
        return resolve_effect(c.effect)
    root = paths.checkout()
    if root is None:
        raise ConfigError(f"The case '{c.name}' hides {c.effect}, a file of the source "
                          "checkout, which an installed package does not hold. Fix: run it "
                          "from a clone of the repository.")
    return resolve_effect(str(root / c.effect))


def true_bus(c: Case):
    """The richer bus that made the log: 12m with the hidden effect at its true values."""
    bus = load_bus(BUS)
    if c.effect is not None:
        bus = bus.with_effect(hidden_effect(c))
    params: dict = {}
    for name, value in c.truth.items():
        effect, param = name.split(".")
        params.setdefault(effect, {})[param] = value
    return bus.overlay({"params": params}, f"hidden case {c.name}")


def baseline_bus(c: Case):
    """The bus the diagnosis starts from."""
    return load_bus(BUS, without=c.without)


def _route_day(c: Case, service: Service) -> tuple[Profile, np.ndarray]:
    """Out and back on a route with a layover at each end, until the day is full; returns the
    profile and the altitude along it."""
    out, back = load_route(f"{c.route}_out"), load_route(f"{c.route}_back")
    legs = [(out, out.cycle(dt_s=DT_S)), (back, back.cycle(dt_s=DT_S))]
    n_total = int(round(c.hours * 3600 / DT_S))
    n_layover = int(round(service.layover_min * 60 / DT_S))
    speed, grade, altitude, plugged = [], [], [], []
    rows, k = 0, 0
    while rows < n_total:
        route, cyc = legs[k % 2]
        speed.append(cyc.speed_kmh / 3.6)
        grade.append(cyc.grade_frac)
        altitude.append(route.altitude_along(cyc))
        plugged.append(np.zeros(len(cyc.speed_kmh)))
        speed.append(np.zeros(n_layover))
        grade.append(np.zeros(n_layover))
        altitude.append(np.full(n_layover, altitude[-1][-1]))
        plugged.append(np.ones(n_layover))
        rows += len(cyc.speed_kmh) + n_layover
        k += 1
    cut = slice(0, n_total)
    channels = {"speed_ref_mps": np.concatenate(speed)[cut],
                "grade_frac": np.concatenate(grade)[cut],
                "charger_connected": np.concatenate(plugged)[cut]}
    notes = [f"{c.route} out and back, {service.layover_min:g} min layovers on a charger"]
    return Profile(channels, DT_S, c.name, c.start_h, notes=notes), \
        np.concatenate(altitude)[cut]


def day_profile(c: Case) -> tuple[Profile, np.ndarray | None]:
    """The case's service day (and the altitude along it, for a route)."""
    bus = load_bus(BUS)
    service = Service(**{**asdict(bus.service), "start_time_h": c.start_h, **c.service})
    altitude = None
    if c.route:
        profile, altitude = _route_day(c, service)
    else:
        parts = [service_day(load_cycle(name), c.hours / len(c.cycles), DT_S,
                             replace(service, start_time_h=(c.start_h + k * c.hours /
                                                            len(c.cycles)) % 24))
                 for k, name in enumerate(c.cycles)]
        channels = {k: np.concatenate([p.channels[k] for p in parts]) for k in parts[0].channels}
        profile = Profile(channels, DT_S, c.name, c.start_h,
                          notes=[n for p in parts for n in p.notes])
    n = profile.n_steps
    ambient = np.linspace(c.ambient_degc[0], c.ambient_degc[1], n)
    return profile.with_channels(ambient_degc=ambient), altitude


def generate(c: Case, seed: int = SEED):
    """The degraded 1 Hz log of a case (pandas DataFrame, canonical columns)."""
    from ebus_env.synthetic import synthetic_log

    profile, altitude = day_profile(c)
    model = true_bus(c).build(DT_S)
    frame = synthetic_log(model, profile, soc_start=c.soc_start, period_s=1.0,
                          soc_step_pct=0.1, soc_noise_pct=0.02, seed=seed)
    frame = frame.drop(columns=["battery_current_a", "battery_voltage_v", "grade_frac"],
                       errors="ignore")
    frame["speed_kmh"] = frame["speed_kmh"].round(1)
    frame["ambient_degc"] = (frame["ambient_degc"] * 2).round() / 2
    if altitude is not None:
        rows = np.rint(frame["time_s"].to_numpy() / DT_S).astype(int)
        frame["altitude_m"] = altitude[rows].round(1)
    start = np.datetime64(DATE) + np.timedelta64(int(round(c.start_h * 3600)), "s")
    stamps = start + (frame["time_s"].to_numpy() * 1000).astype("timedelta64[ms]")
    frame.insert(0, "timestamp", np.datetime_as_string(stamps, unit="s"))
    return frame.drop(columns="time_s")


def write_all(folder: str | Path = OUT_DIR, seed: int = SEED) -> list[Path]:
    """Write every case's log and ``cases.json`` to ``folder``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written, manifest = [], {}
    for k, c in enumerate(CASES):
        path = folder / f"{c.name}.csv.gz"
        generate(c, seed + k).to_csv(path, index=False, float_format=FLOAT_FORMAT,
                                     compression={"method": "gzip", "mtime": 0})
        written.append(path)
        manifest[c.name] = {"file": path.name, "hidden_effect": c.effect, "baseline": {
            "bus": BUS, "without": list(c.without)}, "truth": c.truth,
            "description": c.description, "seed": seed + k, "start_h": c.start_h,
            "hours": c.hours}
    (folder / "cases.json").write_text(json.dumps(manifest, indent=2) + "\n")
    return written


def main(argv: list[str] | None = None) -> None:
    """``python -m ebus_env.diagnostics.hidden [--help] [FOLDER]``."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m ebus_env.diagnostics.hidden",
                                     description="Write the hidden-effect logs and cases.json.")
    parser.add_argument("folder", nargs="?", type=Path, default=OUT_DIR,
                        help=f"output folder (default: {OUT_DIR})")
    for p in write_all(parser.parse_args(argv).folder):
        print(p)


if __name__ == "__main__":  # pragma: no cover
    main()
