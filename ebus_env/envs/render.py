"""Rendering of the environments: the day so far (speed, SoC, power, cabin temperature)."""

from __future__ import annotations

import numpy as np


def draw(history: list[np.ndarray], title: str, mode: str) -> np.ndarray | None:
    """``rgb_array``: an (H, W, 3) uint8 image of the day so far; ``human``: the same in a
    window (matplotlib), returning None. ``history``: a row per decision, (hours into
    service, mean speed [km/h], SoC [1], battery power [kW], grid power [kW], cabin
    temperature [degC], setpoint [degC])."""
    import matplotlib

    if mode == "rgb_array":
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    h = np.array(history) if history else np.zeros((0, 7))
    fig, axes = plt.subplots(4, 1, figsize=(6, 6), sharex=True, constrained_layout=True)
    t = h[:, 0]
    axes[0].plot(t, h[:, 1], color="C0")
    axes[0].set_ylabel("speed\n[km/h]")
    axes[1].plot(t, 100 * h[:, 2], color="C2")
    axes[1].set_ylabel("SoC [%]")
    axes[2].plot(t, h[:, 3], color="C3", label="battery")
    axes[2].plot(t, h[:, 4], color="C1", label="grid")
    axes[2].set_ylabel("power [kW]")
    axes[2].legend(loc="upper right", fontsize=7)
    axes[3].plot(t, h[:, 5], color="C4", label="cabin")
    axes[3].plot(t, h[:, 6], color="0.5", ls="--", label="setpoint")
    axes[3].set_ylabel("cabin\n[degC]")
    axes[3].legend(loc="upper right", fontsize=7)
    axes[3].set_xlabel("hours into service")
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[0].set_title(title)
    if mode == "human":
        plt.show(block=False)
        plt.pause(0.001)
        return None
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = fig.canvas
    assert isinstance(canvas, FigureCanvasAgg)  # the Agg backend, chosen above
    canvas.draw()
    image = np.asarray(canvas.buffer_rgba())[:, :, :3].copy()
    plt.close(fig)
    return image
