"""Checks of a study file's values: each failure is one ConfigError line naming the key."""

from __future__ import annotations

import math

from ebus_env.errors import ConfigError, did_you_mean


def check_keys(data, known, where: str) -> None:
    """``data`` must be a mapping whose keys are all in ``known``."""
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping, got {data!r}.")
    for key in data:
        if key not in known:
            raise ConfigError(f"{where}: unknown key '{key}'.{did_you_mean(key, known)} "
                              f"Known: {', '.join(sorted(known))}.")


def is_number(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def positive(value, where: str, integer: bool = False, zero: bool = False) -> float:
    """``value`` as a number > 0 (>= 0 with ``zero``; an integer with ``integer``)."""
    ok = is_number(value) and (value >= 0 if zero else value > 0) and (
        not integer or float(value).is_integer())
    if not ok:
        kind = "an integer" if integer else "a number"
        raise ConfigError(f"{where} = {value!r}: give {kind} {'>= 0' if zero else '> 0'}.")
    return int(value) if integer else float(value)
