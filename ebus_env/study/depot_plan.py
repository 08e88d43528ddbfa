"""Overnight depot charging of a timetable's buses, planned three ways on 15-min steps.

Each bus b is at the depot from its arrival to its next departure (whole 15-min steps k of
length dt inside that window) and needs ``E_b`` kWh into its pack. The depot has ``N`` plugs
of ``P`` kW (the charger's output, drawing ``P / eta`` from the grid) behind a grid limit
``L``; the site also carries a base load ``B_k`` (the terminals' charging, when the study
bills one account).

``optimal``: a linear programme with the plug count as a capacity, solved by HiGHS through
``scipy.optimize.milp`` (no integer variables, so HiGHS returns the optimum, gap 0)::

    min   sum_k c_k dt sum_b p_bk  +  D * peak  +  M * sum_b s_b
    s.t.  sum_k eta p_bk dt + s_b >= E_b        each bus gets its energy (s_b: what it lacks)
          0 <= p_bk <= P / eta                  at most its charger's rating
          sum_b p_bk <= N P / eta               the plugs, as a capacity per step
          sum_b p_bk <= L                       the depot's grid limit
          peak >= B_k + sum_b p_bk              the billed 15-min peak

with ``p_bk`` the grid power [kW] of bus b in step k, ``c_k`` the energy price of the step's
hour, ``D`` the demand charge per kW and day (``demand_charge_per_kw_month * 12 /
operating_days``) and ``M`` a penalty well above any price (a bus left short is reported,
never hidden). The plug capacity is exact when buses may change plug within a step: any
powers with p_bk <= P / eta and a sum within N P / eta fit on N plugs by McNaughton's
wrap-around rule (bus after bus fills a plug's 15 minutes, the overflow continuing on the
next plug). A depot whose buses stay on one plug all night needs a binary per bus and step
instead (a MILP); this plan is then a lower bound of its cost. The pack's CC/CV taper is not
in the plan (it holds a constant power through each step).

``on_arrival``: each bus plugs in when it arrives (first come, first served; a bus keeps its
plug until charged) and charges at the full rating. ``flat``: the same plugs, each bus at the
constant power that spreads its need over the time it has left. In both, the plugged buses'
powers are scaled together to the grid limit.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

STEP_S = 900.0
TIME_LIMIT_S = 10.0  # HiGHS stops there (it returns the best plan found and says so)
METHODS = ("optimal", "on_arrival", "flat")


@dataclass
class DepotPlan:
    """A depot plan: grid power per bus and step [kW] from step ``k0`` (step k covers
    [k dt, (k + 1) dt) after the service day's midnight), the energy each bus got into its
    pack [kWh], and for the optimisation its solver status and solve time."""

    method: str
    k0: int
    power_kw: np.ndarray  # (buses, steps)
    delivered_kwh: np.ndarray
    need_kwh: np.ndarray
    status: str = ""
    solve_s: float = 0.0

    @property
    def short(self) -> np.ndarray:
        """Buses that do not get their energy (0.5 % or 0.1 kWh tolerance)."""
        return self.delivered_kwh < self.need_kwh - np.maximum(0.005 * self.need_kwh, 0.1)

    def folded_kw(self) -> np.ndarray:
        """The depot's load over a day of 96 steps from midnight (a step past 24:00 lands on
        the next morning's hour: the same day repeated)."""
        out = np.zeros(int(86400 / STEP_S))
        k = (self.k0 + np.arange(self.power_kw.shape[1])) % len(out)
        np.add.at(out, k, self.power_kw.sum(axis=0))
        return out


def _window(arrive_s: np.ndarray, depart_s: np.ndarray) -> tuple[int, np.ndarray]:
    """The first step and the (buses, steps) mask of whole steps each bus is at the depot."""
    k0 = int(np.floor(arrive_s.min() / STEP_S)) if len(arrive_s) else 0
    k1 = int(np.ceil(depart_s.max() / STEP_S)) if len(arrive_s) else 0
    starts = (k0 + np.arange(max(k1 - k0, 0))) * STEP_S
    present = (starts[None, :] >= arrive_s[:, None] - 1e-6) & \
        (starts[None, :] + STEP_S <= depart_s[:, None] + 1e-6)
    return k0, present


def plan(method: str, arrive_s, depart_s, need_kwh, chargers: int, charger_kw: float,
         efficiency: float, limit_kw: float, price_per_kwh, demand_per_kw_day: float,
         base_kw: np.ndarray | None = None) -> DepotPlan:
    """Plan the depot by ``method`` (``METHODS``). ``price_per_kwh``: 24 hourly prices from
    midnight; ``base_kw``: the site's other load over 96 steps from midnight (None: 0)."""
    arrive_s, depart_s = np.asarray(arrive_s, float), np.asarray(depart_s, float)
    need = np.maximum(np.asarray(need_kwh, float), 0.0)
    k0, present = _window(arrive_s, depart_s)
    if chargers <= 0:
        present[:] = False
    grid_max = charger_kw / efficiency
    if method == "optimal":
        return _optimal(k0, present, need, chargers, grid_max, efficiency, limit_kw,
                     np.asarray(price_per_kwh, float), demand_per_kw_day, base_kw)
    if method not in METHODS:
        raise ValueError(f"depot plan {method!r}: one of {', '.join(METHODS)}")
    n, m = present.shape
    power = np.zeros((n, m))
    left = need / efficiency  # grid energy still to draw [kWh]
    plugged = np.zeros(n, bool)
    order = np.argsort(arrive_s, kind="stable")
    dt_h = STEP_S / 3600.0
    for k in range(m):
        plugged &= present[:, k] & (left > 1e-9)
        for b in order:  # first come, first served on the free plugs
            if plugged.sum() >= chargers:
                break
            if present[b, k] and left[b] > 1e-9 and not plugged[b]:
                plugged[b] = True
        want = np.zeros(n)
        if method == "on_arrival":
            want[plugged] = grid_max
        else:
            steps_left = present[:, k:].sum(axis=1)
            want[plugged] = np.minimum(grid_max, left[plugged] / (np.maximum(
                steps_left[plugged], 1) * dt_h))
        want = np.minimum(want, left / dt_h)
        total = want.sum()
        if total > limit_kw:
            want *= limit_kw / total
        power[:, k] = want
        left -= want * dt_h
    return DepotPlan(method, k0, power, power.sum(axis=1) * dt_h * efficiency, need)


def _optimal(k0, present, need, chargers, grid_max, efficiency, limit_kw, prices, demand,
             base_kw) -> DepotPlan:
    from scipy.optimize import Bounds, LinearConstraint, milp
    from scipy.sparse import coo_matrix

    n, m = present.shape
    dt_h = STEP_S / 3600.0
    b_idx, k_idx = np.nonzero(present)
    v = len(b_idx)  # power variables, then each bus's shortfall, then the peak
    hours = ((k0 + k_idx) * STEP_S % 86400 // 3600).astype(int)
    base = np.zeros(m) if base_kw is None else np.asarray(base_kw, float)[
        (k0 + np.arange(m)) % len(base_kw)]
    penalty = 100.0 * max(prices.max(), 1e-3) / efficiency
    cost = np.concatenate([prices[hours] * dt_h, np.full(n, penalty), [demand]])
    total = v + n + 1
    step_cap = min(limit_kw, chargers * grid_max)  # the grid limit and the plugs per step
    rows = np.concatenate([b_idx, np.arange(n), n + k_idx, n + m + k_idx, n + m + np.arange(m)])
    cols = np.concatenate([np.arange(v), v + np.arange(n), np.arange(v), np.arange(v),
                           np.full(m, total - 1)])
    vals = np.concatenate([np.full(v, efficiency * dt_h), np.ones(n), np.ones(v), -np.ones(v),
                           np.ones(m)])
    lo = np.concatenate([need, np.zeros(m), base])
    hi = np.concatenate([np.full(n, np.inf), np.full(m, step_cap), np.full(m, np.inf)])
    a = coo_matrix((vals, (rows, cols)), shape=(n + 2 * m, total)).tocsr()
    upper = np.concatenate([np.full(v, grid_max), np.full(n + 1, np.inf)])
    t0 = time.perf_counter()
    res = milp(cost, constraints=LinearConstraint(a, lo, hi), bounds=Bounds(0.0, upper),
               options={"time_limit": TIME_LIMIT_S, "disp": False})
    solve_s = time.perf_counter() - t0
    power = np.zeros((n, m))
    if res.x is None:
        return DepotPlan("optimal", k0, power, np.zeros(n), need,
                         f"no plan: {res.message}", solve_s)
    power[b_idx, k_idx] = np.maximum(res.x[:v], 0.0)
    return DepotPlan("optimal", k0, power, power.sum(axis=1) * dt_h * efficiency, need,
                     f"LP, HiGHS: {res.message}", solve_s)
