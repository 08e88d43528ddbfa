"""Built-in effects. Importing this package registers them."""

from ebus_env.effects import (  # noqa: F401
    auxiliaries,
    battery,
    cabin,
    charging,
    driver,
    drivetrain,
    regen,
    road_load,
    vehicle,
)
from ebus_env.effects.base import Call, Effect, Param, State, effect, get_effect, registered_effects
from ebus_env.effects.tables import Table, TableData, lookup1, lookup2

__all__ = ["Call", "Effect", "Param", "State", "Table", "TableData", "effect", "get_effect",
           "lookup1", "lookup2", "registered_effects"]
