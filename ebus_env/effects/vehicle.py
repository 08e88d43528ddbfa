"""Vehicle body, passengers and their mass."""

from __future__ import annotations

import math

import numpy as np

from ebus_env.effects.base import Param, effect
from ebus_env.effects.tables import Table, TableData, lookup1
from ebus_env.units import PASSENGER_MASS_KG


@effect("vehicle_body", slot="vehicle", params=[
    Param("curb_mass_kg", 13000.0, "kg", (500.0, 40000.0), "Curb mass m_0, driver included",
          "12 m: ADVISOR RTS06/Orion VI 12.2-12.6 t, eCitaro 13.5 t (docs/physics.md §2.5)"),
    Param("rotational_mass_factor", 1.05, "1", (1.0, 1.2),
          "Rotating-mass factor delta: effective inertia m_eff = delta * m", "docs/physics.md §2.1"),
    Param("max_speed_kmh", 80.0, "km/h", (10.0, 250.0), "Maximum vehicle speed v_max",
          "Urban bus governor setting"),
    Param("max_brake_decel_mps2", 5.0, "m/s^2", (1.0, 10.0),
          "Largest deceleration the service brakes give", "Typical bus service brake"),
])
def vehicle_body(curb_mass_kg: float, rotational_mass_factor: float, max_speed_kmh: float,
                 max_brake_decel_mps2: float) -> tuple[float, float, float, float]:
    """Rigid body of the bus: curb mass, rotating-mass factor and speed/brake limits."""
    return curb_mass_kg, rotational_mass_factor, max_speed_kmh / 3.6, max_brake_decel_mps2


@effect("passenger_load", slot="passengers", label="constant passenger load", params=[
    Param("load_frac", 0.5, "1", (0.0, 1.0),
          "Passenger load as a fraction of max_passengers (paper's categories: driver only 0, "
          "half load 0.5, full load 1)", "Hasan et al. 2023, tuned parameter"),
    Param("max_passengers", 85.0, "1", (1.0, 250.0), "Passenger capacity n_max",
          "12 m: 70-95 (Solaris Urbino 12: 94); 18 m: 120-150", whole=True),
])
def passenger_load(passenger_count: float, load_frac: float, max_passengers: float) -> float:
    """Passengers on board: the measured count where the profile gives one, else
    ``n = load_frac * n_max``."""
    if math.isnan(passenger_count):
        return load_frac * max_passengers
    return passenger_count


@effect("passenger_mass", sink="mass_kg", label="passenger mass", drivers=("passengers",), params=[
    Param("passenger_mass_kg", PASSENGER_MASS_KG, "kg", (50.0, 100.0), "Mass per passenger m_p",
          "UN ECE R107 design mass"),
])
def passenger_mass(passengers: float, passenger_mass_kg: float) -> float:
    """Mass of the passengers: m_pax = n * m_p [kg]."""
    return passengers * passenger_mass_kg


COMMUTER_SHAPE = Table(
    "load_shape", "1", "Passenger load over the time of day [h] (x), 0 at base, 1 at peak",
    presets={"commuter": TableData(
        (0.0, 5.0, 6.0, 7.5, 9.0, 10.0, 15.0, 16.5, 18.0, 19.5, 22.0, 24.0),
        (0.0, 0.0, 0.3, 1.0, 1.0, 0.4, 0.4, 1.0, 1.0, 0.3, 0.0, 0.0),
        source="morning and evening commuter peaks (docs/physics.md §2.1)")},
    default="commuter",
)


@effect("passenger_schedule", slot="passengers", label="passenger load over the day",
        drivers=("time_of_day_h",),
        tables=[COMMUTER_SHAPE], key_params=("peak_frac", "base_frac"), refines="passenger_load", params=[
    Param("base_frac", 0.2, "1", (0.0, 1.0), "Load between the peaks, fraction of n_max"),
    Param("peak_frac", 0.9, "1", (0.0, 1.0), "Load at the peaks, fraction of n_max"),
    Param("max_passengers", 85.0, "1", (1.0, 250.0), "Passenger capacity n_max", whole=True),
])
def passenger_schedule(passenger_count: float, time_of_day_h: float, base_frac: float, peak_frac: float,
                       max_passengers: float, load_shape: np.ndarray) -> float:
    """Passengers over the day: the measured count where the profile has one, else
    n = n_max (base + (peak - base) shape(time of day)), with commuter peaks."""
    if not math.isnan(passenger_count):
        return passenger_count
    shape = lookup1(load_shape, time_of_day_h)
    return max_passengers * (base_frac + (peak_frac - base_frac) * shape)
