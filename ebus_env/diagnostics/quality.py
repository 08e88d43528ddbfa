"""Data problems, not model problems: deviations the log cannot have physically.

Windows with such deviations are excluded from the attribution, and the report says which and
why (the paper ignores them):

* SoC falls while the bus stands unplugged faster than any load it could have draws;
* SoC rises while the bus stands unplugged, or faster than the charger and pack allow;
* the battery current and the SoC disagree on the capacity (Ah per % SoC) between windows or
  against the pack (BMW trip B02: about 0.80 Ah per % against 0.62 elsewhere);
* speed above the vehicle's top speed, time gaps (from the loader's report).
"""

from __future__ import annotations

import numpy as np

from ebus_env.diagnostics.residual import channel

CAPACITY_TOLERANCE = 0.15


def data_issues(results, windows, model, params: np.ndarray, measured_w: np.ndarray,
                model_w: np.ndarray, loader_notes=()) -> tuple[list[dict], np.ndarray]:
    """(issues, mask of windows usable for attribution), from the recorded runs and each
    window's measured and model battery power [W]."""
    issues: list[dict] = []
    usable = np.ones(len(windows), bool)
    value = dict(zip(model.param_names, params, strict=True))
    peak_w = 1e3 * value.get("efficiency_map.peak_power_kw",
                             value.get("constant_efficiency.peak_power_kw", 200.0))
    charger_w = 1e3 * value.get("grid_charger.power_kw", np.inf)
    for w in range(len(windows)):
        r = results[windows.profile_index[w]]
        rows = windows.rows(w, r.record_every)
        standing = float(np.mean(r.trace("speed_mps")[rows] < 0.1))
        plugged = float(np.mean(channel(r, "charger_connected")[rows] > 0.5))
        measured, model = measured_w[w], model_w[w]
        where = {"window_start_h": round(float(windows.start_h[w]), 3),
                 "window_end_h": round(float(windows.start_h[w] + windows.duration_h[w]), 3)}
        if standing > 0.9 and plugged < 0.1:
            if measured > model + max(3 * abs(model), 0.2 * peak_w):
                issues.append({"issue": "SoC falls while standing unplugged faster than any "
                               "plausible load", "power_kw": round(measured / 1e3, 1), **where})
                usable[w] = False
            elif measured < -0.05 * peak_w:
                issues.append({"issue": "SoC rises while standing unplugged",
                               "power_kw": round(measured / 1e3, 1), **where})
                usable[w] = False
        limit = _charge_limit_w(r, rows, charger_w)
        if plugged > 0.5 and measured < -1.3 * limit:
            issues.append({"issue": "SoC rises faster than the charger and pack allow",
                           "power_kw": round(measured / 1e3, 1),
                           "limit_kw": round(limit / 1e3, 1), **where})
            usable[w] = False
    cap = _capacity_issues(results, windows, model, params)
    for item in cap:
        for w in item.pop("windows", []):
            usable[w] = False
        issues.append(item)
    for r in results:
        vmax = value.get("vehicle_body.max_speed_kmh")
        ref = 3.6 * r.profile.channels["speed_ref_mps"]
        if vmax is not None and np.any(ref > vmax + 1e-6):
            issues.append({"issue": f"speed above the vehicle's top speed {vmax:g} km/h",
                           "seconds": round(float(np.sum(ref > vmax)) * r.profile.dt_s, 1),
                           "max_kmh": round(float(ref.max()), 1)})
    for note in loader_notes:
        if "gap" in note:
            issues.append({"issue": "time gaps in the log", "detail": note})
    return issues, usable


def _charge_limit_w(r, rows: slice, charger_w: float) -> float:
    """Largest charging power into the pack the model allows in recorded ``rows`` [W]: the
    charger's rating (the log's, else the model's) and the pack's limit."""
    rating = channel(r, "charger_rating_w")[rows]
    rating = np.where(np.isfinite(rating) & (rating > 0), rating, charger_w)
    pack = r.trace("charge_power_max_w")[rows]
    return float(np.max(np.minimum(rating, pack)))


def _capacity_issues(results, windows, model, params) -> list[dict]:
    """Ah per % SoC from battery current against the SoC, per window and against the pack."""
    out = []
    for k, r in enumerate(results):
        p = r.profile
        current = p.measured.get("battery_current_a")
        soc = p.measured.get("soc_frac")
        if current is None or soc is None or not np.all(np.isfinite(current)):
            continue
        pack = float(r.trace("capacity_ah")[0]) / 100.0
        ratios, ids = [], []
        for w in windows.of(k):
            a, b = windows.start_step[w], windows.stop_step[w]
            drop_pct = 100.0 * (soc[a] - soc[b - 1])
            if abs(drop_pct) < 0.5:
                continue
            ah = float(np.sum(current[a:b])) * p.dt_s / 3600.0
            ratios.append(ah / drop_pct)
            ids.append(w)
        if not ratios:
            continue
        ratios = np.array(ratios)
        whole_drop = 100.0 * (soc[0] - soc[-1])
        whole = float(np.sum(current)) * p.dt_s / 3600.0 / whole_drop if abs(whole_drop) > 1 \
            else float(np.median(ratios))
        if abs(whole / pack - 1) > CAPACITY_TOLERANCE:
            out.append({"issue": "battery current and SoC disagree on the capacity",
                        "ah_per_pct": round(whole, 3), "pack_ah_per_pct": round(pack, 3),
                        "detail": f"{whole:.2f} Ah per % SoC in {p.name}, the pack has "
                                  f"{pack:.2f}: the SoC signal (or the current sensor) is off"})
        median = float(np.median(ratios))
        odd = [w for w, x in zip(ids, ratios, strict=True)
               if abs(x / median - 1) > CAPACITY_TOLERANCE]
        if odd and len(odd) < len(ids):
            out.append({"issue": "capacity inconsistent across the log",
                        "detail": f"{len(odd)} of {len(ids)} windows differ by more than "
                                  f"{100 * CAPACITY_TOLERANCE:.0f} % from the median "
                                  f"{median:.2f} Ah per % SoC",
                        "windows": odd})
    return out
