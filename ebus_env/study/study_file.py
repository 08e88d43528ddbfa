"""The study file: what to simulate and how to price it, checked in full before any work.

A study YAML has the keys of :class:`StudySpec`::

    name: a title
    lines:            # each an env config (configs/env keys) plus buses and an optional headway
      - {name: sort2, cycle: sort2, bus: 12m, buses: 6, service_h: 13.5, headway_min: 10}
    climate: {place: gothenburg, month: 1}     # or omitted: the lines' own ambient keys
    infrastructure:   # every combination of the listed values is one option
      terminal_chargers: [1, 2]
      terminal_charger_kw: [300, 450]
      depot_chargers: 3
      depot_charger_kw: 100
      site_limit_kw: [400, 600]
    strategies:       # fixed ECO settings, or a policy (``module:factory``) run every decision
      - {name: baseline}
      - {name: eco_charging, charge_power_frac: 0.6, pulse_duty: 0.8}
    days: {count: 3, seed: 0, traffic_random_frac: 0.1}
    costs: {...}      # every key of ebus_env.study.costs.CostModel, none defaulted

or, for a timetable, ``gtfs`` (the keys of :class:`GtfsSpec`) instead of ``lines``: the
feed's blocks are the buses, ``terminal_chargers`` x ``terminal_charger_kw`` stand at each of
its ``terminals``, ``site_limit_kw`` is the depot's grid limit, and each strategy names a
``depot_plan`` (``optimal``, ``on_arrival``, ``flat``; all three when ``strategies`` is left
out)::

    gtfs: {feed: data/gtfs/king_county_example.zip, date: 2024-03-12, terminals: [kc45_A]}
"""

from __future__ import annotations

import importlib.util
import itertools
from dataclasses import dataclass, field, fields
from pathlib import Path

from ebus_env.envs.climate import climate_of
from ebus_env.envs.common import ACTIONS, EnvConfig
from ebus_env.errors import ConfigError
from ebus_env.inputs import check
from ebus_env.study.checks import check_keys, is_number, positive
from ebus_env.study.costs import CostModel

LINE_KEYS = {"name", "buses", "headway_min"}  # besides EnvConfig's keys
INFRA_KEYS = ("terminal_chargers", "terminal_charger_kw", "depot_chargers", "depot_charger_kw",
              "site_limit_kw")
DAY_KEYS = {"count", "seed", "traffic_random_frac", "ambient_random_k", "passengers_random_frac"}
STRATEGY_KEYS = {"name", "policy", "policy_args", "decision_s"} | {a.name for a in ACTIONS}
GTFS_STRATEGY_KEYS = {"name", "depot_plan"}
DEPOT_PLANS = ("optimal", "on_arrival", "flat")
# fixed settings of the baseline (no ECO feature): ebus_env.envs.ebus.ACTIONS' no-cap ends
BASELINE = {"speed_cap_kmh": 80.0, "accel_cap_mps2": 1.5, "setpoint_degc": 21.0,
            "charge_power_frac": 1.0, "pulse_duty": 1.0}
# the line keys the study sets itself (from climate, days, infrastructure)
STUDY_SET = {"climate", "month", "charger_kw", "ambient_random_k", "passengers_random_frac",
             "decision_s", "decide_at_stops", "reward"}


@dataclass(frozen=True)
class Line:
    """A line: ``buses`` buses of one env config, departing ``headway_min`` apart (None: the
    lap period over the buses)."""

    name: str
    buses: int
    env: dict  # EnvConfig keys
    headway_min: float | None = None


@dataclass(frozen=True)
class Infrastructure:
    """One charging option: terminal and depot chargers (count x kW) behind one site grid
    connection of ``site_limit_kw`` (the terminal by day, the depot by night)."""

    terminal_chargers: int
    terminal_charger_kw: float
    depot_chargers: int
    depot_charger_kw: float
    site_limit_kw: float

    @property
    def name(self) -> str:
        return (f"T{self.terminal_chargers}x{self.terminal_charger_kw:g}kW_"
                f"D{self.depot_chargers}x{self.depot_charger_kw:g}kW_"
                f"L{self.site_limit_kw:g}kW")

    @property
    def installed_kw(self) -> float:
        return (self.terminal_chargers * self.terminal_charger_kw
                + self.depot_chargers * self.depot_charger_kw)


