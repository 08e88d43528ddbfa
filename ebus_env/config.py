"""Bus configs (YAML): which effects a bus has, and values that override their defaults.

A config holds values only; every parameter is declared (default, unit, bounds, source) by its
effect. Layout::

    name: 12m
    description: 12 m city bus ...
    slots: {drivetrain: efficiency_map}          # optional, defaults per slot
    contributions: [aero_drag, rolling_resistance, road_grade, ...]
    with: [my_effects.py:headwind]               # a user's effects (path beside this file)
    params: {vehicle_body: {curb_mass_kg: 13000}, ...}
    tables: {rint_battery: {ocv_cell_v: lfp_a123}}
    bounds: {vehicle_body: {curb_mass_kg: [12000, 14500]}}   # may only narrow
    service: {soc_start_pct: 95, ambient_degc: 10, layover_every_min: 60, ...}

An overlay (e.g. a calibration result) has the same keys plus ``with``/``without`` lists and is
merged on top. Unknown keys fail with a close-match suggestion.
"""

from __future__ import annotations

import copy
import hashlib
import importlib.util
import re
import sys
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import yaml

from ebus_env import paths
from ebus_env.effects.base import Effect, get_effect, registered_effects
from ebus_env.errors import ConfigError, unknown_name
from ebus_env.inputs import RANGES, check


@dataclass
class Service:
    """How a bus runs a service day built from a cycle (``ebus simulate --cycle``)."""

    soc_start_pct: float = 95.0
    ambient_degc: float = 15.0
    start_time_h: float = 5.0
    layover_every_min: float = 60.0
    layover_min: float = 6.0
    layover_charger_kw: float | None = None  # None: the charger's power parameter
    charge_at_layovers: bool = True
    depot_charger_kw: float | None = None
    passenger_profile: dict | None = None  # {hour of day: passengers}, linear in between


LOAD_CATEGORIES = {"driver": 0.0, "half": 0.5, "full": 1.0}
"""The paper's passenger-load categories as ``passenger_load.load_frac``."""


_TOP_KEYS = {"name", "description", "slots", "contributions", "params", "tables", "bounds",
             "service", "with"}
_OVERLAY_KEYS = _TOP_KEYS | {"with", "without", "base", "calibration"}


@dataclass
class BusConfig:
    """A bus: its effects, parameter values and service defaults (see module docstring)."""

    name: str = ""
    description: str = ""
    slots: dict = field(default_factory=dict)
    contributions: list = field(default_factory=list)
    params: dict = field(default_factory=dict)
    tables: dict = field(default_factory=dict)
    bounds: dict = field(default_factory=dict)
    service: Service = field(default_factory=Service)
    path: Path | None = None

    def build(self, dt_s: float = 0.1):
        """Compose the model (its kernel compiles, or loads from cache, on first run)."""
        from ebus_env.model.model import build_model

        check("dt_s", dt_s, "dt_s")
        return build_model(self.slots, self.contributions, self.params, self.tables,
                           self.bounds, dt_s=dt_s, name=self.name)

    # -- changing the composition ---------------------------------------------------------
    def with_effect(self, item: str | Effect) -> BusConfig:
        """A copy with an effect added (a contribution) or put in its slot; the values and
        bounds of the effect it replaces carry over to the parameters of the same name."""
        eff = item if isinstance(item, Effect) else resolve_effect(item)
        new = copy.deepcopy(self)
        if eff.slot is not None:
            from ebus_env.signals import SLOTS

            old = new.slots.get(eff.slot, SLOTS[eff.slot].default)
            names = {p.name for p in eff.params}
            for store in (new.params, new.bounds):
                shared = {k: v for k, v in (store.get(old) or {}).items() if k in names}
                if old != eff.name and shared:
                    store[eff.name] = {**shared, **(store.get(eff.name) or {})}
            new.slots[eff.slot] = eff.name
        elif eff.name not in new.contributions:
            new.contributions.append(eff.name)
        return new

    def effect_names(self) -> list[str]:
        """The effects in this bus: its contributions and each slot's implementation."""
        from ebus_env.signals import SLOTS

        return list(self.contributions) + [self.slots.get(s, SLOTS[s].default) for s in SLOTS]

    def without_effect(self, name: str) -> BusConfig:
        """A copy without an effect (a slot implementation leaves its slot empty)."""
        new = copy.deepcopy(self)
        if name in new.contributions:
            new.contributions.remove(name)
            return new
        from ebus_env.signals import SLOTS

        for slot_name, slot in SLOTS.items():
            if new.slots.get(slot_name, slot.default) == name:
                new.slots[slot_name] = "none"
                return new
        raise unknown_name(f"effect in bus '{self.name}'", name, self.effect_names())

    def overlay(self, data: dict, source: str = "overlay") -> BusConfig:
        """A copy with an overlay mapping merged on top (see module docstring)."""
        _check_keys(data, _OVERLAY_KEYS, source)
        new = copy.deepcopy(self)
        for key in ("name", "description"):
            if key in data:
                setattr(new, key, str(data[key]))
        new.slots.update(_mapping(data.get("slots"), "slots", source))
        if "contributions" in data:
            new.contributions = _names(data["contributions"], "contributions", source)
        for key in ("params", "tables", "bounds"):
            for effect_name, values in _mapping(data.get(key), key, source).items():
                new_values = _mapping(values, f"{key}.{effect_name}", source)
                for name, value in new_values.items():
                    _check_value(key, f"{effect_name}.{name}", value, source)
                getattr(new, key).setdefault(effect_name, {}).update(new_values)
        if "service" in data:
            known = {f.name for f in fields(Service)}
            service = _mapping(data["service"], "service", source)
            _check_keys(service, known, f"{source}: service")
            new.service = Service(**{**asdict(new.service), **service})
            check_service(new.service, source)
        for item in data.get("with") or []:
            new = new.with_effect(_relative_to(item, source))
        for item in data.get("without") or []:
            new = new.without_effect(item)
        return new

    def to_dict(self) -> dict:
        return {"name": self.name, "description": self.description, "slots": self.slots,
                "contributions": self.contributions, "params": self.params,
                "tables": self.tables, "bounds": self.bounds, "service": asdict(self.service)}


