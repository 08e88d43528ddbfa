"""Rewards of the environments: a swappable class with documented weights and units."""

from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class Reward:
    """Negative cost of one decision interval::

        r = -( w_battery E_battery + w_grid E_grid + w_peak dP_peak + w_comfort D_comfort
               + w_delay T_late + w_reserve R )

    E_battery  net energy out of the battery's chemical store [kWh]
    E_grid     energy drawn from the grid by the charger [kWh]
    dP_peak    rise of the episode's peak grid power (mean over a decision) [kW]: a
               demand-charge proxy, paid once per kW of new peak
    D_comfort  cabin temperature outside the comfort band, integrated [K h]
    T_late     delay added at departures from the terminal beyond the layover slack [min]
    R          SoC below the reserve, integrated [%-points h]

    Defaults price energy at 1 per kWh, the peak like a monthly demand charge spread over a
    month's days (0.5 per kW), and comfort, delay and reserve high enough that the policy
    does not buy energy with them.
    """

    battery_per_kwh: float = 1.0
    grid_per_kwh: float = 0.2
    peak_per_kw: float = 0.5
    comfort_per_kelvin_hour: float = 2.0
    delay_per_min: float = 0.5
    reserve_per_pct_hour: float = 5.0

    def terms(self, battery_kwh: float, grid_kwh: float, peak_rise_kw: float,
              comfort_kh: float, late_min: float, reserve_pct_h: float) -> dict[str, float]:
        """Each term of the cost (positive numbers, the reward is minus their sum)."""
        return {"battery_energy": self.battery_per_kwh * battery_kwh,
                "grid_energy": self.grid_per_kwh * grid_kwh,
                "peak_power": self.peak_per_kw * peak_rise_kw,
                "comfort": self.comfort_per_kelvin_hour * comfort_kh,
                "delay": self.delay_per_min * late_min,
                "reserve": self.reserve_per_pct_hour * reserve_pct_h}

    def __call__(self, **quantities: float) -> tuple[float, dict[str, float]]:
        terms = self.terms(**quantities)
        return -sum(terms.values()), terms

    def to_dict(self) -> dict:
        return asdict(self)


def comfort_band_degc(ambient_degc: float, passengers: float, capacity: float) -> tuple[
        float, float]:
    """Comfort band of the cabin [degC]: centred at 20 degC up to 15 degC outside and 0.25 K
    warmer per K above (adaptive comfort: people dressed for the weather, after EN 16798-1),
    +-2.5 K wide, narrowed by up to 1 K when the bus is full (crowding)."""
    centre = 20.0 + 0.25 * min(max(ambient_degc - 15.0, 0.0), 16.0)
    half = 2.5 - 1.0 * min(max(passengers / max(capacity, 1.0), 0.0), 1.0)
    return centre - half, centre + half
