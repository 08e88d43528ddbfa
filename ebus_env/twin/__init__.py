"""The fleet's live digital twin: telematics in, a self-tuning model per bus, predictions and
alarms out, on a dashboard (``ebus twin serve``; docs/twin.md).

The Python API::

    from ebus_env.twin import Twin, open_store
    twin = Twin(open_store("twin.sqlite"))
    twin.ingest("bus-01", frame)              # a DataFrame of 1 Hz samples
    twin.predict("bus-01", block)             # SoC at each charger and at the block's end

The names load on first use (PEP 562), so that ``ebus --help``, which imports the twin's
command module (:mod:`ebus_env.twin.twin_command`), loads neither pandas nor SQLAlchemy.
"""

from __future__ import annotations

import importlib

_WHERE = {"Twin": "ebus_env.twin.fleet_twin", "Store": "ebus_env.twin.store",
          "open_store": "ebus_env.twin.store"}
__all__ = ["Store", "Twin", "open_store"]


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(importlib.import_module(_WHERE[name]), name)
    raise AttributeError(f"module 'ebus_env.twin' has no attribute '{name}'")


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
