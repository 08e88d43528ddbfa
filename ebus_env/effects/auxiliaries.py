"""Auxiliary electrical loads (not HVAC): compressors, steering, lights, electronics."""

from __future__ import annotations

import numpy as np

from ebus_env.effects.base import Param, effect
from ebus_env.effects.tables import Table, TableData, lookup1


@effect("auxiliaries", sink="dc_load_w", label="constant auxiliary load", params=[
    Param("base_power_w", 4000.0, "W", (0.0, 30000.0), "Constant auxiliary load P_aux,0",
          "12 m: 3-5 kW, 18 m: 5-7 kW; TransitBus 5 kW (docs/physics.md §7.1)"),
])
def auxiliaries(base_power_w: float) -> float:
    """Constant auxiliary load: P_aux = P_aux,0 [W]."""
    return base_power_w


SCHEDULE = Table(
    "schedule_w", "W", "Auxiliary load by time of day [h] (x), added to the constant load",
    presets={
        "evening_lights": TableData((0.0, 6.0, 7.0, 16.0, 17.0, 22.0, 23.0, 24.0),
                                    (500.0, 500.0, 0.0, 0.0, 500.0, 500.0, 500.0, 500.0),
                                    source="example: interior and exterior lights in the dark"),
    },
    default="evening_lights",
)


@effect("aux_schedule", sink="dc_load_w", label="auxiliary load over the time of day",
        drivers=("time_of_day_h",), tables=[SCHEDULE], params=[
    Param("scale", 1.0, "1", (0.0, 5.0), "Factor on the scheduled load"),
])
def aux_schedule(time_of_day_h: float, scale: float, schedule_w: np.ndarray) -> float:
    """Auxiliary load that follows the time of day: P = scale * P_sched(t) [W] (a table in the
    bus config, ``tables: {aux_schedule: {schedule_w: {x: [hours], y: [watts]}}}``)."""
    return scale * lookup1(schedule_w, time_of_day_h)


@effect("replayed_load", sink="dc_load_w", label="the log's measured load",
        drivers=("logged_load_w",),
        params=[
    Param("scale", 1.0, "1", (0.0, 3.0), "Factor on the logged load",
          "1: the load as the log measures it"),
])
def replayed_load(logged_load_w: float, scale: float) -> float:
    """A load the log measures and the model does not compute, replayed onto the DC bus:
    P = scale * P_logged [W] (the log's ``logged_load_kw``: an HVAC or compressor submeter).
    In a diagnosis it is the candidate "the logged load explains the missing power", and
    ``scale`` says how much of it: 1 where the submeter and the pack agree."""
    return scale * logged_load_w
