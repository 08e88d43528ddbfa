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
import sys
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import yaml

from ebus_env.effects.base import Effect, get_effect, registered_effects
from ebus_env.errors import ConfigError, unknown_name

ROOT = Path(__file__).resolve().parent.parent
"""Repository root: ``configs/`` and ``data/`` live here."""


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
        present = list(new.contributions) + [new.slots.get(s, SLOTS[s].default) for s in SLOTS]
        raise unknown_name(f"effect in bus '{self.name}'", name, present)

    def overlay(self, data: dict, source: str = "overlay") -> BusConfig:
        """A copy with an overlay mapping merged on top (see module docstring)."""
        _check_keys(data, _OVERLAY_KEYS, source)
        new = copy.deepcopy(self)
        for key in ("name", "description"):
            if key in data:
                setattr(new, key, str(data[key]))
        new.slots.update(_mapping(data.get("slots"), "slots", source))
        if "contributions" in data:
            new.contributions = list(data["contributions"] or [])
        for key in ("params", "tables", "bounds"):
            for effect_name, values in _mapping(data.get(key), key, source).items():
                new_values = _mapping(values, f"{key}.{effect_name}", source)
                getattr(new, key).setdefault(effect_name, {}).update(new_values)
        if "service" in data:
            known = {f.name for f in fields(Service)}
            service = _mapping(data["service"], "service", source)
            _check_keys(service, known, f"{source}: service")
            new.service = Service(**{**asdict(new.service), **service})
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


def read_yaml(path: Path) -> dict:
    try:
        data = yaml.safe_load(Path(path).read_text())
    except FileNotFoundError:
        raise ConfigError(f"Config file {path} does not exist.") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path} is not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path} must hold a mapping at the top level.")
    return data


def find_config(name: str | Path, kind: str = "bus") -> Path:
    """A config path: as given, or ``configs/<kind>/<name>.yaml`` here or in the repository."""
    path = Path(name)
    if path.suffix in (".yaml", ".yml"):
        if path.exists():
            return path
        raise ConfigError(f"Config file {path} does not exist.")
    for base in (Path.cwd() / "configs" / kind, ROOT / "configs" / kind):
        candidate = base / f"{name}.yaml"
        if candidate.exists():
            return candidate
    available = sorted(p.stem for p in (ROOT / "configs" / kind).glob("*.yaml"))
    raise unknown_name(f"{kind} config", str(name), available)


def load_bus(name: str | Path, with_=(), without=(), overlays=()) -> BusConfig:
    """Load a bus config by path or name (``12m``), then apply ``overlays`` (paths or mappings),
    add effects ``with_`` (names or ``file.py:Name``) and drop ``without``."""
    path = find_config(name)
    data = read_yaml(path)
    _check_keys(data, _TOP_KEYS, str(path))
    bus = BusConfig(name=str(data.get("name", path.stem)), path=path).overlay(data, str(path))
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
        raise unknown_name(f"effect in {file}", name,
                           list(found) + [k for k, v in vars(module).items()
                                          if isinstance(v, Effect)])
    if item.endswith(".py"):
        raise ConfigError(f"Name the effect in the file too: '{item}:EffectName'.")
    registered_effects()
    return get_effect(item)
