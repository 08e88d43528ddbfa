"""ebus-env: a calibrated Lo-Fi electric-bus model, fast enough for fleets and RL.

Quick start::

    from ebus_env import load_bus, service_day

    bus = load_bus("12m")
    model = bus.build()
    result = model.simulate(service_day("sort2", 13.5, service=bus.service), soc_start=0.95)
    result.summary()["kwh_per_km"]

Names are imported lazily so that the command line starts quickly.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

_EXPORTS = {
    "load_bus": "ebus_env.config",
    "BusConfig": "ebus_env.config",
    "Service": "ebus_env.config",
    "load_effects_file": "ebus_env.config",
    "Param": "ebus_env.effects.base",
    "State": "ebus_env.effects.base",
    "Effect": "ebus_env.effects.base",
    "Call": "ebus_env.effects.base",
    "effect": "ebus_env.effects.base",
    "helper": "ebus_env.effects.base",
    "get_effect": "ebus_env.effects.base",
    "registered_effects": "ebus_env.effects.base",
    "Table": "ebus_env.effects.tables",
    "TableData": "ebus_env.effects.tables",
    "lookup1": "ebus_env.effects.tables",
    "lookup2": "ebus_env.effects.tables",
    "Input": "ebus_env.signals",
    "Model": "ebus_env.model.model",
    "build_model": "ebus_env.model.model",
    "Profile": "ebus_env.profile",
    "Cycle": "ebus_env.cycles",
    "load_cycle": "ebus_env.cycles",
    "service_day": "ebus_env.cycles",
    "load_log": "ebus_env.io.measured",
    "plot_trace": "ebus_env.plotting",
    # the commands as functions: each does its command's whole work
    "BusChoice": "ebus_env.bus_choice",
    "LogReading": "ebus_env.io.log_reading",
    "simulate_bus": "ebus_env.simulate",
    "calibrate_logs": "ebus_env.calibration.calibrate_logs",
    "diagnose_logs": "ebus_env.diagnostics.diagnose_logs",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'ebus_env' has no attribute '{name}'")


def _register_envs() -> None:
    """``gymnasium.make("EBus-v0")`` after ``import ebus_env`` (when Gymnasium is installed:
    the ``rl`` extra)."""
    try:
        from ebus_env.envs import register_envs
    except ImportError:  # pragma: no cover - gymnasium not installed
        return
    register_envs()


_register_envs()
