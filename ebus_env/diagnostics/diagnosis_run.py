"""The run context of one diagnosis: what :func:`~ebus_env.diagnostics.pipeline.diagnose`
was given, and what each of its stages builds, passed through them in turn.

Each stage (``stage01_intake`` ... ``stage11_ladder``) reads the fields the stages before it
filled and fills its own; the fields below are in the order the stages fill them.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ebus_env.config import BusConfig
    from ebus_env.diagnostics.ladder import Freedom, Rung
    from ebus_env.diagnostics.normal_day import Reference
    from ebus_env.diagnostics.power_path import PowerRun
    from ebus_env.diagnostics.stage04_residual import Residual
    from ebus_env.diagnostics.stage06_attribution import Attributed
    from ebus_env.diagnostics.stage11_ladder import Fits
    from ebus_env.diagnostics.voltage import ResistanceCheck


@dataclass
class DiagnosisRun:
    """One diagnosis of ``bus`` against measured ``profiles`` (the options are
    :func:`~ebus_env.diagnostics.pipeline.diagnose`'s), and what its stages build."""

    # -- what diagnose(...) was given; the intake checks it, and the reference day may
    # overlay the bus, hold its parameters (``freedom``) and so imply ``calibrate``
    bus: BusConfig
    profiles: Sequence
    calibrate: bool = False
    add: Sequence = ()  # effects for the error ladder (Effects after the intake)
    window_s: float | None = None
    settings: object = None  # calibration settings (None: the defaults)
    polish_starts: int | None = None
    loader_notes: Sequence[str] = ()
    progress: Callable[[str], None] | None = None
    freedom: Freedom | None = None
    reference: Sequence | Reference | None = None  # a normal day: its profiles, or measured
    domain: str = "soc"  # soc, power or auto (the intake settles it: power_stage.domain_of)
    # -- what the stages build
    timings: dict[str, float] = field(default_factory=dict)  # seconds, by part of the run
    started: float = field(default_factory=time.perf_counter)  # perf_counter at the start
    held: dict = field(default_factory=dict)  # intake: the values the user holds (freedom)
    blocks: tuple = ()  # intake: the calibration and held-out blocks
    normal: Reference | None = None  # reference day: what a normal day of the bus misses
    model: object = None  # calibration: the bus's model (with the reference day's overlay)
    first_rung: Rung | None = None  # calibration: rung 0, the bus calibrated as given
    known: dict = field(default_factory=dict)  # calibration: the values the model holds
    nuisance: tuple[str, ...] = ()  # calibration: the calibrated (free) parameters
    res: Residual | None = None  # residual: the missing power per window
    check: ResistanceCheck | None = None  # residual: the resistance the voltage shows
    candidates: list = field(default_factory=list)  # candidates: effects' and parameters'
    by_name: dict = field(default_factory=dict)  # candidates: each by its name
    aside: list[dict] = field(default_factory=list)  # candidates: effects set aside, and why
    power: PowerRun | None = None  # power stage (BMS logs): the power path's run
    days: list[str] = field(default_factory=list)  # power stage: each day's date or log
    found: Attributed | None = None  # attribution, then bound, voltage, tie, outside
    fits: Fits | None = None  # ladder: the errors before and after, the ladder, the runs

    @property
    def dt_s(self) -> float:
        """The logs' time step (the intake has made ``profiles`` Profiles)."""
        return self.profiles[0].dt_s

    def say(self, text: str) -> None:
        """Tell the caller's ``progress`` what the run is doing."""
        if self.progress:
            self.progress(text)

    def elapsed_s(self) -> float:
        """Seconds since the run started."""
        return time.perf_counter() - self.started

    @contextmanager
    def timed(self, key: str):
        """Record the seconds the ``with`` block takes as ``timings[key]``."""
        t1 = time.perf_counter()
        yield
        self.timings[key] = time.perf_counter() - t1
