"""The operator's cost of a fleet day, split into energy, demand, chargers and battery wear.

Tariffs, capex and battery prices differ by country, utility and year, so the cost model has no
defaults: every input is required in the study file, in one currency (the shipped example states
where its values come from). Per day::

    energy   = sum_t P_site(t) dt price(hour of t)                       [currency]
    demand   = P_15min,max * demand_charge_per_kw_month * 12 / operating_days_per_year
    chargers = installed_kw * capex_per_kw * a(r, n) / operating_days_per_year,
               a(r, n) = r / (1 - (1 + r)^-n)   (annuity factor; 1/n when r = 0)
    wear     = E_discharged * battery_price_per_kwh / cycle_life_efc

The demand charge takes the day's 15-min peak as the month's (the billing peak is the month's
highest 15-min mean). Wear prices throughput: a pack that reaches its end of life after
``cycle_life_efc`` equivalent full cycles, each discharging its capacity C once, has passed
C * EFC kWh, so each discharged kWh costs price * C / (C * EFC) = price / EFC.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from ebus_env.errors import ConfigError
from ebus_env.study.checks import check_keys, is_number


@dataclass(frozen=True)
class CostModel:
    """Prices (all required). ``energy_price_per_kwh``: one price or 24 hourly prices from
    00:00 [currency/kWh]; ``interest_rate`` [1/year]."""

    currency: str
    energy_price_per_kwh: tuple[float, ...]
    demand_charge_per_kw_month: float
    charger_capex_per_kw: float
    charger_life_years: float
    interest_rate: float
    battery_price_per_kwh: float
    battery_cycle_life_efc: float
    operating_days_per_year: float

    @classmethod
    def load(cls, data: dict) -> CostModel:
        """From the study's ``costs`` mapping; a missing or bad input is a ConfigError."""
        names = [f.name for f in fields(cls)]
        check_keys(data, names, "costs")
        missing = [n for n in names if n not in data]
        if missing:
            raise ConfigError(f"costs: missing {', '.join(missing)}; the cost model has no "
                              "defaults (tariffs differ by utility): give each in the study "
                              "file (see configs/studies/example.yaml).")
        prices = data["energy_price_per_kwh"]
        prices = prices if isinstance(prices, list) else [prices] * 24
        if len(prices) != 24 or not all(is_number(p) and p >= 0 for p in prices):
            raise ConfigError(f"costs.energy_price_per_kwh = {data['energy_price_per_kwh']!r}: "
                              "give one price >= 0 or a list of 24 hourly prices from 00:00.")
        values = {"currency": str(data["currency"]), "energy_price_per_kwh": tuple(map(float,
                                                                                       prices))}
        bounds = {"interest_rate": (0.0, 1.0), "charger_life_years": (1.0, 60.0),
                  "operating_days_per_year": (1.0, 366.0)}
        for key in names[2:]:
            low, high = bounds.get(key, (0.0, np.inf))
            value = data[key]
            if not is_number(value) or not low <= value <= high or (
                    key in ("battery_cycle_life_efc",) and value <= 0):
                raise ConfigError(f"costs.{key} = {value!r}: give a number in [{low:g}, "
                                  f"{high:g}]{' (> 0)' if key == 'battery_cycle_life_efc' else ''}.")
            values[key] = float(value)
        return cls(**values)

    @property
    def annuity_factor(self) -> float:
        """Capital recovery factor r / (1 - (1 + r)^-n) [1/year]."""
        r, n = self.interest_rate, self.charger_life_years
        return 1.0 / n if r == 0.0 else r / (1.0 - (1.0 + r) ** -n)

    def day(self, load_kw: np.ndarray, step_h: float, start_h: float, peak_15min_kw: float,
            installed_kw: float, discharged_kwh: float) -> dict[str, float]:
        """A day's cost by part [currency]: ``load_kw`` the site's mean power in steps of
        ``step_h`` from ``start_h`` (hour of day)."""
        hours = (start_h + step_h * np.arange(len(load_kw))) % 24.0
        price = np.asarray(self.energy_price_per_kwh)[hours.astype(int)]
        days = self.operating_days_per_year
        return {
            "energy": float(np.sum(load_kw * step_h * price)),
            "demand": peak_15min_kw * self.demand_charge_per_kw_month * 12.0 / days,
            "chargers": installed_kw * self.charger_capex_per_kw * self.annuity_factor / days,
            "battery_wear": discharged_kwh * self.battery_price_per_kwh
            / self.battery_cycle_life_efc,
        }



def add_costs(row: dict, cost: dict[str, float]) -> dict:
    """A day's row with its cost by part per km, in all, per day, and its grid kWh per km."""
    km = max(row["distance_km"], 1e-9)
    row.update({f"cost_{part}_per_km": value / km for part, value in cost.items()})
    row["cost_per_km"] = sum(cost.values()) / km
    row["cost_day"] = sum(cost.values())
    row["kwh_per_km"] = row["grid_kwh"] / km
    return row
