"""Plots of a run: speed, power, state of charge and cabin temperature over time."""

from __future__ import annotations

from pathlib import Path


def plot_trace(result, path: str | Path | None = None, max_points: int = 20000):
    """Four stacked panels of a simulated run (measured SoC overlaid when the log has it).

    Returns the matplotlib figure; saves it to ``path`` (PNG, SVG, PDF) when given.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t_h = result.time_s / 3600.0
    stride = max(1, len(t_h) // max_points)
    sl = slice(None, None, stride)
    names = result.model.trace_names
    fig, axes = plt.subplots(4, 1, figsize=(11, 9), sharex=True, constrained_layout=True)

    ax = axes[0]
    ax.plot(t_h[sl], 3.6 * result.trace("speed_ref_mps")[sl], lw=0.6, color="0.6",
            label="reference")
    ax.plot(t_h[sl], 3.6 * result.trace("speed_mps")[sl], lw=0.6, color="C0", label="bus")
    ax.set_ylabel("speed [km/h]")
    ax.legend(loc="upper right", fontsize=8)

    ax = axes[1]
    ax.plot(t_h[sl], result.trace("battery_power_w")[sl] / 1e3, lw=0.5, color="C3",
            label="battery (> 0 discharge)")
    ax.plot(t_h[sl], result.trace("grid_power_w")[sl] / 1e3, lw=0.7, color="C2", label="grid")
    ax.plot(t_h[sl], result.trace("dc_load_w")[sl] / 1e3, lw=0.7, color="C1",
            label="auxiliaries + HVAC")
    ax.set_ylabel("power [kW]")
    ax.legend(loc="upper right", fontsize=8)

    ax = axes[2]
    ax.plot(t_h[sl], 100 * result.trace("soc_frac")[sl], color="C0", label="model")
    measured = result.profile.measured.get("soc_frac")
    if measured is not None:
        m = measured[:: result.record_every]
        ax.plot(t_h[sl], 100 * m[sl], color="k", lw=0.8, ls="--", label="measured")
    ax.set_ylabel("SoC [%]")
    ax.legend(loc="upper right", fontsize=8)

    ax = axes[3]
    ax.plot(t_h[sl], result.trace("ambient_degc")[sl], color="0.5", label="ambient")
    if "cabin_temp_degc" in names:
        ax.plot(t_h[sl], result.trace("cabin_temp_degc")[sl], color="C4", label="cabin")
    ax.set_ylabel("temperature [degC]")
    ax.set_xlabel("time [h]")
    ax.legend(loc="upper right", fontsize=8)

    for ax in axes:
        ax.grid(alpha=0.3)
    title = f"{result.model.name} on {result.profile.name}"
    fig.suptitle(title)
    if path is not None:
        fig.savefig(path, dpi=110)
        plt.close(fig)
    return fig
