"""Where the shipped files are: bus, env, calibration, agent and log-preset configs, cycles,
routes, demo logs and trained agents.

The project keeps them in the top-level folders ``configs/``, ``data/`` and ``trained/``; a
built wheel installs them inside the package (``ebus_env/configs`` ..., see ``pyproject.toml``).
Every lookup goes through this module, which imports nothing of the project, so finding a file
never loads the model or numba. Files are read from the file system (no zip imports).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

_PACKAGE = Path(str(resources.files("ebus_env")))
_SHIPPED = ("configs", "data", "trained")


def _shipped(folder: str) -> Path:
    """A shipped top-level folder: inside the installed package, else in the source checkout."""
    installed = _PACKAGE / folder
    return installed if installed.is_dir() else _PACKAGE.parent / folder


def configs(kind: str) -> Path:
    """Folder of the shipped configs of one kind: ``bus``, ``env``, ``calibration``,
    ``agents`` or ``logs``."""
    return _shipped("configs") / kind


def config_names(kind: str) -> list[str]:
    """Names of the shipped configs of one kind (file stems), sorted."""
    return sorted(p.stem for p in configs(kind).glob("*.yaml"))


def data(*parts: str) -> Path:
    """A shipped data file or folder, e.g. ``data("cycles")``, ``data("measured", "hidden")``."""
    return _shipped("data").joinpath(*parts)


def trained(name: str) -> Path:
    """Folder of a shipped trained agent, e.g. ``trained("ppo_sort2_day")``."""
    return _shipped("trained") / name


def here_or_shipped(path: str | Path) -> Path:
    """``path`` itself where it exists; else, for a relative path into a shipped folder
    (``configs/bus/12m.yaml``, ``data/measured/...``), the shipped file, so that the commands
    the documentation gives work from any folder once the wheel is installed."""
    path = Path(path)
    if path.exists() or path.is_absolute() or not path.parts or path.parts[0] not in _SHIPPED:
        return path
    shipped = _shipped(path.parts[0]).joinpath(*path.parts[1:])
    return shipped if shipped.exists() else path


def checkout() -> Path | None:
    """Root of the source checkout when running from one (``examples/`` and ``tests/`` exist
    only there), else None."""
    root = _PACKAGE.parent
    return root if (root / "pyproject.toml").is_file() and (root / "examples").is_dir() else None
