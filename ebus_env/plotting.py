"""Plots of a run: speed, power, state of charge and cabin temperature over time."""

from __future__ import annotations

from pathlib import Path

import numpy as np

DETAIL_H = 1.0 / 3.0
"""Speed and power of a run longer than ``OVERVIEW_FROM_H`` are drawn over its first 20 min:
at 10 Hz a whole service day of stops is a solid block at any figure width."""
OVERVIEW_FROM_H = 1.5


def plot_trace(result, path: str | Path | None = None, max_points: int = 20000,
               detail_h: float = DETAIL_H):
    """Four stacked panels of a simulated run (measured SoC overlaid when the log has it).

    A run longer than ``OVERVIEW_FROM_H`` shows speed and power over its first ``detail_h``
    (shaded on the panels below), and SoC and temperatures over the whole run. The vehicle is
    labelled by its config's name; the reference speed is drawn dashed over it.

    Returns the matplotlib figure; saves it to ``path`` (PNG, SVG, PDF) when given.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t_h = result.time_s / 3600.0
    names = result.model.trace_names
    vehicle = result.model.name or "vehicle"
    duration_h = float(t_h[-1]) if len(t_h) else 0.0
    detail = duration_h > OVERVIEW_FROM_H
    fig, axes = plt.subplots(4, 1, figsize=(11, 9), constrained_layout=True)
    axes[1].sharex(axes[0])
    axes[3].sharex(axes[2])
    if not detail:
        axes[2].sharex(axes[0])
    n_fast = int(np.searchsorted(t_h, detail_h, side="right")) if detail else len(t_h)
    fast = slice(0, n_fast, max(1, n_fast // max_points))  # speed and power
    slow = slice(None, None, max(1, len(t_h) // max_points))  # SoC and temperatures
    t_fast = 60.0 * t_h[fast] if detail else t_h[fast]

    ax = axes[0]
    ax.plot(t_fast, 3.6 * result.trace("speed_mps")[fast], lw=1.6, color="C0", label=vehicle)
    ax.plot(t_fast, 3.6 * result.trace("speed_ref_mps")[fast], lw=0.8, color="k", ls="--",
            label="reference")
    ax.set_ylabel("speed [km/h]")
    ax.legend(loc="upper right", fontsize=8)

    ax = axes[1]
    ax.plot(t_fast, result.trace("battery_power_w")[fast] / 1e3, lw=0.7, color="C3",
            label="battery (> 0 discharge)")
    ax.plot(t_fast, result.trace("grid_power_w")[fast] / 1e3, lw=0.9, color="C2", label="grid")
    ax.plot(t_fast, result.trace("dc_load_w")[fast] / 1e3, lw=0.9, color="C1",
            label="auxiliaries + HVAC")
    ax.set_ylabel("power [kW]")
    ax.legend(loc="upper right", fontsize=8)
    if detail:
        ax.set_xlabel(f"time [min] (the first {60 * detail_h:.0f} min of the run)")

    ax = axes[2]
    ax.plot(t_h[slow], 100 * result.trace("soc_frac")[slow], color="C0", label="model")
    measured = result.profile.measured.get("soc_frac")
    if measured is not None:
        m = measured[:: result.record_every]
        ax.plot(t_h[slow], 100 * m[slow], color="k", lw=0.8, ls="--", label="measured")
    ax.set_ylabel("SoC [%]")
    ax.legend(loc="upper right", fontsize=8)

    ax = axes[3]
    ax.plot(t_h[slow], result.trace("ambient_degc")[slow], color="0.5", label="ambient")
    if "cabin_temp_degc" in names:
        ax.plot(t_h[slow], result.trace("cabin_temp_degc")[slow], color="C4", label="cabin")
    ax.set_ylabel("temperature [degC]")
    ax.set_xlabel("time [h]")
    ax.legend(loc="upper right", fontsize=8)

    for ax in axes:
        ax.grid(alpha=0.3)
    if detail:
        for ax in axes[2:]:
            ax.axvspan(0.0, detail_h, color="C1", alpha=0.15, lw=0, label="speed and power above")
            ax.legend(loc="upper right", fontsize=8)
    fig.suptitle(f"{vehicle} on {result.profile.name}")
    if path is not None:
        fig.savefig(path, dpi=110)
        plt.close(fig)
    return fig
