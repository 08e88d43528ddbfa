"""iSOPT: the improved simple optimization metaheuristic (Thomas & Mahapatra 2016).

SOPT (Hasancebi & Kazemzadeh Azad 2012) keeps a population sorted by cost and samples new
candidates around the best one, with a spread taken from the population itself::

    exploitation:  x_new = x_best + c2 sigma z      (c2 < 1, narrow)
    exploration:   x_new = x_best + c1 sigma z      (c1 > 1, wide)
    sigma_j = std_i(x_ij),  z ~ N(0, 1),  x clipped to the box
    selection: the best N of population + candidates   ((mu + lambda) truncation)

iSOPT adds a way out of local optima. Only the abstract of the iSOPT paper could be read, so the
escape is a reconstruction (docs/physics.md §9.3): when the best cost has not improved for
``stall_iterations`` iterations, or the population has collapsed (every sigma_j below
``sigma_min``), the worst ``reinit_frac`` of the population is re-drawn uniformly in the box.

Where the published algorithm is uncertain, and what is chosen here (all configurable):

* the order of the phases: exploitation first, then exploration (as the one public port);
* the constants: c2 = 0.7, c1 = 1.6 (docs/physics.md §9.4: with N = 11, c1 = 1.0 collapses early);
* Gaussian z (the port) rather than uniform; a sigma floor of ``sigma_min`` per variable;
* ``offspring`` candidates per phase, default N, so one run costs N + 2 N T evaluations
  (11 + 2 x 11 x 50 = 1111 with the defaults);
* all variables normalised to [0, 1] (the calibrator knows nothing of units).

An evaluation may return a lower bound instead of the cost for a candidate that cannot enter
the population (the upper-bound strategy of Hasancebi & Kazemzadeh Azad 2013): the optimiser
passes the cost a candidate must beat, and the selection is unchanged by it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np


@dataclass
class ISOPTSettings:
    """Constants of iSOPT (see module docstring)."""

    population: int = 11
    iterations: int = 50
    offspring: int | None = None  # per phase; None: the population size
    c_exploit: float = 0.7
    c_explore: float = 1.6
    stall_iterations: int = 8
    sigma_min: float = 1e-3
    reinit_frac: float = 0.5
    improvement_tol: float = 1e-9
    seed: int = 0

    def __post_init__(self) -> None:
        if self.population < 2 or self.iterations < 0:
            raise ValueError("iSOPT needs a population of at least 2 and iterations >= 0.")
        if self.c_exploit <= 0 or self.c_explore <= 0:
            raise ValueError("iSOPT step scales must be positive.")

    @property
    def n_offspring(self) -> int:
        return self.offspring or self.population

    @property
    def budget(self) -> int:
        """Evaluations of a full run without escapes: N + 2 * offspring * T."""
        return self.population + 2 * self.n_offspring * self.iterations


@dataclass
class History:
    """What a run did: best cost after each iteration (index 0: the initial population)."""

    best_cost: list[float] = field(default_factory=list)
    best_x: list[np.ndarray] = field(default_factory=list)
    evaluations: list[int] = field(default_factory=list)
    wall_time_s: list[float] = field(default_factory=list)
    escapes: list[int] = field(default_factory=list)
    x: list[np.ndarray] = field(default_factory=list)  # every candidate evaluated (normalised)
    cost: list[np.ndarray] = field(default_factory=list)  # its cost or lower bound

    def all_evaluated(self) -> tuple[np.ndarray, np.ndarray]:
        return np.concatenate(self.x), np.concatenate(self.cost)


@dataclass
class ISOPTResult:
    x: np.ndarray  # best point, normalised
    cost: float
    history: History
    evaluations: int
    interrupted: bool = False
    population: np.ndarray | None = None  # the final population, best first


CostFunction = Callable[[np.ndarray, float], np.ndarray]
Progress = Callable[[int, float, int], None]
"""A progress callback: (iteration or window, best cost so far, evaluations so far)."""


def isopt(cost: CostFunction, dim: int, settings: ISOPTSettings | None = None,
          x0: np.ndarray | None = None,
          callback: Progress | None = None,
          population: np.ndarray | None = None) -> ISOPTResult:
    """Minimise ``cost`` over the unit box [0, 1]^dim.

    Parameters
    ----------
    cost
        ``cost(U, threshold) -> costs`` for candidates ``U`` (n, dim); a candidate whose cost
        is known to exceed ``threshold`` may get any value above it (a lower bound).
    dim
        Number of variables.
    settings
        Constants; see :class:`ISOPTSettings`.
    x0
        Warm start: the first member of the initial population (e.g. the previous window's best).
    population
        Warm start with a whole population (e.g. the previous window's final one, re-evaluated
        on the new data); fills the first members of the initial population.
    callback
        ``callback(iteration, best_cost, evaluations)`` after each iteration.

    A ``KeyboardInterrupt`` during the run stops it: the best point so far is returned with
    ``interrupted=True``.
    """
    s = settings or ISOPTSettings()
    rng = np.random.default_rng(s.seed)
    history = History()
    t0 = time.perf_counter()
    n = s.population
    evaluations = 0

    def evaluate(u: np.ndarray, threshold: float) -> np.ndarray:
        nonlocal evaluations
        c = np.asarray(cost(u, threshold), dtype=float)
        c = np.where(np.isfinite(c), c, np.inf)
        evaluations += len(u)
        history.x.append(u.copy())
        history.cost.append(c.copy())
        return c

    pop = rng.uniform(0.0, 1.0, (n, dim))
    if population is not None:
        k = min(n, len(population))
        pop[:k] = np.clip(np.asarray(population, dtype=float)[:k], 0.0, 1.0)
    if x0 is not None:
        pop[0] = np.clip(np.asarray(x0, dtype=float), 0.0, 1.0)
    interrupted = False
    try:
        f = evaluate(pop, math.inf)
    except KeyboardInterrupt:
        raise KeyboardInterrupt("interrupted before the first population was evaluated") from None
    order = np.argsort(f, kind="stable")
    pop, f = pop[order], f[order]
    best_cost = f[0]
    stall = 0

    def record(iteration: int) -> None:
        history.best_cost.append(float(f[0]))
        history.best_x.append(pop[0].copy())
        history.evaluations.append(evaluations)
        history.wall_time_s.append(time.perf_counter() - t0)
        if callback:
            callback(iteration, float(f[0]), evaluations)

    record(0)
    try:
        for it in range(1, s.iterations + 1):
            for scale in (s.c_exploit, s.c_explore):
                sigma = np.maximum(pop.std(axis=0), s.sigma_min)
                z = rng.standard_normal((s.n_offspring, dim))
                candidates = np.clip(pop[0] + scale * sigma * z, 0.0, 1.0)
                fc = evaluate(candidates, float(f[-1]))
                merged = np.concatenate([pop, candidates])
                fm = np.concatenate([f, fc])
                keep = np.argsort(fm, kind="stable")[:n]
                pop, f = merged[keep], fm[keep]
            if f[0] < best_cost - s.improvement_tol:
                best_cost = f[0]
                stall = 0
            else:
                stall += 1
            collapsed = float(np.max(pop.std(axis=0))) < s.sigma_min
            if stall >= s.stall_iterations or collapsed:
                # the iSOPT escape: re-draw the worst members, keep the elite
                k = math.ceil(s.reinit_frac * (n - 1))
                fresh = rng.uniform(0.0, 1.0, (k, dim))
                pop[n - k:] = fresh
                f[n - k:] = evaluate(fresh, math.inf)
                order = np.argsort(f, kind="stable")
                pop, f = pop[order], f[order]
                history.escapes.append(it)
                stall = 0
            record(it)
    except KeyboardInterrupt:
        interrupted = True
    return ISOPTResult(pop[0].copy(), float(f[0]), history, evaluations, interrupted, pop.copy())