@dataclass(frozen=True)
class Strategy:
    """Fixed ECO settings (physical units, the keys of ``ACTIONS``) held all day, or a policy
    ``module:factory`` (called with ``policy_args``; see :func:`ebus_env.study.runner.policy`)
    asked every ``decision_s``."""

    name: str
    settings: tuple  # ((action name, value), ...) in ACTIONS order
    policy: str | None = None
    decision_s: float = 60.0
    policy_args: dict = field(default_factory=dict)  # keyword arguments of the factory
    depot_plan: str | None = None  # a timetable study's depot charging (DEPOT_PLANS)


@dataclass(frozen=True)
class GtfsSpec:
    """A timetable study's network: a GTFS ``feed`` (zip or folder) on a service ``date``
    (YYYY-MM-DD), the ``routes`` to electrify (short names or ids; None: all), the user's
    ``altitude`` and ``speed_limits`` CSVs along the shapes (None: grade zero, the driver's
    cap), the ``terminals`` (stop ids) that get the option's terminal chargers, the bus and
    its SoC at the start of the day and the reserve it must keep, passengers on board
    (``passengers``: a number per trip, or None: the commuter profile of ``days``' random
    base/peak around ``passengers_base_frac``/``passengers_peak_frac``), and the vehicle
    scheduling of trips without ``block_id``."""

    feed: str
    date: str
    routes: tuple | None = None
    altitude: str | None = None
    speed_limits: str | None = None
    terminals: tuple = ()
    bus: str = "12m"
    soc_start_pct: float = 95.0
    reserve_soc_pct: float = 20.0
    passengers: float | None = None
    passengers_base_frac: float = 0.2
    passengers_peak_frac: float = 0.8
    min_layover_min: float = 3.0
    deadhead_speed_kmh: float = 25.0
    mixed_blocks: str = "whole"

    def read(self):
        """The service day's blocks (:func:`ebus_env.gtfs.read_network_day`)."""
        from ebus_env.gtfs import read_network_day

        return read_network_day(self.feed, self.date, routes=self.routes,
                                altitude=self.altitude, speed_limits=self.speed_limits,
                                min_layover_s=60.0 * self.min_layover_min,
                                deadhead_speed_kmh=self.deadhead_speed_kmh,
                                mixed_blocks=self.mixed_blocks)


@dataclass(frozen=True)
class Days:
    """Seeded day variations: each day draws the ambient mean, the passenger loads and the
    traffic (the day's top speed lowered by up to ``traffic_random_frac``)."""

    count: int = 1
    seed: int = 0
    traffic_random_frac: float = 0.0
    ambient_random_k: float = 2.0
    passengers_random_frac: float = 0.15


@dataclass(frozen=True)
class StudySpec:
    """A checked study: lines, climate, infrastructure options, strategies, days, costs."""

    name: str
    lines: tuple[Line, ...]
    infrastructure: tuple[Infrastructure, ...]
    strategies: tuple[Strategy, ...]
    days: Days
    costs: CostModel
    climate: dict | None = None
    source: str = ""
    gtfs: GtfsSpec | None = None
    raw: dict = field(default_factory=dict, compare=False, repr=False)  # as read (for workers)

    def env_config(self, line: Line, infra: Infrastructure, strategy: Strategy) -> EnvConfig:
        """The env config of ``line`` in this study (climate, days and charger applied)."""
        keys = dict(line.env)
        if self.climate is not None:
            keys.update(climate=self.climate["place"], month=self.climate["month"])
        keys.update(charger_kw=infra.terminal_charger_kw, decision_s=strategy.decision_s,
                    ambient_random_k=self.days.ambient_random_k,
                    passengers_random_frac=self.days.passengers_random_frac)
        return EnvConfig.load(keys)


