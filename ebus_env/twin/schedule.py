"""A bus's block for one day, as the twin reads it: the trips (start and end times, route and
direction) and the charger sessions planned at terminals (start, end, rated power)::

    {"bus": "bus-01", "date": "2025-05-05",
     "trips": [{"trip": "rt7-1", "route": "rt7", "direction": 0,
                "start": "2025-05-05T06:02:10", "end": "2025-05-05T06:48:31"}, ...],
     "chargers": [{"start": "...", "end": "...", "power_kw": 300.0, "site": "terminal-0"}],
     "end": "2025-05-05T15:40:00"}

Times are ISO 8601, UTC where they carry no offset (as the samples' ``t``).
"""

from __future__ import annotations

from dataclasses import dataclass

import pandas as pd


def _t(text, where: str) -> float:
    try:
        stamp = pd.Timestamp(text)
    except (ValueError, TypeError):
        raise ValueError(f"{where}: '{text}' is not an ISO 8601 date-time") from None
    if stamp.tzinfo is None:
        stamp = stamp.tz_localize("UTC")
    return stamp.timestamp()


@dataclass(frozen=True)
class Leg:
    """A trip or a charger session, in UTC epoch seconds."""

    start_s: float
    end_s: float
    direction: int = 0
    power_kw: float = 0.0
    name: str = ""


@dataclass(frozen=True)
class Block:
    trips: tuple[Leg, ...]
    chargers: tuple[Leg, ...]
    end_s: float
    date: str

    @property
    def start_s(self) -> float:
        return min([t.start_s for t in self.trips] + [self.end_s])


def check_block(data: dict, day: str | None = None) -> dict:
    """``data`` as a block, checked (a ValueError names the trip or charger and the field)."""
    if not isinstance(data, dict) or not isinstance(data.get("trips"), list):
        raise ValueError("a block is an object with a list of 'trips'")
    if not data["trips"]:
        raise ValueError("a block has at least one trip")
    if day is not None and str(data.get("date", day)) != day:
        raise ValueError(f"the block's date {data.get('date')} is not the day {day}")
    previous = -float("inf")
    for i, trip in enumerate(data["trips"], start=1):
        a, b = _t(trip.get("start"), f"trip {i} start"), _t(trip.get("end"), f"trip {i} end")
        if not b > a:
            raise ValueError(f"trip {i}: its end is not after its start")
        if a < previous:
            raise ValueError(f"trip {i}: it starts before trip {i - 1} ends")
        previous = b
        if trip.get("direction", 0) not in (0, 1):
            raise ValueError(f"trip {i}: direction is 0 or 1")
    for i, ch in enumerate(data.get("chargers", []), start=1):
        a, b = _t(ch.get("start"), f"charger {i} start"), _t(ch.get("end"), f"charger {i} end")
        if not b > a:
            raise ValueError(f"charger {i}: its end is not after its start")
        power = ch.get("power_kw")
        if not isinstance(power, (int, float)) or not 0 < power <= 1000:
            raise ValueError(f"charger {i}: power_kw must be in (0, 1000] kW")
    if "end" in data:
        _t(data["end"], "end")
    return data


def read_block(data: dict) -> Block:
    data = check_block(data)
    trips = tuple(Leg(_t(t["start"], ""), _t(t["end"], ""), int(t.get("direction", 0)),
                      name=str(t.get("trip", ""))) for t in data["trips"])
    chargers = tuple(Leg(_t(c["start"], ""), _t(c["end"], ""), power_kw=float(c["power_kw"]),
                         name=str(c.get("site", ""))) for c in data.get("chargers", []))
    end = _t(data["end"], "") if "end" in data else trips[-1].end_s
    return Block(trips, chargers, max(end, trips[-1].end_s), str(data.get("date", "")))
