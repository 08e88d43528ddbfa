"""A charging site: the buses of one or more lines sharing a terminal's chargers and its grid
connection, advanced one decision at a time.

This is the one site step of the package: ``EBusFleet-v0`` (:mod:`ebus_env.envs.fleet`) and
the fleet studies (:mod:`ebus_env.study.runner`) both call :meth:`ChargingSite.step`. A
decision of ``decision_s`` is three passes over every line's buses
(:class:`ebus_env.envs.batch.BusBatch`):

1. each line drives its buses under their actions, writing the 10 Hz input rows (the
   reference vehicle asks for a plug on every layover row);
2. the terminal's plugs and grid limit are shared row by row (:func:`share_site`): a bus
   on a layover takes a free plug first come, first served, the others wait unplugged; the
   plugged buses' ratings are scaled together so that their grid draw stays within the limit;
3. each line runs its physics on the shared rows, then scores and observes its buses.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ebus_env.envs.batch import OBSERVATIONS, BusBatch
from ebus_env.errors import ConfigError

PLUGGED = [o[0] for o in OBSERVATIONS].index("charger_connected")


@numba.njit(cache=True, nogil=True)
def share_site(connected: np.ndarray, rating_w: np.ndarray, efficiency: np.ndarray,
               plugged: np.ndarray, waiting_since: np.ndarray, chargers: int, limit_w: float,
               row0: int) -> None:
    """The terminal's charging, row by row (in place): buses on a layover take a free plug
    first come, first served (the others wait unconnected); the plugged buses' charger
    ratings are scaled down together so that their grid draw, sum(P_rated / eta), stays
    within ``limit_w`` (balanced sharing). ``plugged``, ``waiting_since`` (row index, -1:
    not waiting) carry over between decisions; ``row0``: the first row's index."""
    n, n_rows = connected.shape
    for r in range(n_rows):
        used = 0
        for b in range(n):
            if plugged[b] and connected[b, r] < 0.5:
                plugged[b] = False
            if connected[b, r] >= 0.5 and not plugged[b] and waiting_since[b] < 0:
                waiting_since[b] = row0 + r
            if connected[b, r] < 0.5:
                waiting_since[b] = -1
            used += plugged[b]
        while used < chargers:  # the longest waiting takes the next free plug
            first = -1
            for b in range(n):
                if waiting_since[b] >= 0 and (first < 0 or waiting_since[b] < waiting_since[first]):
                    first = b
            if first < 0:
                break
            plugged[first] = True
            waiting_since[first] = -1
            used += 1
        draw_w = 0.0
        for b in range(n):
            if plugged[b]:
                draw_w += rating_w[b, r] / efficiency[b]
        scale = min(1.0, limit_w / draw_w) if draw_w > 0.0 else 1.0
        for b in range(n):
            if plugged[b]:
                rating_w[b, r] *= scale
            else:
                connected[b, r] = 0.0
                rating_w[b, r] = math.nan


@numba.njit(cache=True, nogil=True)
def _share(connected: np.ndarray, rating_w: np.ndarray, rows: np.ndarray, efficiency: np.ndarray,
           plugged: np.ndarray, waiting_since: np.ndarray, chargers: int, limit_w: float,
           row0: int) -> tuple[float, float]:
    """:func:`share_site` (with no charger nobody connects); returns the bus-rows that asked
    for a plug and those that held one, counting each bus's ``rows`` (a last decision may be
    short)."""
    wanted = _live_rows(connected, rows)
    if chargers == 0:
        connected[:] = 0.0
        rating_w[:] = math.nan
    else:
        share_site(connected, rating_w, efficiency, plugged, waiting_since, chargers, limit_w,
                   row0)
    return wanted, _live_rows(connected, rows)


@numba.njit(cache=True, nogil=True, inline="always")
def _live_rows(connected: np.ndarray, rows: np.ndarray) -> float:
    total = 0.0  # sums of 0s and 1s: exact in any order
    for b in range(connected.shape[0]):
        for r in range(rows[b]):
            total += connected[b, r]
    return total


def _gather(arrays: list[np.ndarray]) -> np.ndarray:
    """The buses of every line in one array: a line's own array (a view) when there is one."""
    return arrays[0] if len(arrays) == 1 else np.concatenate(arrays)


