"""Auxiliary electrical loads (not HVAC): compressors, steering, lights, electronics."""

from __future__ import annotations

from ebus_env.effects.base import Param, effect
from ebus_env.effects.tables import Table, TableData, lookup1

SCHEDULE = Table(
    "schedule_w", "W", "Extra auxiliary load by time of day [h] (added to the base load)",
    presets={
        "flat": TableData((0.0, 24.0), (0.0, 0.0), source="no schedule"),
    },
    default="flat",
)


@effect("auxiliaries", sink="dc_load_w", drivers=("time_of_day_h",), tables=[SCHEDULE], params=[
    Param("base_power_w", 4000.0, "W", (0.0, 30000.0), "Constant auxiliary load P_aux,0",
          "12 m: 3-5 kW, 18 m: 5-7 kW; TransitBus 5 kW (physics.md 3.2)"),
])
def auxiliaries(time_of_day_h, base_power_w, schedule_w):
    """Auxiliary load: P_aux = P_aux,0 + P_sched(time of day) [W]."""
    return base_power_w + lookup1(schedule_w, time_of_day_h)