def load_study(source: str | Path | dict) -> StudySpec:
    """Read and check a study (a YAML path, a shipped study's name such as ``example``, or a
    mapping); any problem is one ConfigError line naming the file and key, before any
    simulation."""
    where = "study"
    if isinstance(source, dict):
        data = source
    else:
        from ebus_env.config import find_config, read_yaml

        path = find_config(source, kind="studies")  # a path, or a shipped study's name
        where = str(path)
        data = read_yaml(path)
    try:
        return _parse(data, where)
    except ConfigError as e:
        if str(e).startswith(where):
            raise
        raise ConfigError(f"{where}: {e}") from None


def _parse(data: dict, where: str) -> StudySpec:
    check_keys(data, {"name", "lines", "gtfs", "climate", "infrastructure", "strategies",
                      "days", "costs"}, "top level")
    if "gtfs" in data:
        return _parse_gtfs(data, where)
    for key in ("lines", "infrastructure", "strategies", "costs"):
        if key not in data:
            raise ConfigError(f"missing '{key}' (see configs/studies/example.yaml).")
    climate, days = _climate_and_days(data)
    lines = _lines(data["lines"], climate)
    infra = _infrastructure(data["infrastructure"], lines)
    strategies = _strategies(data["strategies"])
    costs = CostModel.load(data["costs"])
    spec = StudySpec(str(data.get("name", "study")), lines, infra, strategies, days, costs,
                     climate, where, raw=data)
    from ebus_env.config import load_bus
    from ebus_env.envs.batch import course_of

    for line in lines:  # every line must build: its keys, bus, cycle or route, climate
        cfg = spec.env_config(line, infra[0], strategies[0])
        load_bus(cfg.bus, overlays=[cfg.overlay] if cfg.overlay else ())
        course_of(cfg)
    service = {float(spec.env_config(ln, infra[0], strategies[0]).service_h) for ln in lines}
    start = {float(spec.env_config(ln, infra[0], strategies[0]).start_time_h) for ln in lines}
    if len(service) > 1 or len(start) > 1:
        raise ConfigError("every line needs the same start_time_h and service_h (the site "
                          f"runs one clock): got {sorted(start)} and {sorted(service)}.")
    if next(iter(service)) >= 24.0:
        raise ConfigError(f"service_h = {next(iter(service))}: a service day must leave time "
                          "(< 24 h) for the depot to recharge the buses.")
    return spec


def _climate_and_days(data: dict) -> tuple[dict | None, Days]:
    climate = data.get("climate")
    if climate is not None:
        check_keys(climate, {"place", "month"}, "climate")
        if set(climate) != {"place", "month"}:
            raise ConfigError("climate needs both 'place' and 'month' (1-12).")
        climate_of(climate["place"]).ambient(climate["month"])
    days = data.get("days") or {}
    check_keys(days, DAY_KEYS, "days")
    days = Days(**days)
    positive(days.count, "days.count", integer=True)
    positive(days.seed, "days.seed", integer=True, zero=True)
    for key in ("traffic_random_frac", "passengers_random_frac", "ambient_random_k"):
        positive(getattr(days, key), f"days.{key}", zero=True)
    if days.traffic_random_frac >= 0.8:
        raise ConfigError(f"days.traffic_random_frac = {days.traffic_random_frac}: give a "
                          "fraction below 0.8 (the top speed lowered by up to it).")
    return climate, days


