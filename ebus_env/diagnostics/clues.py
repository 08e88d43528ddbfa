"""Clues for an effect the library lacks: what the missing power moves with.

Each window gets physically meaningful features of what the bus did in it; their weighted
correlation with the missing power says what kind of effect to write: one that grows with
v^3 is aerodynamic, with m a v inertial, with grade v potential, with I^2 ohmic, with the cold
a heating load, with time of day a schedule, with idle time a standing load. Every signal of
the log the model does not use (a heater's power, a cabin or pack temperature) is a feature
too: ``log:heating_power_can_kw``.
"""

from __future__ import annotations

import numpy as np

from ebus_env.diagnostics.residual import channel

FEATURES = {
    "speed_cubed": "v^3 (aerodynamic: drag power grows with the cube of speed)",
    "inertial_power": "m a v while accelerating (mass or inertia: energy to speed up)",
    "grade_power": "m g grade v (potential energy: climbing)",
    "current_squared": "I^2 (ohmic: losses in the pack or cables)",
    "regen_high_soc": "braking power at SoC above 90 % (charge acceptance at high SoC)",
    "idle_share": "share of time standing, not charging (standing loads)",
    "charging_share": "share of time on a charger (charging losses, preconditioning)",
    "heating_degrees": "max(15 - ambient, 0) (cabin heating)",
    "cooling_degrees": "max(ambient - 22, 0) (cabin cooling)",
    "door_share": "share of time with doors open (door air exchange)",
    "time_of_day_h": "time of day (a schedule: lights, auxiliaries, passengers)",
    "passengers": "passengers on board (mass, heat)",
    "speed_mean": "mean speed",
}
MODEL_SIGNALS = {"soc_frac", "battery_current_a", "battery_voltage_v"}


def logged_signals(profiles) -> list[str]:
    """Measured signals of every profile that the model does not take as input."""
    names = set.intersection(*(set(p.measured) for p in profiles)) - MODEL_SIGNALS
    return sorted(n for n in names if all(np.isfinite(p.measured[n]).any() for p in profiles))


def window_features(results, windows) -> dict[str, np.ndarray]:
    """Mean of each feature over each window of recorded runs."""
    per_row = []
    for r in results:
        v = r.trace("speed_mps")
        mass = r.trace("effective_mass_kg")
        accel = r.trace("accel_mps2")
        grade = channel(r, "grade_frac")
        current = r.trace("battery_current_a")
        soc = r.trace("soc_frac")
        wheel = r.trace("wheel_force_n")
        plugged = channel(r, "charger_connected") > 0.5
        ambient = channel(r, "ambient_degc")
        per_row.append({
            "speed_cubed": v**3,
            "inertial_power": np.maximum(mass * accel * v, 0.0),
            "grade_power": r.trace("mass_kg") * 9.81 * grade * v,
            "current_squared": current**2,
            "regen_high_soc": np.where((wheel < 0) & (soc > 0.9), -wheel * v, 0.0),
            "idle_share": ((v < 0.1) & ~plugged).astype(float),
            "charging_share": plugged.astype(float),
            "heating_degrees": np.maximum(15.0 - ambient, 0.0),
            "cooling_degrees": np.maximum(ambient - 22.0, 0.0),
            "door_share": channel(r, "door_open"),
            "time_of_day_h": channel(r, "time_of_day_h"),
            "passengers": r.trace("passengers") if "passengers" in r.model.trace_names
            else np.zeros(len(v)),
            "speed_mean": v,
        })
    logged = logged_signals([r.profile for r in results])
    for r, features in zip(results, per_row, strict=True):
        for name in logged:
            features[f"log:{name}"] = r.profile.measured[name][:: r.record_every]
    out = {name: np.zeros(len(windows)) for name in per_row[0]}
    for w in range(len(windows)):
        k = windows.profile_index[w]
        rows = windows.rows(w, results[k].record_every)
        for name in out:
            out[name][w] = float(np.nanmean(per_row[k][name][rows]))
    return out


def correlations(features: dict[str, np.ndarray], missing_w: np.ndarray, weights: np.ndarray,
                 usable: np.ndarray) -> list[dict]:
    """Weighted Pearson correlation of the missing power with each feature, strongest first."""
    out = []
    for name, values in features.items():
        ok = usable & np.isfinite(values)
        if ok.sum() < 3:
            continue
        x, y = values[ok], missing_w[ok]
        w = weights[ok] / np.sum(weights[ok])
        xm, ym = np.sum(w * x), np.sum(w * y)
        sx = np.sqrt(np.sum(w * (x - xm) ** 2))
        sy = np.sqrt(np.sum(w * (y - ym) ** 2))
        if sx <= 1e-12 or sy <= 1e-12:
            continue
        r = float(np.sum(w * (x - xm) * (y - ym)) / (sx * sy))
        meaning = FEATURES.get(name) or f"the log's {name[4:]} (a signal the model does not use)"
        out.append({"feature": name, "meaning": meaning, "correlation": r})
    out.sort(key=lambda c: -abs(c["correlation"]))
    return out
