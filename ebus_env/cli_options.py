"""The command line's shared parts: the option groups every command declares the same way, the
parsers of their values, and :func:`run_command`, the way each command runs.

A command module (``ebus_env/cli.py``, or a package's own ``register(app)`` module) declares a
group by these aliases, one parameter each, and hands the values to its library function
(``--bus``/``--with``/``--without``/``--overlay`` as a
:class:`~ebus_env.bus_choice.BusChoice`, the log options as a
:class:`~ebus_env.io.log_reading.LogReading`). Only typer and the standard library are imported
here, so that ``ebus --help`` starts quickly: the work is imported when a command runs.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ebus_env.errors import ConfigError, EbusError

# the bus: a config, effects added and removed, overlays merged, parameters set
BusOpt = Annotated[str, typer.Option("--bus", "-b", help="Bus config: name (12m, 18m, bmw_i3) "
                                                         "or path to a YAML file")]
WithOpt = Annotated[list[str] | None, typer.Option(
    "--with", help="Add an effect: registry name or my_effects.py:Name (repeatable)")]
WithoutOpt = Annotated[list[str] | None, typer.Option(
    "--without", help="Remove an effect, e.g. cabin_hvac (repeatable; comma lists allowed)")]
OverlayOpt = Annotated[list[Path] | None, typer.Option(
    "--overlay", help="Bus-config overlay to merge, e.g. a calibration result")]
SetOpt = Annotated[list[str] | None, typer.Option(
    "--set", help="Override a parameter: effect.param=value (repeatable)")]

# how measured logs are read
ColumnsOpt = Annotated[str | None, typer.Option(
    "--columns", help="Column map preset of the logs (configs/logs), e.g. bmw_i3_tum")]
GapsOpt = Annotated[str, typer.Option(
    "--gaps", help="Gaps in a log: error, split, hold, interpolate")]
FillOpt = Annotated[str, typer.Option("--fill", help="Missing values: error or interpolate")]
NoUnitCheckOpt = Annotated[bool, typer.Option(
    "--no-unit-check", help="Skip the m/s-vs-km/h and SoC-unit checks")]
StartOpt = Annotated[str | None, typer.Option(
    "--start-time", help="Clock time of the log's first row, HH:MM, for a log without "
                         "date-times (else 00:00)")]

# outputs and runs
JsonOpt = Annotated[Path | None, typer.Option("--json", help="Write the results as JSON")]
SeedOpt = Annotated[int, typer.Option("--seed", help="Random seed of iSOPT")]


def console():
    """The console the commands print to."""
    from rich.console import Console

    return Console()


def parse_settings(items: list[str] | None, option: str = "--set") -> dict[str, float]:
    """``effect.param=value`` items (of ``--set``, ``--fix``) as ``{qualified name: value}``;
    a malformed item, a value that is no number and a name given twice are refused."""
    out: dict[str, float] = {}
    for item in items or []:
        if "=" not in item or "." not in item.split("=", 1)[0]:
            raise ConfigError(f"{option} needs effect.param=value, got '{item}'.")
        key, value = item.split("=", 1)
        key = key.strip()
        if key in out:
            raise ConfigError(f"{option} {key} is given twice ({out[key]:g} and {value}): keep "
                              "one.")
        try:
            out[key] = float(value)
        except ValueError:
            raise ConfigError(f"{option} {key}: '{value}' is not a number.") from None
    return out


def parse_ranges(items: list[str] | None) -> dict[str, tuple[float, float]]:
    """``effect.param=low:high`` items of ``--range`` as ``{qualified name: (low, high)}``."""
    out = {}
    for item in items or []:
        try:
            name, value = item.split("=", 1)
            low, high = (float(x) for x in value.split(":"))
        except ValueError:
            raise ConfigError(f"--range needs effect.param=low:high, got '{item}'.") from None
        if not low < high:  # NaN fails too
            raise ConfigError(f"--range {item}: low must be below high.")
        out[name.strip()] = (low, high)
    return out


def refuse_unused(given: dict[str, object], takes: str, fix: str) -> None:
    """Refuse each option of ``given`` (option: value) that is set: ``takes`` says what the
    command takes instead, ``fix`` the other way to go. Refused, never silently ignored."""
    used = [name for name, value in given.items() if value]
    if used:
        raise ConfigError(f"{takes}; it does not take {', '.join(used)}. Fix: leave "
                          f"{'it' if len(used) == 1 else 'them'} out, or {fix}.")


def run_command(body):
    """Run a command body: a user error (:class:`~ebus_env.errors.EbusError`) is printed as one
    line without a traceback and exits with code 2; an input warning
    (:class:`~ebus_env.errors.InputWarning`) is printed once, as it comes."""
    import warnings

    from rich.markup import escape

    from ebus_env.errors import InputWarning

    out = console()
    original = warnings.showwarning
    shown: set = set()

    def show(message, category, *args, **kwargs):
        if issubclass(category, InputWarning):
            key = getattr(message, "key", str(message))
            if key not in shown:  # a value checked where it is read and where it is used
                shown.add(key)
                out.print(f"[yellow]warning:[/] {escape(str(message))}", highlight=False,
                          soft_wrap=True)
        else:
            original(message, category, *args, **kwargs)

    with warnings.catch_warnings():
        warnings.simplefilter("always", InputWarning)
        warnings.showwarning = show
        try:
            return body()
        except EbusError as exc:
            out.print(f"[bold red]error:[/] {escape(str(exc))}", highlight=False,
                      soft_wrap=True)
            raise typer.Exit(2) from None
