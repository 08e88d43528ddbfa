"""The bus a run is given: a config by name or path, effects added and removed, overlays merged
(the commands' ``--bus``, ``--with``, ``--without``, ``--overlay``), and the files a run reads
(so that no output overwrites one)."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from ebus_env.config import BusConfig, load_bus


def split_names(items: Iterable[str] | None) -> list[str]:
    """Names given one by one or as comma lists (``["a,b", "c"]`` -> ``["a", "b", "c"]``)."""
    return [part.strip() for item in items or [] for part in item.split(",") if part.strip()]


def input_files(*groups, effects: Iterable[str] = ()) -> list[Path]:
    """The files a run reads: the paths of each group (None left out) and the file of each
    ``file.py:Name`` effect of ``effects``."""
    files = [Path(item.split(":", 1)[0]) for item in split_names(list(effects or []))
             if ".py" in item.split(":", 1)[0]]
    return [Path(p) for group in groups for p in group or [] if p is not None] + files


@dataclass(frozen=True)
class BusChoice:
    """A bus config with effects added and removed and overlays merged.

    Parameters
    ----------
    name
        Config name in ``configs/bus`` (``12m``, ``18m``, ``bmw_i3``) or a YAML path.
    with_
        Effects to add: registry names or ``my_effects.py:Name`` (comma lists allowed).
    without
        Effects to remove (comma lists allowed).
    overlays
        Bus-config overlays merged in order (e.g. a calibration result).
    """

    name: str = "12m"
    with_: list[str] | None = None
    without: list[str] | None = None
    overlays: list[Path] | None = None

    @classmethod
    def of(cls, bus: str | Path | BusChoice) -> BusChoice:
        """``bus`` as a choice: a name or path is that config unchanged."""
        return bus if isinstance(bus, BusChoice) else cls(str(bus))

    def load(self) -> BusConfig:
        """The :class:`~ebus_env.config.BusConfig`, effects added and removed, overlays
        merged."""
        return load_bus(self.name, with_=split_names(self.with_),
                        without=split_names(self.without), overlays=self.overlays or [])

    def files(self, bus: BusConfig) -> list[Path]:
        """The files this choice reads: the bus config, the overlays, the effect files."""
        return input_files([bus.path], self.overlays, effects=self.with_ or ())

    def options(self) -> str:
        """This choice as command-line options (``--bus 12m --without cabin_hvac ...``)."""
        return " ".join([f"--bus {self.name}", *(f"--with {w}" for w in self.with_ or []),
                         *(f"--without {w}" for w in self.without or []),
                         *(f"--overlay {o}" for o in self.overlays or [])])