def _parse_gtfs(data: dict, where: str) -> StudySpec:
    """A timetable study (``gtfs`` instead of ``lines``)."""
    from datetime import date

    from ebus_env import paths

    if "lines" in data:
        raise ConfigError("give either 'lines' (laps of a cycle or route) or 'gtfs' (a "
                          "timetable), not both.")
    for key in ("infrastructure", "costs"):
        if key not in data:
            raise ConfigError(f"missing '{key}' (see configs/studies/gtfs_example.yaml).")
    raw = data["gtfs"]
    check_keys(raw, {f.name for f in fields(GtfsSpec)}, "gtfs")
    for key in ("feed", "date"):
        if key not in raw:
            raise ConfigError(f"gtfs: missing '{key}' (the feed, a zip or folder, and the "
                              "service day, YYYY-MM-DD).")
    keys = dict(raw)
    try:
        keys["date"] = date.fromisoformat(str(raw["date"])).isoformat()
    except ValueError:
        raise ConfigError(f"gtfs.date = {raw['date']!r}: give the service day as YYYY-MM-DD."
                          ) from None
    base = Path(where).parent if where != "study" else Path.cwd()
    for key in ("feed", "altitude", "speed_limits"):
        if keys.get(key) is not None:
            path = Path(str(keys[key]))
            keys[key] = str(path if path.is_absolute() or path.exists() else
                            base / path if (base / path).exists() else
                            paths.here_or_shipped(path))
    for key in ("routes", "terminals"):
        if keys.get(key) is not None:
            if not isinstance(keys[key], list):
                raise ConfigError(f"gtfs.{key} = {keys[key]!r}: give a list.")
            keys[key] = tuple(str(x) for x in keys[key])
    gtfs = GtfsSpec(**keys)
    for key in ("soc_start_pct", "reserve_soc_pct", "min_layover_min", "deadhead_speed_kmh"):
        positive(getattr(gtfs, key), f"gtfs.{key}", zero=key == "min_layover_min")
    if not gtfs.reserve_soc_pct < gtfs.soc_start_pct <= 100.0:
        raise ConfigError(f"gtfs: reserve_soc_pct = {gtfs.reserve_soc_pct} must lie below "
                          f"soc_start_pct = {gtfs.soc_start_pct} <= 100.")
    if gtfs.passengers is not None:
        positive(gtfs.passengers, "gtfs.passengers", zero=True)
    climate, days = _climate_and_days(data)
    infra = _infrastructure(data["infrastructure"], ())
    strategies = _depot_strategies(data.get("strategies"))
    costs = CostModel.load(data["costs"])
    from ebus_env.config import load_bus
    from ebus_env.gtfs.feed import check_feed

    load_bus(gtfs.bus)
    check_feed(gtfs.feed)
    return StudySpec(str(data.get("name", "timetable study")), (), infra, strategies, days,
                     costs, climate, where, gtfs, data)


def _depot_strategies(items) -> tuple[Strategy, ...]:
    if items is None:
        items = [{"name": p, "depot_plan": p} for p in DEPOT_PLANS]
    if not isinstance(items, list) or not items:
        raise ConfigError("strategies: give a list of depot plans, e.g. [{name: optimal, "
                          "depot_plan: optimal}], or leave it out for all three.")
    out = []
    for i, item in enumerate(items):
        check_keys(item, GTFS_STRATEGY_KEYS, f"strategies[{i}] (a timetable study's "
                   "strategies are depot plans)")
        plan = item.get("depot_plan", item.get("name"))
        if plan not in DEPOT_PLANS:
            raise ConfigError(f"strategies[{i}].depot_plan = {plan!r}: give one of "
                              f"{', '.join(DEPOT_PLANS)}.")
        out.append(Strategy(str(item.get("name", plan)), tuple(BASELINE.items()),
                            depot_plan=plan))
    if len({s.name for s in out}) < len(out):
        raise ConfigError("strategies: each needs a name of its own.")
    return tuple(out)


