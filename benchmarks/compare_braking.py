"""The library's braking against the truth simulator's, with the truth's own bus.

    python -m benchmarks.compare_braking [--cache DIR] [--days N] [--decel 0.8] [--one-efficiency]
    python -m benchmarks.compare_braking --smoke   # CI: one control day, 4 h

On control days (nothing hidden) of the truth bench: the battery energy of the truth
simulator's run, by operating mode, against the library's diagnosis baseline driven through
the day's log with the truth's own base parameters (mass, rolling resistance, drag, auxiliary
load, pack, motor powers). Where they differ with the same bus is where the two models' forms
differ: what no calibration of the bus-to-bus parameters can take up, and what every control
day's residual shows. ``--decel`` runs the library a second time with the motor's braking
deceleration limited (series blending, ``regen_cutoff.max_decel_mps2``), the truth's own
form of brake blending, and ``--one-efficiency`` a third time with the truth's drivetrain too (one
motor + inverter efficiency, the truth's, in place of the loss map). Both models' energies are
integrals over each second (the library's steps averaged, the truth's energy counters
differenced): power sampled once a second would count an accelerating second at its start,
its lowest speed, and a braking second at its highest. Prints a table; no assertions.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks.out_of_family import BASELINE_WITHOUT, CELLS_PARALLEL, DAYS_CACHE, truth_day
from benchmarks.truth import cases as truth_cases
from ebus_env.config import load_bus

ROOT = Path(__file__).resolve().parent.parent

def library_values(base: dict, decel_mps2: float | None) -> dict:
    """The library's parameters for the truth's bus (its own names and units)."""
    values = {
        "vehicle_body.curb_mass_kg": base["curb_mass_kg"],
        "vehicle_body.rotational_mass_factor": 1.0 + base["rotating_mass_kg"]
        / base["curb_mass_kg"],
        # the truth's rolling coefficient grows with speed, c_rr0 (1 + k_v v); at 8 m/s, a city
        # bus's mean speed
        "rolling_resistance.rolling_coef": base["c_rr0"] * (1.0 + base["c_rr_speed_per_mps"] * 8.0),
        "aero_drag.drag_coef": base["cda_m2"] / 7.5,  # the 12 m bus's frontal area
        "auxiliaries.base_power_w": base["aux_base_w"],
        "rint_battery.cells_series": base["cells_series"],
        "rint_battery.cell_capacity_ah": base["capacity_ah"] / CELLS_PARALLEL,
        # R_pack = connection factor 1.2 x series / parallel x R_cell
        "rint_battery.cell_resistance_mohm": (base["r0_ohm"] + base["r1_ohm"]) * 1e3
        / (1.2 * base["cells_series"] / CELLS_PARALLEL),
        "efficiency_map.regen_power_kw": base["regen_power_w"] / 1e3,
        "efficiency_map.peak_power_kw": base["traction_power_w"] / 1e3,
    }
    if decel_mps2 is not None:
        values["regen_cutoff.max_decel_mps2"] = decel_mps2
    return values


def library_power_w(profile, base: dict, decel_mps2: float | None,
                    one_efficiency: bool = False) -> dict[str, np.ndarray]:
    """Battery power and motor power of the library's baseline bus, each second's mean, with
    the truth's bus (and, ``one_efficiency``, the truth's drivetrain form)."""
    bus = load_bus("12m", without=list(BASELINE_WITHOUT))
    values = library_values(base, decel_mps2)
    if one_efficiency:  # P_dc = P_wheel / eta in traction, eta P_wheel in regeneration
        bus = bus.with_effect("constant_efficiency")
        values = {name.replace("efficiency_map.", "constant_efficiency."): value
                  for name, value in values.items()}
        values["constant_efficiency.motor_efficiency"] = 1.0
        values["constant_efficiency.gearbox_efficiency"] = base["drive_efficiency"]
    model = bus.build(profile.dt_s)
    bounds = np.array(model.bounds, float)
    for name, value in values.items():  # the truth's bus may lie outside the 12 m bus's ranges
        i = model.param_index(name)
        bounds[i] = (min(bounds[i][0], value), max(bounds[i][1], value))
    model.bounds = bounds
    run = model.simulate(profile, model.param_vector(model.carry_over(values)))
    per_s = int(round(1.0 / profile.dt_s))

    def mean_per_second(name: str) -> np.ndarray:
        power = run.trace(name)
        return power[: len(power) // per_s * per_s].reshape(-1, per_s).mean(axis=1)

    return {"battery": mean_per_second("battery_power_w"), "motor": mean_per_second("motor_power_w")}


def truth_power_w(trace, name: str) -> np.ndarray:
    """The truth's mean power over each second after a row [W], from its energy counter."""
    return np.diff(trace[f"e_{name}_j"].to_numpy())


def compare(case, folder: Path, decel_mps2: float | None, one_efficiency: bool) -> None:
    _, base, _, _, trace = truth_cases.day_trace(case)
    profile = truth_day("truthsim", case, folder)[0][0]
    runs = {"library": library_power_w(profile, base, None)}
    if decel_mps2 is not None:
        runs[f"a_regen {decel_mps2:g}"] = library_power_w(profile, base, decel_mps2)
    if one_efficiency:
        runs[f"+ eta {base['drive_efficiency']:.3f}"] = library_power_w(
            profile, base, decel_mps2, one_efficiency=True)
    truth_w = truth_power_w(trace, "battery")
    n = min(len(truth_w), *(len(r["battery"]) for r in runs.values()))
    truth_w = truth_w[:n]
    mode = truth_cases.modes(trace)[:n]
    print(f"\n{case.case_id}: {n / 3600:.1f} h, truth's blending limit "
          f"{base['regen_max_decel_mps2']:g} m/s^2, drivetrain efficiency "
          f"{base['drive_efficiency']:.3f} (the library's: its loss map)")
    print(f"  {'mode':14s} {'hours':>6s} {'truth kWh':>10s} "
          + " ".join(f"{name + ' kWh':>16s}" for name in runs))
    for k, name in enumerate(truth_cases.MODES):
        rows = mode == k
        if rows.any():
            print(f"  {name:14s} {rows.sum() / 3600:6.2f} {truth_w[rows].sum() / 3.6e6:10.1f} "
                  + " ".join(f"{r['battery'][:n][rows].sum() / 3.6e6:16.1f}"
                             for r in runs.values()))
    drive = truth_power_w(trace, "drive_dc")[:n]
    print(f"  {'braking energy returned to the DC bus':40s} truth {-drive.clip(max=0).sum() / 3.6e6:.1f}"
          " kWh; " + "; ".join(f"{name} {-r['motor'][:n].clip(max=0).sum() / 3.6e6:.1f} kWh"
                               for name, r in runs.items()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", type=Path, default=DAYS_CACHE)
    parser.add_argument("--days", type=int, default=3, help="control days to compare")
    parser.add_argument("--decel", type=float, default=None,
                        help="also run the library with this braking deceleration limit [m/s^2]")
    parser.add_argument("--one-efficiency", action="store_true",
                        help="also run it with the truth's drivetrain: one efficiency, no loss map")
    parser.add_argument("--smoke", action="store_true", help="one 4 h control day (CI)")
    args = parser.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    controls = [c for c in truth_cases.cases() if c.hidden is None][:args.days]
    if args.smoke:
        controls = [replace(controls[0], hours=4.0)]
    for case in controls:
        compare(case, args.cache, args.decel, args.one_efficiency)


if __name__ == "__main__":
    main()
