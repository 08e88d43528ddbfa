"""The BMW i3's logged pack temperature against the model's unmanaged pack, with and without
the pack's own ohmic heat.

    python -m benchmarks.compare_pack_temperature [--reserved]
    python -m benchmarks.compare_pack_temperature --smoke   # CI: trip B03 only

The TUM BMW i3 trips (``data/measured/bmw_i3_tum``) log the pack's temperature (1 K steps).
The i3 (``configs/bus/bmw_i3.yaml``) with ``ambient_battery`` in its battery-temperature slot
(the heat capacity of its 230 kg pack, time constant 3 h) is started at the logged pack
temperature and driven through each trip: once with the pack following the ambient alone
(the Joule term made negligible: heat capacity 5e7 J/K, 200 times the pack's) and once warmed
by its ohmic loss R I^2. Neither value was fitted to these trips. ``--reserved`` runs the
reserved trips B17, B38 and A08 too (their figures are reported, never used to choose a
value). Prints a table; no assertions.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from ebus_env.config import load_bus
from ebus_env.io.measured import load_log

ROOT = Path(__file__).resolve().parent.parent

BMW = ROOT / "data" / "measured" / "bmw_i3_tum"
TRIPS = ("B16", "B03", "B02", "A01", "A07")
RESERVED = ("B17", "B38", "A08")
NO_HEAT_J_PER_K = 5e7
"""A heat capacity at which the pack's own loss warms it 200 times less than the i3's real one:
the pack that only follows the ambient."""


def pack_temperatures(trip: str, joule_heat: bool) -> tuple[np.ndarray, np.ndarray]:
    """Logged and simulated pack temperature [degC] of a trip, at 1 Hz."""
    path = BMW / f"Trip{trip}_1hz.csv"
    profile = load_log(path, columns="bmw_i3_tum").profiles[0]
    logged = pd.read_csv(path)["batt_temp_c"].to_numpy(float)
    model = load_bus("bmw_i3").with_effect("ambient_battery").build(profile.dt_s)
    values = {} if joule_heat else {"ambient_battery.heat_capacity_j_per_k": NO_HEAT_J_PER_K}
    run = model.simulate(profile, model.param_vector(model.carry_over(values)),
                         record_every=int(round(1.0 / profile.dt_s)),
                         cell_temp_degc=float(logged[0]))
    simulated = run.trace("battery_temp_degc").astype(float)
    n = min(len(logged), len(simulated))
    return logged[:n], simulated[:n]


def errors_k(trip: str, joule_heat: bool) -> tuple[float, float]:
    """RMSE and end error [K] of the simulated pack temperature against the logged one."""
    logged, simulated = pack_temperatures(trip, joule_heat)
    return float(np.sqrt(np.mean((simulated - logged) ** 2))), float(simulated[-1] - logged[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reserved", action="store_true",
                        help="also the reserved trips B17, B38, A08 (report only)")
    parser.add_argument("--smoke", action="store_true", help="trip B03 only (CI)")
    args = parser.parse_args()
    trips = ("B03",) if args.smoke else TRIPS + (RESERVED if args.reserved else ())
    print(f"{'trip':6s} {'pack logged degC':>18s} {'ambient degC':>13s} "
          f"{'RMSE following ambient K':>25s} {'RMSE + ohmic heat K':>19s} "
          f"{'end error K (both)':>19s}")
    for trip in trips:
        raw = pd.read_csv(BMW / f"Trip{trip}_1hz.csv")
        (rmse_a, end_a), (rmse_h, end_h) = errors_k(trip, False), errors_k(trip, True)
        temp, ambient = raw["batt_temp_c"], raw["ambient_temp_c"]
        print(f"{trip + ('*' if trip in RESERVED else ''):6s} "
              f"{f'{temp.iloc[0]:.0f} -> {temp.iloc[-1]:.0f} (max {temp.max():.0f})':>18s} "
              f"{f'{ambient.min():.1f} to {ambient.max():.1f}':>13s} {rmse_a:25.2f} "
              f"{rmse_h:19.2f} {f'{end_a:+.1f} / {end_h:+.1f}':>19s}")
    if set(trips) & set(RESERVED):
        print("* reserved trip: reported only")


if __name__ == "__main__":
    main()
