"""A depot's folder of CAN logger files, as it comes, to the buses that need a workshop visit.

- :mod:`~ebus_env.depot.loggers`: the logger-to-bus map (which logger was in which bus, when).
- :mod:`~ebus_env.depot.service_days`: a bus's samples cut at its depot stays.
- :mod:`~ebus_env.depot.bus_days`: the folder's files decoded, given to buses, merged and
  written as one canonical log per bus and service day.
- :mod:`~ebus_env.depot.depot_run`: each bus diagnosed over its days, and what to do with it.
- :mod:`~ebus_env.depot.fleet_summary`: ``summary.csv``, ``files.csv``, ``days.csv``,
  ``index.html``.
- :mod:`~ebus_env.depot.depot_command`: ``ebus depot``.
- :mod:`~ebus_env.depot.sample_days`: made-up logger files from the project's own days.
"""
