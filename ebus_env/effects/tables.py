"""Lookup tables baked into the compiled core.

A table is a compile-time constant: a 1-D curve y(x) or a 2-D map z(x, y) on a uniform grid,
encoded as one flat float64 array so that an effect can read it with :func:`lookup1` or
:func:`lookup2` at the cost of an index computation (no search)::

    1-D: [x0, 1/dx, nx, y_0 .. y_{nx-1}]
    2-D: [x0, 1/dx, nx, y0, 1/dy, ny, z_00 .. z_{nx-1, ny-1}]   (z row-major in x)

(the inverse steps save a division per lookup in the hot loop).

Inputs outside the grid are clamped to the edge value. Tables given on a non-uniform grid are
resampled linearly onto the coarsest uniform grid that contains every breakpoint (e.g. the OCV
tables' 2.5 %-SoC steps), so that they are reproduced exactly; when that grid would need more
than ``MAX_POINTS`` points, onto ``MAX_POINTS`` points (breakpoints then move by up to
1/2000 of the table's span).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Any

import numba
import numpy as np
from numpy.typing import ArrayLike

_HEADER_1D = 3
_HEADER_2D = 6
MAX_POINTS = 2001
"""Largest uniform grid a 1-D table is resampled onto (breakpoints off it are approximated)."""


@numba.njit(error_model="numpy", inline="always")
def lookup1(table: np.ndarray, x: float) -> float:
    """Linear interpolation in an encoded 1-D table, clamped at the ends.

    Written without branches (clamp, then load) so that loops over many buses vectorise."""
    last = table[2] - 1.0
    u = min(max((x - table[0]) * table[1], 0.0), last)
    i = max(min(int(u), int(last) - 1), 0)  # provably >= 0: no negative-index wrap-around code
    f = u - i
    return table[_HEADER_1D + i] * (1.0 - f) + table[_HEADER_1D + i + 1] * f


@numba.njit(error_model="numpy", inline="always")
def lookup2(table: np.ndarray, x: float, y: float) -> float:
    """Bilinear interpolation in an encoded 2-D table, clamped at the edges (branch-free)."""
    ny = int(table[5])
    u = min(max((x - table[0]) * table[1], 0.0), table[2] - 1.0)
    w = min(max((y - table[3]) * table[4], 0.0), table[5] - 1.0)
    i = max(min(int(u), int(table[2]) - 2), 0)
    j = max(min(int(w), ny - 2), 0)
    fu = u - i
    fw = w - j
    base = _HEADER_2D + i * ny + j
    z00 = table[base]
    z01 = table[base + 1]
    z10 = table[base + ny]
    z11 = table[base + ny + 1]
    return (z00 * (1.0 - fw) + z01 * fw) * (1.0 - fu) + (z10 * (1.0 - fw) + z11 * fw) * fu


def _uniform_step(x: np.ndarray) -> float:
    """Largest step that puts every breakpoint of ``x`` on a uniform grid (within 1e-9)."""
    steps = np.diff(x)
    if np.allclose(steps, steps[0], rtol=1e-9, atol=0.0):
        return float(steps[0])
    # Rational GCD of the steps, limited so a pathological grid cannot explode in size.
    fracs = [Fraction(float(s)).limit_denominator(10_000) for s in steps]
    g = fracs[0]
    for f in fracs[1:]:
        g = Fraction(np.gcd(g.numerator * f.denominator, f.numerator * g.denominator),
                     g.denominator * f.denominator)
    step = float(g)
    if (x[-1] - x[0]) / step > MAX_POINTS - 1:  # no exact grid of reasonable size: approximate
        step = (x[-1] - x[0]) / (MAX_POINTS - 1)
    return step


def _check_axis(name: str, x: np.ndarray) -> None:
    if x.ndim != 1 or x.size < 2:
        raise ValueError(f"Table '{name}': the axis needs at least two points, got {x.size}.")
    if not np.all(np.isfinite(x)) or np.any(np.diff(x) <= 0):
        raise ValueError(f"Table '{name}': axis values must be finite and strictly increasing.")


def encode1(name: str, x: ArrayLike, y: ArrayLike) -> np.ndarray:
    """Encode a 1-D table y(x) onto a uniform grid (see module docstring)."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    _check_axis(name, x)
    if y.shape != x.shape or not np.all(np.isfinite(y)):
        raise ValueError(f"Table '{name}': needs {x.size} finite values, got shape {y.shape}.")
    step = _uniform_step(x)
    n = int(round((x[-1] - x[0]) / step)) + 1
    grid = x[0] + step * np.arange(n)
    return np.concatenate([[x[0], 1.0 / step, n], np.interp(grid, x, y)])


