"""User-facing errors: each says what is wrong, where, and how to fix it.

The CLI prints these without a traceback; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable


class EbusError(Exception):
    """Base class of errors caused by the user's input (config, data, command line)."""


class ConfigError(EbusError, ValueError):
    """A config file, parameter or option is wrong."""


class CompositionError(EbusError, ValueError):
    """The chosen effects do not form a valid model."""


class EnvError(EbusError, RuntimeError):
    """An environment is used out of order (e.g. ``step()`` after the episode ended)."""


class ActionError(EbusError, ValueError):
    """An env action of the wrong shape, or not a finite number in [-1, 1]."""


class InputWarning(UserWarning):
    """An input inside its accepted range but outside the usual one (see ebus_env.inputs):
    the run goes on, and the command line prints the warning (once per input and value:
    ``key``)."""

    def __init__(self, line: str, key: tuple | None = None):
        super().__init__(line)
        self.key = key or (line,)


class LogError(EbusError, ValueError):
    """A measured log cannot be used as it is.

    Parameters
    ----------
    problem
        What is wrong.
    path
        The file.
    column, rows
        Where (rows are 0-based data-row numbers, i.e. not counting the header).
    fix
        What the user can do about it.
    """

    def __init__(self, problem: str, *, path=None, column=None, rows=None, fix: str = ""):
        self.problem, self.path, self.column, self.rows, self.fix = problem, path, column, rows, fix
        where = []
        if path is not None:
            where.append(f"file {path}")
        if column is not None:
            where.append(f"column '{column}'")
        if rows is not None:
            where.append(f"{'row' if len(rows) == 1 else 'rows'} {format_rows(rows)}")
        text = problem + (f" ({', '.join(where)})" if where else "")
        if fix:
            text += f". Fix: {fix}"
        super().__init__(text)


def format_rows(rows: Iterable[int], limit: int = 6) -> str:
    """Compact list of row numbers, as runs: ``3, 10-14, 20 (and 12 more)``."""
    rows = sorted(set(int(r) for r in rows))
    runs: list[tuple[int, int]] = []
    for r in rows:
        if runs and r == runs[-1][1] + 1:
            runs[-1] = (runs[-1][0], r)
        else:
            runs.append((r, r))
    text = ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in runs[:limit])
    if len(runs) > limit:
        text += f" (and {len(runs) - limit} more runs)"
    return text


def did_you_mean(name: str, choices: Iterable[str]) -> str:
    """`` Did you mean 'x'?`` for the closest choice, or an empty string."""
    match = difflib.get_close_matches(name, list(choices), n=1, cutoff=0.6)
    return f" Did you mean '{match[0]}'?" if match else ""


def unknown_name(kind: str, name: str, choices: Iterable[str], listed_by: str = "") -> ConfigError:
    """Error for an unknown name, with the closest match and the valid choices (or, when too
    many to list, their number and the command ``listed_by`` that lists them)."""
    choices = sorted(choices)
    hint = did_you_mean(name, choices)
    listing = ", ".join(choices) if len(choices) <= 30 else \
        f"{len(choices)} names" + (f", listed by {listed_by}" if listed_by else "")
    return ConfigError(f"Unknown {kind} '{name}'.{hint} Valid: {listing}.")
