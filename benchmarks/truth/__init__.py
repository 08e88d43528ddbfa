"""An out-of-family truth bench: a bus simulator written independently of ``ebus_env``.

It never imports ``ebus_env``: it reads the shipped route files directly and has its own
road-load, driver, drivetrain, HVAC and battery formulations, so the diagnosis can be tested on
data that its own model family did not generate.

* ``days``: the driving plan of a service day on King County routes.
* ``vehicles``: a nominal 12 m bus and the per-day random draw of its base parameters.
* ``sim``: plan + base + hidden effect -> clean truth trace.
* ``degrade``: clean trace -> a 1 Hz log in the project's canonical columns, degraded like a
  real one.
* ``cases``: the case list, the truth records, and the writer
  (``python -m benchmarks.truth.cases --out DIR``).
"""