def encode2(name: str, x: ArrayLike, y: ArrayLike, z: ArrayLike) -> np.ndarray:
    """Encode a 2-D map z(x, y) given on a uniform grid (z has shape (len(x), len(y)))."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    z = np.asarray(z, dtype=float)
    _check_axis(name, x)
    _check_axis(name, y)
    for axis, label in ((x, "x"), (y, "y")):
        if not np.allclose(np.diff(axis), axis[1] - axis[0], rtol=1e-9, atol=0.0):
            raise ValueError(f"Table '{name}': 2-D maps need a uniform {label} axis.")
    if z.shape != (x.size, y.size) or not np.all(np.isfinite(z)):
        raise ValueError(
            f"Table '{name}': map values must be finite with shape ({x.size}, {y.size}), "
            f"got {z.shape}."
        )
    header = [x[0], 1.0 / (x[1] - x[0]), x.size, y[0], 1.0 / (y[1] - y[0]), y.size]
    return np.concatenate([header, z.ravel()])


@dataclass(frozen=True)
class TableData:
    """Points of a table: ``y(x)`` (1-D) or ``z(x, y)`` (2-D).

    ``param_defaults``: ``(name, value)`` pairs of the effect's parameters that belong with
    these points (a cell's voltage window with its OCV curve); a model built with this table
    takes them as those parameters' defaults, unless the bus config sets them."""

    x: tuple
    y: tuple
    z: tuple | None = None
    source: str = ""
    param_defaults: tuple = ()

    def encode(self, name: str) -> np.ndarray:
        if self.z is None:
            return encode1(name, self.x, self.y)
        return encode2(name, self.x, self.y, self.z)


TableValue = str | TableData | Mapping[str, Any] | None
"""A config's value for a table: a preset's name, points, a mapping with keys x, y (z) or None
(the default preset)."""


@dataclass(frozen=True)
class Table:
    """A compile-time lookup table of an effect.

    Parameters
    ----------
    name
        Argument name under which the effect function receives the encoded table.
    unit
        Unit of the tabulated values (and axes, in words).
    description
        What the table holds.
    presets
        Named tables shipped with the project; a bus config picks one by name or gives points.
    default
        Name of the preset used when the config says nothing.
    """

    name: str
    unit: str
    description: str
    presets: dict = field(default_factory=dict)
    default: str = ""

    def resolve(self, value: TableValue = None) -> TableData:
        """Return the table points for a config value: None, a preset name or points."""
        if value is None:
            value = self.default
        if isinstance(value, str):
            if value not in self.presets:
                from ebus_env.errors import unknown_name

                raise unknown_name(f"preset of table '{self.name}'", value, self.presets)
            return self.presets[value]
        if isinstance(value, TableData):
            return value
        if isinstance(value, dict):
            keys = set(value)
            allowed = {"x", "y", "z", "source"}
            if not keys <= allowed or not {"x", "y"} <= keys:
                raise ValueError(
                    f"Table '{self.name}': give a preset name ({', '.join(self.presets)}) or a "
                    f"mapping with keys x, y (and z for a 2-D map); got keys {sorted(keys)}."
                )
            z = value.get("z")
            return TableData(
                tuple(value["x"]), tuple(value["y"]),
                None if z is None else tuple(map(tuple, z)), value.get("source", "config"),
            )
        raise ValueError(f"Table '{self.name}': cannot use a value of type {type(value).__name__}.")