def _lines(items, climate) -> tuple[Line, ...]:
    if not isinstance(items, list) or not items:
        raise ConfigError("lines: give a list of at least one line.")
    env_keys = {f.name for f in fields(EnvConfig)} - STUDY_SET
    out = []
    for i, item in enumerate(items):
        check_keys(item, env_keys | LINE_KEYS, f"lines[{i}]")
        if "buses" not in item:
            raise ConfigError(f"lines[{i}]: missing 'buses' (how many buses run the line).")
        buses = positive(item["buses"], f"lines[{i}].buses", integer=True)
        headway = item.get("headway_min")
        if headway is not None:
            positive(headway, f"lines[{i}].headway_min")
        env = {k: v for k, v in item.items() if k not in LINE_KEYS}
        if climate is not None and {"ambient_mean_degc", "ambient_amplitude_k"} & set(env):
            raise ConfigError(f"lines[{i}]: the study's climate sets the ambient; drop "
                              "ambient_mean_degc / ambient_amplitude_k or the climate.")
        line = Line(str(item.get("name", f"line{i}")), buses, env,
                    None if headway is None else float(headway))
        service_h = float(env.get("service_h", EnvConfig.service_h))
        if headway is not None and (buses - 1) * headway / 60.0 >= service_h:
            raise ConfigError(f"lines[{i}]: {buses} buses {headway} min apart would not all "
                              f"depart within service_h = {service_h}.")
        out.append(line)
    return tuple(out)


def _infrastructure(data, lines) -> tuple[Infrastructure, ...]:
    check_keys(data, set(INFRA_KEYS), "infrastructure")
    missing = [k for k in INFRA_KEYS if k not in data]
    if missing:
        raise ConfigError(f"infrastructure: missing {', '.join(missing)} (a value or a list).")
    values = {k: data[k] if isinstance(data[k], list) else [data[k]] for k in INFRA_KEYS}
    out = []
    for combo in itertools.product(*values.values()):
        keys = dict(zip(INFRA_KEYS, combo, strict=True))
        for k in ("terminal_chargers", "depot_chargers"):
            keys[k] = positive(keys[k], f"infrastructure.{k}", integer=True, zero=True)
        for k in ("terminal_charger_kw", "depot_charger_kw", "site_limit_kw"):
            keys[k] = positive(keys[k], f"infrastructure.{k}")
        for k in ("terminal_charger_kw", "depot_charger_kw"):
            check("charger_kw", keys[k], f"infrastructure.{k}")
        out.append(Infrastructure(**keys))
    if any(o.terminal_chargers + o.depot_chargers == 0 for o in out):
        raise ConfigError("infrastructure: an option with no terminal and no depot charger "
                          "cannot recharge any bus; give at least one of them.")
    return tuple(out)


def _find_module(name: str):
    try:
        return importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return None


def _strategies(items) -> tuple[Strategy, ...]:
    if not isinstance(items, list) or not items:
        raise ConfigError("strategies: give a list of at least one strategy.")
    out, names = [], set()
    for i, item in enumerate(items):
        check_keys(item, STRATEGY_KEYS, f"strategies[{i}]")
        name = str(item.get("name", f"strategy{i}"))
        if name in names:
            raise ConfigError(f"strategies[{i}]: the name '{name}' is used twice.")
        names.add(name)
        settings = dict(BASELINE)
        for a in ACTIONS:
            if a.name in item:
                value = item[a.name]
                if not is_number(value) or not a.low <= value <= a.high:
                    raise ConfigError(f"strategies[{i}].{a.name} = {value!r}: give a number in "
                                      f"[{a.low:g}, {a.high:g}] {a.unit}.")
                settings[a.name] = float(value)
        policy = item.get("policy")
        if policy is not None and (not isinstance(policy, str) or ":" not in policy
                                   or _find_module(policy.partition(":")[0]) is None):
            raise ConfigError(f"strategies[{i}].policy = {policy!r}: give 'module:factory' of "
                              "an importable module (a callable returning an object with "
                              "predict(obs)).")
        policy_args = item.get("policy_args") or {}
        if not isinstance(policy_args, dict) or (policy_args and policy is None):
            raise ConfigError(f"strategies[{i}].policy_args = {policy_args!r}: give a mapping of "
                              "the policy factory's keyword arguments, with 'policy'.")
        decision_s = positive(item.get("decision_s", 60.0), f"strategies[{i}].decision_s")
        if 900.0 % decision_s > 1e-9:
            raise ConfigError(f"strategies[{i}].decision_s = {decision_s}: give a divisor of "
                              "900 s (the 15-min demand interval), e.g. 60.")
        out.append(Strategy(name, tuple(settings.items()), policy, decision_s, policy_args))
    return tuple(out)
