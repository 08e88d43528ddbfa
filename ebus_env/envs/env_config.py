"""The episode config of the environments (:class:`EnvConfig`, ``configs/env/*.yaml``) and how
a config dataclass is read from a name, a YAML file or a mapping (:func:`config_keys`)."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from ebus_env import paths
from ebus_env.config import read_yaml
from ebus_env.envs.climate import climate_of
from ebus_env.envs.reward import Reward
from ebus_env.errors import ConfigError
from ebus_env.inputs import ENV_KEYS, check

CONFIG_DIR = paths.configs("env")
EnvSource = str | Path | dict | None
"""An env config: a name in ``configs/env``, a YAML path, a mapping of its keys or None
(the defaults)."""


@dataclass(frozen=True)
class EnvConfig:
    """Everything that defines an episode (``configs/env/*.yaml`` hold these keys)."""

    bus: str = "12m"  # name in configs/bus or a path
    overlay: str | None = None  # a calibrated overlay (``ebus calibrate --out``)
    cycle: str | None = "sort2"  # laps of a cycle, or
    route: str | None = None  # a King County route (``kc45_out``...), or
    log: str | None = None  # a measured log (CSV/Parquet): its speed profile is one trip
    log_columns: str | dict | None = None  # the log's column map or preset (configs/logs)
    laps_per_trip: int | None = None  # cycle laps between terminal layovers (None: ~1 h)
    service_h: float = 13.5
    start_time_h: float = 5.0
    decision_s: float = 60.0  # a decision's length (with decide_at_stops: the longest)
    decide_at_stops: bool = False  # decide at each departure (stop-to-stop segments, layovers)
    dt_s: float = 0.1
    soc_start_pct: float = 95.0
    reserve_soc_pct: float = 20.0
    layover_min: float = 6.0  # scheduled layover at the terminal, on the charger
    min_layover_min: float = 2.0  # the shortest layover (plugging in and out)
    charger_kw: float | None = None  # terminal charger rating (None: the bus's charger)
    charge_at_terminal: bool = True
    climate: str | dict | None = None  # monthly normals (ebus_env.envs.climate), with month
    month: int | None = None  # 1-12: the climate's month (sets the two ambient keys below)
    ambient_mean_degc: float | None = None  # daily mean (default 15 without a climate)
    ambient_amplitude_k: float | None = None  # half the daily swing (coldest 05:00,
    # warmest 15:00; default 4 without a climate)
    ambient_random_k: float = 2.0  # daily mean drawn +- this per episode
    passengers_base_frac: float = 0.2  # of capacity, between peaks
    passengers_peak_frac: float = 0.8  # at the morning and evening peaks
    passengers_random_frac: float = 0.15  # each drawn +- this per episode
    jerk_mps3: float = 1.0  # ramp of the acceleration (paper App. B.1)
    comfort_decel_mps2: float = 1.0  # braking towards stops
    reward: dict | Reward = field(default_factory=dict)  # weights of Reward, or one

    def __post_init__(self) -> None:
        mean, amplitude = self.ambient_mean_degc, self.ambient_amplitude_k
        if self.climate is not None or self.month is not None:
            if self.climate is None or self.month is None:
                raise ConfigError("climate and month go together: e.g. climate: barcelona, "
                                  "month: 7.")
            if mean is not None or amplitude is not None:
                raise ConfigError("Give either climate and month or ambient_mean_degc and "
                                  "ambient_amplitude_k, not both (the climate sets them).")
            mean, amplitude = climate_of(self.climate).ambient(self.month)
        object.__setattr__(self, "ambient_mean_degc", 15.0 if mean is None else float(mean))
        object.__setattr__(self, "ambient_amplitude_k",
                           4.0 if amplitude is None else float(amplitude))
        for key, name in ENV_KEYS.items():
            if getattr(self, key) is not None:
                value = getattr(self, key)
                check(name, value, f"env config {key}")
                if key == "laps_per_trip" and float(value) != int(float(value)):
                    raise ConfigError(f"env config laps_per_trip = {value!r} must be a whole "
                                      "number.")
                kind = int if key == "laps_per_trip" else float
                object.__setattr__(self, key, kind(float(value)))  # "1e3" read from YAML
        for key in ("bus", "overlay", "cycle", "route", "log"):
            if not isinstance(getattr(self, key), (str, Path, type(None))):
                raise ConfigError(f"env config {key} = {getattr(self, key)!r} must name a "
                                  "config or file.")
        if not isinstance(self.reward, (dict, Reward)):
            raise ConfigError(f"env config reward = {self.reward!r} must map reward terms to "
                              "weights (or be a Reward).")
        for key in ("decide_at_stops", "charge_at_terminal"):
            if not isinstance(getattr(self, key), bool):
                raise ConfigError(f"env config {key} = {getattr(self, key)!r} must be true or "
                                  "false.")
        if self.min_layover_min > self.layover_min:
            raise ConfigError(f"env config min_layover_min = {self.min_layover_min:g} is longer "
                              f"than layover_min = {self.layover_min:g}.")

    @property
    def ambient_day(self) -> tuple[float, float]:
        """The day's ambient: its mean [degC] and half its swing [K] (the climate's, the
        config's or the defaults, as resolved on construction)."""
        mean, amplitude = self.ambient_mean_degc, self.ambient_amplitude_k
        assert mean is not None and amplitude is not None  # set by __post_init__
        return mean, amplitude

    @classmethod
    def load(cls, source: EnvSource = None, **overrides: Any) -> EnvConfig:
        """From a name in ``configs/env``, a YAML path or a mapping, with overrides."""
        return cls(**config_keys(cls, source, overrides, "env"))


def config_keys(cls: type, source: str | Path | dict | None, overrides: dict, kind: str,
                folder: Path = CONFIG_DIR) -> dict:
    """The keys of a config dataclass ``cls`` from a mapping, a YAML path or a name in
    ``folder``, with overrides on top; a missing file or an unknown key is a clear error."""
    data: dict = {}
    if isinstance(source, dict):
        data = dict(source)
    elif source is not None:
        path = paths.here_or_shipped(source)  # configs/env/x.yaml from any folder too
        if not path.suffix:
            path = folder / f"{source}.yaml"
        if not path.exists():
            names = sorted(p.stem for p in folder.glob("*.yaml"))
            raise ConfigError(f"No {kind} config '{source}' (looked for {path}); shipped: "
                              f"{', '.join(names)}.")
        data = read_yaml(path)  # bad YAML or a duplicated key: a ConfigError with the line
    data.update(overrides)
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(f"Unknown {kind} config key(s) {unknown}; known: {sorted(known)}.")
    return data
