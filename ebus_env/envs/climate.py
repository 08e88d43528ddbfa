"""Climate normals by month: the ambient temperature of the environments' service days.

A day's ambient follows a daily cycle between the month's mean daily minimum (at 05:00) and
mean daily maximum (at 15:00) (:func:`ebus_env.envs.batch.ambient_degc`), so an env config
needs only ``climate`` and ``month``::

    mean = (T_min + T_max) / 2,   amplitude = (T_max - T_min) / 2

Shipped (``CLIMATES``), with their sources:

* ``barcelona``: Barcelona city (Can Bruixa), Servei Meteorologic de Catalunya, as charted in
  Wikipedia's "Climate of Barcelona" (read 2026-11 through the mirror
  wiki.camac.ltd/content/wikipedia_en_all_mini_2026-03/Climate_of_Barcelona);
* ``gothenburg``: climatestotravel.com/climate/sweden/gothenburg (average daily minimum and
  maximum, whole degrees).

Osnabrueck (the paper's 18 m buses) is not shipped: no citable table of monthly normals was
within reach when this was written. Give any place's normals as a mapping instead, e.g. from
the DWD's multi-annual station means (opendata.dwd.de, climate/multi_annual)::

    climate: {name: osnabrueck, min_degc: [...12 values], max_degc: [...12], source: "..."}
"""

from __future__ import annotations

from dataclasses import dataclass

from ebus_env.errors import ConfigError, unknown_name

MONTHS = ("jan", "feb", "mar", "apr", "may", "jun", "jul", "aug", "sep", "oct", "nov", "dec")


@dataclass(frozen=True)
class Climate:
    """Mean daily minimum and maximum temperature [degC] of each month, January first."""

    name: str
    min_degc: tuple[float, ...]
    max_degc: tuple[float, ...]
    source: str

    def __post_init__(self) -> None:
        for key in ("min_degc", "max_degc"):
            values = getattr(self, key)
            if len(values) != 12:
                raise ConfigError(f"Climate '{self.name}': {key} needs 12 monthly values "
                                  f"(January first), got {len(values)}.")
        for m, (low, high) in enumerate(zip(self.min_degc, self.max_degc, strict=True)):
            if not -60.0 <= low <= high <= 60.0:
                raise ConfigError(f"Climate '{self.name}', {MONTHS[m]}: min_degc {low} must not "
                                  f"exceed max_degc {high} (both within +-60 degC).")

    def ambient(self, month: int) -> tuple[float, float]:
        """(daily mean [degC], half the daily swing [K]) of ``month`` (1-12)."""
        if not isinstance(month, int | float) or month not in range(1, 13):
            raise ConfigError(f"month = {month!r}: give a month number 1-12.")
        low, high = self.min_degc[int(month) - 1], self.max_degc[int(month) - 1]
        return 0.5 * (low + high), 0.5 * (high - low)


CLIMATES = {c.name: c for c in (
    Climate("barcelona",
            min_degc=(9, 9, 11, 13, 16, 20, 23, 23, 20, 17, 12, 10),
            max_degc=(15, 16, 17, 19, 23, 26, 29, 29, 26, 23, 18, 15),
            source="Servei Meteorologic de Catalunya, Barcelona (Can Bruixa), via Wikipedia "
                   "'Climate of Barcelona'"),
    Climate("gothenburg",
            min_degc=(-3, -4, -1, 2, 7, 11, 13, 12, 9, 6, 2, -2),
            max_degc=(1, 1, 5, 10, 16, 20, 21, 21, 16, 12, 6, 3),
            source="https://www.climatestotravel.com/climate/sweden/gothenburg"),
)}


def climate_of(value: str | dict | Climate) -> Climate:
    """A shipped climate by name, or one from a mapping (name, min_degc, max_degc, source)."""
    if isinstance(value, Climate):
        return value
    if isinstance(value, str):
        if value.lower() not in CLIMATES:
            raise unknown_name("climate", value, CLIMATES)
        return CLIMATES[value.lower()]
    if isinstance(value, dict):
        keys = set(value)
        if not {"min_degc", "max_degc"} <= keys or not keys <= {"name", "min_degc", "max_degc",
                                                                "source"}:
            raise ConfigError("A climate mapping needs min_degc and max_degc (12 values each, "
                              f"January first) and may have name and source; got {sorted(keys)}.")
        return Climate(str(value.get("name", "custom")), tuple(map(float, value["min_degc"])),
                       tuple(map(float, value["max_degc"])), str(value.get("source", "config")))
    raise ConfigError(f"climate = {value!r}: give a name ({', '.join(CLIMATES)}) or a mapping.")
