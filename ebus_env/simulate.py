"""Run a model over one or more profiles (segments of a log split at its gaps) and combine."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ebus_env.inputs import check

_ADDITIVE = ("distance_km", "duration_h", "battery_energy_kwh", "consumed_energy_kwh",
             "grid_energy_kwh", "charging_time_h", "wall_time_s", "battery_shortfall_kwh",
             "battery_limited_s", "stranded_h")


@dataclass
class Run:
    """Results of consecutive segments and their combined summary."""

    results: list
    summary: dict

    @property
    def label(self) -> str:
        name = self.results[0].profile.name
        return name if len(self.results) == 1 else f"{name} ({len(self.results)} segments)"

    def trace_frame(self):
        """Traces of all segments, one after the other, with a ``segment`` column; ``time_s``
        is the log's own time (a gap between segments stays a gap)."""
        import pandas as pd

        frames = []
        for i, result in enumerate(self.results):
            frame = result.trace_frame()
            frame["time_s"] += result.profile.start_s
            frame.insert(1, "segment", i)
            frames.append(frame)
        return pd.concat(frames, ignore_index=True)


def combine(summaries: list[dict], results: list) -> dict:
    """One summary for consecutive segments (sums, extremes, first/last SoC, pooled errors)."""
    if len(summaries) == 1:
        return summaries[0]
    out = dict(summaries[0])
    for key in _ADDITIVE:
        if any(key in s for s in summaries):
            out[key] = sum(s.get(key, 0.0) for s in summaries)
    out["breakdown_kwh"] = {k: sum(s["breakdown_kwh"][k] for s in summaries)
                            for k in summaries[0]["breakdown_kwh"]}
    out["kwh_per_km"] = out["consumed_energy_kwh"] / out["distance_km"] \
        if out["distance_km"] > 0 else float("nan")
    out["soc_end_pct"] = summaries[-1]["soc_end_pct"]
    out["soc_min_pct"] = min(s["soc_min_pct"] for s in summaries)
    out["peak_grid_kw"] = max(s["peak_grid_kw"] for s in summaries)
    out["max_behind_m"] = max(s["max_behind_m"] for s in summaries)
    stranded = [i for i, s in enumerate(summaries) if "stranded_at_h" in s]
    if stranded:  # where the first segment to strand did, in the log's time and distance
        i = stranded[0]
        out["stranded_at_h"] = summaries[i]["stranded_at_h"] + results[i].profile.start_s / 3600
        out["stranded_at_km"] = summaries[i]["stranded_at_km"] + sum(
            s["distance_km"] for s in summaries[:i])
    errors = [r.soc_error_samples() for r in results]
    errors = [e for e in errors if e is not None]
    if errors:
        err = np.concatenate([e[0] for e in errors])
        span = max(e[1] for e in errors)
        out["soc_rmse_pct"] = float(np.sqrt(np.mean(err**2)))
        out["soc_nrmse"] = out["soc_rmse_pct"] / span if span > 0 else float("nan")
        out["soc_max_abs_error_pct"] = float(np.max(np.abs(err)))
        out["soc_end_error_pct"] = summaries[-1].get("soc_end_error_pct", float("nan"))
    out["segments"] = len(summaries)
    return out


def run_profiles(model, profiles, params=None, soc_start=None, record=True) -> Run:
    """Simulate each profile in turn (each from its own measured SoC unless ``soc_start``, a
    fraction 0-1)."""
    if soc_start is not None:
        check("soc_start_pct", 100.0 * soc_start, "soc_start (as percent)")
    results = [model.simulate(p, params, soc_start if i == 0 else None, record=record)
               for i, p in enumerate(profiles)]
    return Run(results, combine([r.summary() for r in results], results))
