"""A bus's block for one day, as the twin reads it: the block format of the timetable studies
(:mod:`ebus_env.blocks`, its hand-written JSON form), put on the calendar.

The body of ``PUT /v1/buses/BUS/schedules/DAY`` is one block in that form, alone or as the one
item of ``blocks``, with an optional IANA ``timezone`` (default UTC) for its clock::

    {"timezone": "UTC",
     "blocks": [{"block_id": "bus-01 2025-05-05",
                 "chargers": {"kc7_A": {"count": 1, "power_kw": 300}},
                 "trips": [{"trip_id": "rt7-1", "cycle": "kc7_out",
                            "start": "06:40:16", "end": "07:41:00"}, ...]}]}

Its times are the day's clock (``HH:MM:SS``, past 24:00 for trips after midnight); the twin
maps them to UTC epoch seconds, the samples' time. A trip of the bus is known again on later
days by its route and its two terminal stops (:func:`trip_key`): the twin drives a trip still
ahead with the speed trace of one the bus drove (:mod:`ebus_env.twin.forecast`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cached_property, lru_cache

import pandas as pd

from ebus_env.blocks import Block, Trip, blocks_from_dict
from ebus_env.errors import ConfigError


def trip_key(trip: Trip) -> tuple[str, str, str]:
    """What makes two trips of a bus the same run: route, first and last stop."""
    return (trip.route, trip.start_stop, trip.end_stop)


@dataclass(frozen=True, eq=False)
class DayBlock:
    """A :class:`~ebus_env.blocks.Block` on its day: ``midnight_s`` is the UTC epoch second
    of the day's 00:00 in the block's time zone."""

    block: Block
    day: str
    midnight_s: float

    @property
    def start_s(self) -> float:
        return self.midnight_s + self.block.start_s

    @property
    def end_s(self) -> float:
        return self.midnight_s + self.block.end_s

    @cached_property
    def trips(self) -> list[tuple[Trip, float, float]]:
        """(trip, start, end) [UTC epoch s] in time order."""
        return [(t, self.midnight_s + t.start_s, self.midnight_s + t.end_s)
                for t in self.block.trips]

    @cached_property
    def charger_stops(self) -> list[tuple[str, float, float, float]]:
        """(stop, start, end [UTC epoch s], power [kW]) of each layover at a charger."""
        return [(lay.stop_id, self.midnight_s + lay.start_s, self.midnight_s + lay.end_s,
                 lay.charger.power_kw) for lay in self.block.layovers()
                if lay.charger is not None and lay.end_s > lay.start_s]


def _midnight(day: str, timezone: str) -> float:
    try:
        stamp = pd.Timestamp(day)
    except (ValueError, TypeError):
        raise ConfigError(f"day '{day}': give the date as YYYY-MM-DD") from None
    try:
        return stamp.tz_localize(timezone).timestamp()
    except Exception:  # pytz/zoneinfo raise their own kinds
        raise ConfigError(f"timezone '{timezone}': give an IANA time zone name, e.g. "
                          "'Europe/Stockholm' or 'UTC'") from None


def read_block(data: dict, day: str) -> DayBlock:
    """The block of ``data`` (see the module docstring) on ``day`` (YYYY-MM-DD); a
    :class:`~ebus_env.errors.ConfigError` names what is wrong (its trip and field)."""
    if not isinstance(data, dict):
        raise ConfigError("a schedule is an object: one block, or {'blocks': [one block]}")
    timezone = str(data.get("timezone", "UTC"))
    body = data if "blocks" in data else {"blocks": [
        {k: v for k, v in data.items() if k != "timezone"}]}
    if not isinstance(body.get("blocks"), list) or len(body["blocks"]) != 1:
        raise ConfigError("a bus's schedule for a day is one block: give 'blocks' with one item")
    block = blocks_from_dict(body, f"the schedule of {day}")[0]
    if block.problems():
        raise ConfigError(f"block {block.block_id}: {'; '.join(block.problems())}")
    return DayBlock(block, day, _midnight(day, timezone))


@lru_cache(maxsize=4096)
def read_stored(text: str, day: str) -> DayBlock:
    """:func:`read_block` of a block stored as JSON text, read once per process (reading a
    block builds its trips' cycles: tens of ms a trip)."""
    return read_block(json.loads(text), day)
