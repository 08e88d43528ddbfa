"""A bus's samples cut into service days: the runs between its depot stays.

A depot stay is a stretch of at least ``stay_h`` hours in which the bus does not move (its
speed stays at or below ``moving_kmh``, or the logger sends nothing: a bus parked with its
ignition off). A service day runs from ``margin_min`` minutes before its first moving sample
to ``margin_min`` minutes after its last, so that the standing before the first departure
and after the last arrival (pre-heating, doors, the loads at the depot) stays in the day,
while the hours of a stay (the overnight charge) do not. Terminal layovers and breaks shorter
than ``stay_h`` stay inside the day; a day may run past midnight. The defaults (2 h, 15 min)
suit city service with overnight depot stays; a split shift with a midday return to the depot
of more than ``stay_h`` gives two service days on one date.

Days with less than ``min_day_h`` hours between their ends are listed but not diagnosed:
the diagnosis needs an hour or more (a bus shunted around the depot makes such a day).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ebus_env.errors import ConfigError


@dataclass(frozen=True)
class DayRule:
    """How a bus's samples are cut into service days (see the module docstring)."""

    stay_h: float = 2.0
    margin_min: float = 15.0
    min_day_h: float = 1.0
    moving_kmh: float = 1.0

    def __post_init__(self):
        if not 0.25 <= self.stay_h <= 24:
            raise ConfigError(f"--stay-h {self.stay_h:g}: a depot stay lasts 0.25-24 h.")
        if not 0 <= self.margin_min * 2 < self.stay_h * 60:
            raise ConfigError(f"--margin-min {self.margin_min:g}: at least 0 and less than "
                              f"half a depot stay ({self.stay_h * 30:g} min), so that two "
                              "days' margins do not overlap.")
        if not 0 <= self.min_day_h <= 24:
            raise ConfigError(f"--min-day-h {self.min_day_h:g}: 0-24 h.")
        if not 0 <= self.moving_kmh <= 10:
            raise ConfigError(f"moving_kmh {self.moving_kmh:g}: 0-10 km/h.")


DEFAULT_RULE = DayRule()


def service_days(t_s: np.ndarray, speed_kmh: np.ndarray, rule: DayRule = DEFAULT_RULE
                 ) -> list[tuple[float, float]]:
    """The service days ``[(start, end), ...]`` [s, the times' own origin] of a bus whose
    speed samples are ``(t_s, speed_kmh)`` (time-ordered)."""
    moving = t_s[speed_kmh > rule.moving_kmh]
    if not moving.size:
        return []
    cuts = np.flatnonzero(np.diff(moving) >= rule.stay_h * 3600.0)
    firsts = np.concatenate([[moving[0]], moving[cuts + 1]])
    lasts = np.concatenate([moving[cuts], [moving[-1]]])
    margin = rule.margin_min * 60.0
    # the end is exclusive: the last moving sample stays in the day even without a margin
    return [(float(a - margin), float(np.nextafter(b + margin, np.inf)))
            for a, b in zip(firsts, lasts, strict=True)]
