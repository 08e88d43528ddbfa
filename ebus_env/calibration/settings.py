"""Calibration configs (YAML, ``configs/calibration/``): free parameters, prior ranges, fixed
values and the optimiser's constants. Unknown keys fail with a close-match suggestion."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from ebus_env.calibration.isopt import ISOPTSettings
from ebus_env.calibration.windowed import WindowSettings
from ebus_env.config import find_config, read_yaml
from ebus_env.errors import ConfigError, unknown_name

if TYPE_CHECKING:
    from _typeshed import DataclassInstance


@dataclass
class CalibrationConfig:
    params: list[str] | None = None
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)
    fixed: dict[str, float] = field(default_factory=dict)
    categorical_load: bool = False
    isopt: ISOPTSettings = field(default_factory=ISOPTSettings)
    polish_starts: int = 4
    windows: WindowSettings = field(default_factory=WindowSettings)


T = TypeVar("T", bound="DataclassInstance")


def _pair(value: Any) -> tuple[float, float]:
    """A YAML ``[low, high]`` as two floats (a ValueError for anything else)."""
    low, high = (float(x) for x in value)
    return low, high


def _dataclass_from(cls: type[T], data: dict[str, Any], where: str) -> T:
    names = {f.name for f in fields(cls)}
    for key in data:
        if key not in names:
            raise unknown_name(f"key in {where}", key, names)
    return cls(**data)


def load_calibration_config(name: str | Path | None = None) -> CalibrationConfig:
    """A calibration config by path or name (``default``); None gives the defaults."""
    if name is None:
        return CalibrationConfig()
    path = find_config(name, kind="calibration")
    data = read_yaml(path)
    top = {f.name for f in fields(CalibrationConfig)}
    for key in data:
        if key not in top:
            raise unknown_name(f"key in {path}", key, top)
    try:
        ranges = {str(k): _pair(v) for k, v in (data.get("ranges") or {}).items()}
    except (TypeError, ValueError):
        raise ConfigError(f"{path}: ranges must map names to [low, high].") from None
    return CalibrationConfig(
        params=list(data["params"]) if data.get("params") else None,
        ranges=ranges,
        fixed={k: float(v) for k, v in (data.get("fixed") or {}).items()},
        categorical_load=bool(data.get("categorical_load", False)),
        isopt=_dataclass_from(ISOPTSettings, data.get("isopt") or {}, f"{path}: isopt"),
        polish_starts=int(data.get("polish_starts", 4)),
        windows=_dataclass_from(WindowSettings, data.get("windows") or {}, f"{path}: windows"),
    )


def calibration_config_file(name: str | Path | None) -> Path | None:
    """The file of the calibration config ``name`` (None: the defaults, no file)."""
    return None if name is None else find_config(name, kind="calibration")
