"""Rewards of the environments: a swappable class with documented weights and units."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numba
import numpy as np

QUANTITIES = ("battery_kwh", "grid_kwh", "peak_rise_kw", "comfort_kh", "late_min",
              "reserve_pct_h", "service_lost_h")
"""What a decision is scored on, per bus (columns of the quantities the envs pass)."""
TERMS = ("battery_energy", "grid_energy", "peak_power", "comfort", "delay", "reserve",
         "lost_service")


@dataclass(frozen=True)
class Reward:
    """Negative cost of one decision interval::

        r = -( w_battery E_battery + w_grid E_grid + w_peak dP_peak + w_comfort D_comfort
               + w_delay T_late + w_reserve R + w_lost H_lost )

    E_battery  net energy out of the battery's chemical store [kWh]
    E_grid     energy drawn from the grid by the charger [kWh]
    dP_peak    rise of the episode's peak grid power (mean over a decision) [kW]: a
               demand-charge proxy, paid once per kW of new peak (the fleet: the site's peak)
    D_comfort  cabin temperature outside the comfort band, integrated [K h]
    T_late     delay added at departures from the terminal beyond the layover slack [min]
    R          SoC below the reserve, integrated [%-points h]
    H_lost     service hours left when the battery runs empty (the episode ends there) [h]

    Defaults price energy at 1 per kWh, the peak like a monthly demand charge spread over a
    month's days (0.5 per kW), and comfort, delay and reserve high enough that the policy
    does not buy energy with them. Lost service is priced like a replacement bus and driver
    (about 100 EUR/h at 0.25 EUR/kWh: 400 per hour), so that running the pack empty never
    pays, even though it ends the episode and with it the costs of the rest of the day.
    Another reward: subclass and override :meth:`costs`.
    """

    battery_per_kwh: float = 1.0
    grid_per_kwh: float = 0.2
    peak_per_kw: float = 0.5
    comfort_per_kelvin_hour: float = 2.0
    delay_per_min: float = 0.5
    reserve_per_pct_hour: float = 5.0
    lost_service_per_hour: float = 400.0
    weights: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "weights", np.array(
            [self.battery_per_kwh, self.grid_per_kwh, self.peak_per_kw,
             self.comfort_per_kelvin_hour, self.delay_per_min, self.reserve_per_pct_hour,
             self.lost_service_per_hour]))

    def costs(self, quantities: np.ndarray) -> np.ndarray:
        """(n, 7) quantities (columns ``QUANTITIES``) -> (n, 7) costs (columns ``TERMS``)."""
        return quantities * self.weights

    def __call__(self, quantities: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rewards (n,) and costs (n, 7) of n buses' decisions."""
        costs = self.costs(quantities)
        return -costs.sum(axis=1), costs

    def to_dict(self) -> dict[str, float]:
        out = asdict(self)
        out.pop("weights")
        return out


@numba.njit(cache=True, nogil=True)
def comfort_band_degc(ambient_degc: float, passengers: float, capacity: float
                      ) -> tuple[float, float]:
    """Comfort band of the cabin [degC]: centred at 20 degC up to 15 degC outside and 0.25 K
    warmer per K above (adaptive comfort: people dressed for the weather, after EN 16798-1),
    +-2.5 K wide, narrowed by up to 1 K when the bus is full (crowding)."""
    centre = 20.0 + 0.25 * min(max(ambient_degc - 15.0, 0.0), 16.0)
    half = 2.5 - 1.0 * min(max(passengers / max(capacity, 1.0), 0.0), 1.0)
    return centre - half, centre + half