def _relative_to(item: str, source: str) -> str:
    """``file.py:Name`` with a relative file found beside the config that names it."""
    if ".py:" not in item:
        return item
    file, name = item.split(":", 1)
    beside = Path(source).parent / file
    if not Path(file).is_absolute() and not Path(file).exists() and beside.exists():
        return f"{beside}:{name}"
    return item


def _is_number(value) -> bool:
    """A YAML number, or text PyYAML leaves unread that is one (``1.0e6``: YAML 1.1 wants a
    sign in the exponent)."""
    if isinstance(value, str):
        try:
            float(value)
        except ValueError:
            return False
        return True
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _check_value(key: str, qualified: str, value, source: str) -> None:
    """A parameter value is a number and a bound a [low, high] pair of numbers (a unit or a
    list there is an error naming the file and key, never a bare ``float()`` failure)."""
    if key == "params" and not _is_number(value):
        raise ConfigError(f"{source}: params {qualified} = {value!r} is not a number. Fix: "
                          "give the value alone in the parameter's unit (see `ebus effects`), "
                          "e.g. 13000 for a mass of 13 t in kg.")
    if key == "bounds" and not (isinstance(value, (list, tuple)) and len(value) == 2
                                and all(_is_number(v) for v in value)):
        raise ConfigError(f"{source}: bounds {qualified} = {value!r} is not a [low, high] pair "
                          "of numbers.")
    if key == "tables" and not isinstance(value, (str, list, dict)):
        raise ConfigError(f"{source}: tables {qualified} = {value!r} must name a table or "
                          "give its values (a list, or x and y).")


def _names(value, what: str, source: str) -> list[str]:
    if value is None:
        return []
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"{source}: '{what}' must be a list of effect names, got {value!r}.")
    return list(value)


_SERVICE_RANGES = {"soc_start_pct": "soc_start_pct", "ambient_degc": "ambient_degc",
                   "start_time_h": "start_time_h", "layover_every_min": "layover_every_min",
                   "layover_min": "layover_min", "layover_charger_kw": "charger_kw",
                   "depot_charger_kw": "charger_kw"}


def check_service(service: Service, source: str) -> None:
    """Every service value in its declared range (:mod:`ebus_env.inputs`)."""
    for key, name in _SERVICE_RANGES.items():
        value = getattr(service, key)
        no_layovers = key == "layover_every_min" and service.layover_min == 0 and value == 0
        if value is None and getattr(Service, key) is not None:
            raise ConfigError(f"{source}: service.{key} is empty; give a number in "
                              f"{RANGES[name].text()}.")
        if value is not None and not no_layovers:
            check(name, value, f"{source}: service.{key}")
    if not isinstance(service.charge_at_layovers, bool):
        raise ConfigError(f"{source}: service.charge_at_layovers = "
                          f"{service.charge_at_layovers!r} must be true or false.")
    profile = service.passenger_profile
    if profile is not None:
        if not isinstance(profile, dict) or not profile or not all(
                _is_number(h) and 0 <= h <= 24 and _is_number(n) and n >= 0
                for h, n in profile.items()):
            raise ConfigError(f"{source}: service.passenger_profile must map hours of the day "
                              f"(0-24) to passengers (>= 0), got {profile!r}.")
        for hour, count in profile.items():
            check("log_passengers", count, f"{source}: service.passenger_profile[{hour}]")


def _mapping(value, what: str, source: str) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ConfigError(f"{source}: '{what}' must be a mapping, got {type(value).__name__}.")
    return value


def _check_keys(data: dict, allowed: set, source: str) -> None:
    for key in data:
        if key not in allowed:
            raise unknown_name(f"key in {source}", str(key), allowed)


