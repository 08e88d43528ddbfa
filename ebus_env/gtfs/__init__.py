"""GTFS timetables as blocks: read a feed's service day (:mod:`ebus_env.gtfs.feed`), chain its
trips into vehicle blocks (:mod:`ebus_env.gtfs.scheduling`), and build the example feed of
King County routes 45, 7 and 44 on a made-up timetable (:mod:`ebus_env.gtfs.example_feed`)."""

from ebus_env.gtfs.feed import NetworkDay, read_network_day

__all__ = ["NetworkDay", "read_network_day"]
