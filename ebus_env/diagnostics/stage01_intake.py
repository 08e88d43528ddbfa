"""Stage 1, intake: the inputs of a diagnosis checked before any model is built.

The bus must be a config, the profiles Profiles, the window inside its range; the effects to
add are resolved, each must replay only what the log has, and the values a user holds must
name parameters inside their bounds (:func:`~ebus_env.diagnostics.ladder.check_known`). The
logs are split into the calibration and held-out blocks every later stage shares.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ebus_env.config import BusConfig
from ebus_env.diagnostics.ladder import Freedom, as_effect, check_known, split_blocks
from ebus_env.diagnostics.power_stage import DOMAINS, domain_of
from ebus_env.errors import ConfigError
from ebus_env.inputs import check as check_input
from ebus_env.profile import as_profiles

if TYPE_CHECKING:
    from ebus_env.diagnostics.diagnosis_run import DiagnosisRun

LOGGED_ONLY = {"logged_load_w": "logged_load_kw"}
"""Input channels only a log gives (no default stands for them), and the log's column."""


def run(ctx: DiagnosisRun) -> None:
    """Check ``ctx``'s inputs (a clear error on the first that is wrong) and fill its
    ``profiles`` (as Profiles), ``add`` (as Effects), ``held`` and ``blocks``."""
    if not isinstance(ctx.bus, BusConfig):
        raise ConfigError(f"diagnose: give a bus config (load_bus('12m')), not a "
                          f"{type(ctx.bus).__name__}: the diagnosis builds its own models of it.")
    ctx.profiles = profiles = as_profiles(ctx.profiles, "diagnose")
    if ctx.domain not in DOMAINS:
        raise ConfigError(f"diagnose: domain={ctx.domain!r} is not one of {', '.join(DOMAINS)}.")
    ctx.domain = domain_of(ctx)
    if ctx.window_s is not None:
        check_input("window_s", ctx.window_s, "diagnose(window_s=...)")
    ctx.add = [as_effect(a) for a in ctx.add]
    for eff in ctx.add:  # an effect that replays a logged signal the log lacks would test nothing
        for channel, column in LOGGED_ONLY.items():
            if channel in eff.drivers and not all(channel in p.channels for p in profiles):
                raise ConfigError(f"--add {eff.name} replays the log's '{column}' column, "
                                  "which the log does not have. Fix: add the column (a load "
                                  "measured on the bus), or add another effect.")
    check_known(ctx.bus, ctx.add, ctx.freedom, ctx.dt_s)
    # the values the user holds, before a reference day's join them (stage 3)
    ctx.held = dict((ctx.freedom or Freedom()).fixed)
    ctx.blocks = split_blocks(profiles)