class _UniqueKeyLoader(yaml.SafeLoader):
    """YAML loader that refuses a key given twice in one mapping (the last would win)."""

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"the key '{key}' is given twice in one mapping; keep one",
                    key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep)


# YAML 1.2's floats: PyYAML (YAML 1.1) reads ``3e-4`` and ``1e6``, without a dot, as strings
_UniqueKeyLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"), list("-+0123456789"))


def _yaml_problem(exc: yaml.YAMLError) -> str:
    """One line: the problem and where (``line 12, column 5``)."""
    mark = getattr(exc, "problem_mark", None)
    problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    return problem + (f" at line {mark.line + 1}, column {mark.column + 1}" if mark else "")


def read_yaml(path: Path) -> dict:
    """A YAML mapping from a file; a missing file, bad YAML or a duplicated key is a
    :class:`ConfigError` naming the file (and line)."""
    try:
        data = yaml.load(Path(path).read_text(), Loader=_UniqueKeyLoader)  # a SafeLoader
    except FileNotFoundError:
        raise ConfigError(f"Config file {path} does not exist.") from None
    except IsADirectoryError:
        raise ConfigError(f"{path} is a folder. Fix: give a YAML file in it.") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path} is not valid YAML: {_yaml_problem(exc)}.") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path} must hold a mapping at the top level.")
    return data


def find_config(name: str | Path, kind: str = "bus") -> Path:
    """A config path: as given (a relative ``configs/...`` path the working folder lacks: the
    shipped file), or ``configs/<kind>/<name>.yaml`` in the working folder or among the
    shipped configs."""
    path = paths.here_or_shipped(name)
    if path.suffix in (".yaml", ".yml"):
        if path.exists():
            return path
        raise ConfigError(f"Config file {path} does not exist.")
    for base in (Path.cwd() / "configs" / kind, paths.configs(kind)):
        candidate = base / f"{name}.yaml"
        if candidate.exists():
            return candidate
    if path.is_dir():
        raise ConfigError(f"{path} is a folder. Fix: give a YAML file in it, or a {kind} "
                          f"config's name ({', '.join(paths.config_names(kind))}).")
    raise unknown_name(f"{kind} config", str(name), paths.config_names(kind))


def load_bus(name: str | Path, with_=(), without=(), overlays=()) -> BusConfig:
    """Load a bus config by path or name (``12m``), then apply ``overlays`` (paths or mappings),
    add effects ``with_`` (names or ``file.py:Name``) and drop ``without``."""
    path = find_config(name)
    data = read_yaml(path)
    _check_keys(data, _TOP_KEYS, str(path))
    bus = BusConfig(name=str(data.get("name", path.stem)), path=path).overlay(data, str(path))
    if not bus.contributions:
        raise ConfigError(f"{path} lists no contributions: the bus would drive without drag, "
                          "rolling resistance, grade or auxiliaries. Fix: list them, e.g. "
                          "contributions: [aero_drag, rolling_resistance, road_grade, "
                          "passenger_mass, auxiliaries, cabin_hvac] as in the shipped 12m.yaml.")
    for overlay in overlays:
        if isinstance(overlay, dict):
            bus = bus.overlay(overlay)
        else:
            bus = bus.overlay(read_yaml(Path(overlay)), str(overlay))
    for item in with_:
        bus = bus.with_effect(item)
    for item in without:
        bus = bus.without_effect(item)
    return bus


# -- user effects -------------------------------------------------------------------------
def load_effects_file(path: str | Path):
    """Import a user's Python file of effects (its ``@effect`` decorators register them)."""
    path = Path(path).resolve()
    if not path.exists():
        raise ConfigError(f"Effects file {path} does not exist.")
    key = hashlib.sha1(str(path).encode()).hexdigest()[:10]
    module_name = f"ebus_user_effects_{path.stem}_{key}"
    spec = importlib.util.spec_from_file_location(module_name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module
    try:
        spec.loader.exec_module(module)
    except Exception as exc:  # the user's code: say where it failed
        raise ConfigError(f"Could not import effects file {path}: {exc!r}") from exc
    return module


def resolve_effect(item: str) -> Effect:
    """An effect by registry name, or ``path/to/file.py:Name`` (an object or registry name in
    that file)."""
    if ":" in item and item.split(":", 1)[0].endswith(".py"):
        file, name = item.split(":", 1)
        module = load_effects_file(file)
        obj = getattr(module, name, None)
        if isinstance(obj, Effect):
            return obj
        found = {v.name: v for v in vars(module).values() if isinstance(v, Effect)}
        if name in found:
            return found[name]
        raise unknown_name(f"effect in {file}", name,  # by effect name or variable, once
                           set(found) | {k for k, v in vars(module).items()
                                         if isinstance(v, Effect)})
    if item.endswith(".py"):
        raise ConfigError(f"Name the effect in the file too: '{item}:EffectName'.")
    registered_effects()
    return get_effect(item)
