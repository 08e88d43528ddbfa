"""A bus's logs as its days: the diagnosis fits a bus across its days, and dates what
changes from one of them on."""

from __future__ import annotations


def service_days(profiles) -> tuple[list[int], list[str]]:
    """Each profile's day (0 first) and each day's name: the local date where every log has
    date-times, else the log's name in the order given."""
    if all(p.date is not None for p in profiles):
        keys = [p.date.isoformat() for p in profiles]
        names = sorted(set(keys))
    else:
        keys = [p.name for p in profiles]
        names = list(dict.fromkeys(keys))
    return [names.index(k) for k in keys], names
