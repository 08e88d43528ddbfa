"""Figures of a diagnosis: SoC overlay, missing power with operating modes, attribution, error
ladder, missing power by mode. Each function returns a matplotlib figure."""

from __future__ import annotations

import numpy as np

from ebus_env.diagnostics.residual import MODES, operating_modes

MODE_COLOURS = ("#f4a582", "#d1e5f0", "#92c5de", "#e0e0e0", "#b2df8a", "#33a02c")
COLOUR_OF = {**dict(zip(MODES, MODE_COLOURS, strict=True)),
             # the power domain's modes (diagnostics.power.MODES), as their SoC-window kin
             "standing": MODE_COLOURS[3], "braking": MODE_COLOURS[2],
             "charging": MODE_COLOURS[4], "braking at high SoC": "#4393c3"}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _hours(runs) -> list[np.ndarray]:
    """Time axis of each run, profiles one after another [h]."""
    out, offset = [], 0.0
    for r in runs:
        out.append(offset + r.time_s / 3600.0)
        offset += r.profile.duration_s / 3600.0
    return out


def soc_overlay(d):
    """Measured SoC, the model's, and the model's with the verdict effect."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(10, 3.6), constrained_layout=True)
    for k, (r, t) in enumerate(zip(d.runs, _hours(d.runs), strict=True)):
        meas = r.profile.measured["soc_frac"][:: r.record_every]
        ax.plot(t, 100 * meas, color="k", lw=1.0, label="measured" if k == 0 else None)
        ax.plot(t, 100 * r.trace("soc_frac"), color="C0", lw=1.0,
                label="model" if k == 0 else None)
        if d.after_runs:
            ax.plot(t, 100 * d.after_runs[k].trace("soc_frac"), color="C2", lw=1.0, ls="--",
                    label=d.after_label if k == 0 else None)
    ax.set_xlabel("time [h]")
    ax.set_ylabel("SoC [%]")
    ax.set_title("State of charge: measured and simulated (free-running from the first sample)")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower left", fontsize=8)  # "best" scans every point of the lines
    return fig


def missing_power(d):
    """Missing battery power per window with its uncertainty, the part the verdict explains,
    and the operating modes as a colour strip."""
    plt = _plt()
    fig, (ax, strip) = plt.subplots(2, 1, figsize=(10, 4.2), sharex=True,
                                    gridspec_kw={"height_ratios": [6, 1]},
                                    constrained_layout=True)
    w = d.windows
    mid = w.start_h + w.duration_h / 2
    kw = d.missing_w / 1e3
    ax.errorbar(mid[d.usable], kw[d.usable], yerr=d.noise_w[d.usable] / 1e3, fmt="o", ms=3,
                color="C3", lw=0.8, label="measured - model")
    if (~d.usable).any():
        ax.plot(mid[~d.usable], kw[~d.usable], "x", color="0.5",
                label="excluded (start-up or data problem)")
    if d.verdict_w is not None:
        moved = " (calibrated parameters re-adjusted with it)" if d.calibration else ""
        ax.step(w.start_h, d.verdict_w / 1e3, where="post", color="C2",
                label=f"explained by {d.verdict}{moved}")
    ax.axhline(0, color="k", lw=0.6)
    ax.set_ylabel("missing power [kW]")
    ax.set_title(f"Battery power the model misses, per {d.window_s:g} s window ({d.basis})")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    from matplotlib.colors import ListedColormap

    for r, t in zip(d.anchored, _hours(d.anchored), strict=True):
        # one image row per log: far faster than a marker per sample
        strip.imshow(operating_modes(r)[None, :], aspect="auto", interpolation="nearest",
                     cmap=ListedColormap(MODE_COLOURS), vmin=-0.5, vmax=len(MODES) - 0.5,
                     extent=(t[0], t[-1], 0, 1))
    strip.set_xlim(0, sum(r.profile.duration_s for r in d.anchored) / 3600.0)
    strip.set_yticks([])
    strip.set_xlabel("time [h]")
    handles = [plt.Rectangle((0, 0), 1, 1, color=c) for c in MODE_COLOURS]
    strip.legend(handles, MODES, ncol=6, fontsize=7, loc="upper center",
                 bbox_to_anchor=(0.5, -0.9), frameon=False)
    return fig


def attribution(d):
    """Held-out share of the missing power each candidate explains."""
    plt = _plt()
    rows = [(r["effect"], r["explained_fraction"], r["effect"] == d.verdict) for r in d.ranking]
    rows += [(p["parameter"], p["explained_fraction"], False) for p in d.parameters[:5]]
    fig, ax = plt.subplots(figsize=(10, 0.35 * len(rows) + 1.2), constrained_layout=True)
    names = [r[0] for r in rows][::-1]
    values = [100 * max(r[1], -0.2) for r in rows][::-1]
    colours = ["C2" if r[2] else ("C0" if "." not in r[0] else "0.6") for r in rows][::-1]
    ax.barh(names, values, color=colours)
    ax.axvline(30, color="k", ls=":", lw=0.8)
    ax.set_xlabel("missing power explained on held-out windows [%]")
    ax.set_title("Candidates: missing effects (blue, verdict green) and parameters (grey)")
    ax.set_xlim(-20, 100)
    ax.grid(alpha=0.3, axis="x")
    return fig


def ladder(d):
    """NRMSE on calibration and held-out blocks: before/after, and each rung of the ladder."""
    plt = _plt()
    labels, cal, held = [], [], []
    if d.ladder:
        for r in d.ladder:
            labels.append(r.label)
            cal.append(r.calibration["nrmse"])
            held.append(r.held_out["nrmse"])
    else:
        labels.append("as given")
        cal.append(d.nrmse["before"]["calibration"])
        held.append(d.nrmse["before"]["held_out"])
    if "after" in d.nrmse and not (d.ladder and len(d.ladder) > 1):
        labels.append(d.after_label.removeprefix("model "))
        cal.append(d.nrmse["after"]["calibration"])
        held.append(d.nrmse["after"]["held_out"])
    x = np.arange(len(labels))
    fig, ax = plt.subplots(figsize=(max(5, 1.6 * len(labels) + 2), 3.4), constrained_layout=True)
    ax.bar(x - 0.2, cal, 0.4, label="calibration blocks", color="C0")
    ax.bar(x + 0.2, held, 0.4, label="held-out blocks", color="C1")
    ax.set_xticks(x, labels)
    ax.set_ylabel("NRMSE of SoC")
    ax.set_title("Error ladder")
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8)
    return fig


def modes(d):
    """Missing power by operating mode, with standard errors."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 3), constrained_layout=True)
    names = [m["mode"] for m in d.modes]
    kw = [m["missing_kw"] for m in d.modes]
    se = [m["stderr_kw"] for m in d.modes]
    ax.bar(names, kw, yerr=se, color=[COLOUR_OF.get(n, "#bababa") for n in names],
           edgecolor="k", lw=0.5)
    ax.axhline(0, color="k", lw=0.6)
    ax.set_ylabel("missing power [kW]")
    ax.set_title("Where the model fails: missing power by operating mode")
    ax.tick_params(axis="x", labelsize=8)
    ax.grid(alpha=0.3, axis="y")
    return fig


FIGURES = {"soc": soc_overlay, "missing_power": missing_power, "attribution": attribution,
           "modes": modes, "ladder": ladder}
