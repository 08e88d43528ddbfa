"""The fleet's live digital twin: telematics in, a self-tuning model per bus, predictions and
alarms out, on a dashboard (``ebus twin serve``; docs/twin.md).

The Python API::

    from ebus_env.twin import Twin, open_store
    twin = Twin(open_store("twin.sqlite"))
    twin.ingest("bus-01", frame)              # a DataFrame of 1 Hz samples
    twin.predict("bus-01", block)             # SoC at each charger and at the block's end
"""

from ebus_env.twin.fleet_twin import Twin
from ebus_env.twin.store import Store, open_store

__all__ = ["Store", "Twin", "open_store"]
