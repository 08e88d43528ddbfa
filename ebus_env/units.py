"""Units, physical constants and sign conventions, written once.

The model computes in SI (m, s, kg, N, W, J, A, V, K offsets in degC) and reports in the units
people expect (km, h, kWh, kW, km/h, %). Conversions are written where they happen, beside names
that carry their units (``speed_kmh / 3.6``, ``energy_j / J_PER_KWH``): a call would hide no more,
and a numba kernel could not make it.

Sign conventions
----------------
* Battery power and current > 0 **discharge** the pack; < 0 charge it.
* Wheel power and force > 0 **propel** the bus; < 0 brake it.
* Road-load forces > 0 **resist** motion (uphill grade > 0, downhill < 0).
* Charger and grid power >= 0 flow **into** the bus.
* Heat flows into the cabin are > 0.
"""

from __future__ import annotations

GRAVITY_MPS2 = 9.80665
"""Standard gravity [m/s^2]."""

PASSENGER_MASS_KG = 68.0
"""Design mass of one passenger [kg] (UN ECE R107; ADVISOR uses 150 lb = 68 kg)."""

AIR_CP_J_PER_KG_K = 1005.0
"""Specific heat of air at constant pressure [J/(kg K)]."""

J_PER_KWH = 3.6e6
"""Joules in a kilowatt-hour."""


DIMENSIONLESS = "1"
"""The unit of a dimensionless quantity (a fraction, a count, a factor), as SI writes it."""


def shown_unit(unit: str) -> str:
    """The unit as people read it beside a number: none for a dimensionless quantity."""
    return "" if unit == DIMENSIONLESS else unit


def with_unit(number: str, unit: str) -> str:
    """``"27.5 degC"``, ``"0.099"`` (no unit "1" after a dimensionless number)."""
    return f"{number} {unit}" if shown_unit(unit) else number