class ChargingSite:
    """The buses of ``lines`` (one :class:`BusBatch` per line, one clock) at a terminal with
    ``chargers`` plugs behind a grid connection of ``site_limit_kw``.

    Per bus, in the lines' order: ``plugged`` (holding a plug), ``waiting_since`` (the row
    since which it waits for one, -1: not waiting) and ``efficiency`` (its charger's). Over
    the day so far: ``held_rows`` (bus-rows on a plug) and ``waited_rows`` (bus-rows on a
    layover without one), at ``dt_s``.
    """

    def __init__(self, lines: list[BusBatch], chargers: int, site_limit_kw: float):
        for line in lines:
            if not line.has_charger:
                raise ConfigError(f"The bus '{line.config.bus}' has no charger effect (inputs "
                                  "charger_connected and charger_rating_w): a charging site "
                                  "needs one.")
        self.lines = lines
        self.chargers, self.limit_w = int(chargers), 1e3 * float(site_limit_kw)
        self.n = sum(line.n for line in lines)
        self.edges = np.cumsum([0] + [line.n for line in lines])
        self.efficiency = np.concatenate([np.full(line.n, line.charger_efficiency)
                                          for line in lines])
        self.n_rows = lines[0].n_rows
        self.reset_site()

    def reset(self, rng: np.random.Generator) -> None:
        """Start a new day: every line's buses in turn draw their day from ``rng``
        (:meth:`BusBatch.reset`), every plug is free."""
        for line in self.lines:
            for b in range(line.n):
                line.reset(b, rng)
        self.reset_site()

    def reset_site(self) -> None:
        """Free every plug and clear the day's counts (the buses as they are)."""
        self.plugged = np.zeros(self.n, np.bool_)
        self.waiting_since = np.full(self.n, -1, np.int64)
        self.decision = 0
        self.held_rows = self.waited_rows = 0.0

    def step(self, values: np.ndarray) -> None:
        """One decision of every bus, actions in physical units ``values`` (n, 5) in the
        lines' order; results in each line's ``obs``, ``quantities`` and ``out``."""
        lines = self.lines
        for line, lo, hi in zip(lines, self.edges[:-1], self.edges[1:], strict=True):
            line.drive(0, line.n, values[lo:hi])
        rows = [line.charger_rows() for line in lines]  # views into each line's input rows
        connected, rating = _gather([r[0] for r in rows]), _gather([r[1] for r in rows])
        wanted, held = _share(connected, rating, _gather([line.rows for line in lines]),
                              self.efficiency, self.plugged, self.waiting_since, self.chargers,
                              self.limit_w, self.decision * self.n_rows)
        self.held_rows += held
        self.waited_rows += wanted - held
        if len(lines) > 1:  # one line shared its own rows in place; the others copied
            for (c, r), lo, hi in zip(rows, self.edges[:-1], self.edges[1:], strict=True):
                c[:] = connected[lo:hi]
                r[:] = rating[lo:hi]
        for line in lines:
            line.run(0, line.n)
        self.decision += 1

    def observations(self) -> np.ndarray:
        """Every bus's ``EBus-v0`` observation (n, 16), "charger connected" meaning holding
        one of the site's plugs."""
        obs = np.concatenate([line.obs for line in self.lines])
        obs[:, PLUGGED] = self.plugged
        return obs

    def column(self, name: str) -> np.ndarray:
        """A column of the lines' last decision (``BusBatch.column``) for every bus (a line's
        own array, a view, when there is one line)."""
        return _gather([line.column(name) for line in self.lines])

    def waiting(self) -> int:
        """Buses on a layover waiting for a plug."""
        return int((self.waiting_since >= 0).sum())


def share_plugs(connected: np.ndarray, rating_w: np.ndarray, efficiency: np.ndarray,
                chargers: int, limit_w: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
    """A terminal's plugs shared over given rows (buses, rows) from a free start, by the same
    rule as the site step (:func:`share_site`: first come, first served, ratings scaled to
    ``limit_w``): for schedules whose layovers are known before the physics runs (a
    timetable's blocks). Returns new (connected, rating [W]) arrays; rows without a plug are
    0 and NaN."""
    connected = np.array(connected, float)
    rating = np.array(rating_w, float)
    n = connected.shape[0]
    if chargers <= 0:
        connected[:] = 0.0
        rating[:] = math.nan
        return connected, rating
    share_site(connected, rating, np.asarray(efficiency, float), np.zeros(n, np.bool_),
               np.full(n, -1, np.int64), int(chargers), float(limit_w), 0)
    return connected, rating
