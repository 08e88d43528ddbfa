"""What the diagnosis of a BMS log tests, as power the model would draw per bin:

* **library effects** the bus lacks (and a user's, named for the ladder), each at
  :data:`~ebus_env.diagnostics.candidates.GRID` strengths across its range
  (:func:`~ebus_env.diagnostics.candidates.effect_candidates`), driven along the log as the
  fitted bus is;
* **forms outside the library** (:func:`outside_forms`): an unknown constant load in one
  operating mode (standing, accelerating, cruising, braking, on a charger, braking at high
  SoC), a load in the minutes after the doors close (a compressor refilling the air), a load
  that switches on and off at stops (steps in the logged power the model does not make:
  :func:`switched_on`), and a resisting force while moving (a dragging brake, soft tyres:
  power = F v). They stand for
  what the library lacks, by where the power goes missing.

On several days of one bus each also comes **from a day on** (:func:`from_day`): zero before
that day, as a fault that starts then and stays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import median_filter

from ebus_env.diagnostics.power import (
    MODES,
    TRACE,
    Bins,
    anchored_runs,
    log_power,
    mode_masks,
)

AFTER_DOORS_S = 120.0  # how long a compressor refills the air after the doors close
SWITCH_W = 2e3
"""The least step in the pack's power, at a stop, of a load switching on or off: an air
compressor, a pump or a heater stage (4-8 kW for a bus's brake-air compressor), ten times the
spread the model leaves at a stop."""
EDGE_S = 3  # seconds of a stop left out at each end: launch and halt are timed to a second


@dataclass
class Form:
    """A shape of missing power: its signatures (K, n_bins) [W per unit strength] and
    what it stands for."""

    name: str
    kind: str  # "missing effect", "refinement", "outside"
    signatures_w: np.ndarray
    meaning: str = ""
    strengths: np.ndarray | None = None  # the strength parameter's value per signature
    strength_param: str | None = None
    effect: object = None
    since_day: int = 0  # the form acts from this day on (0: every day)


def bin_signatures(profiles, bins: Bins, base_runs: list[np.ndarray]):
    """``signatures_of`` for :func:`~ebus_env.diagnostics.candidates.effect_candidates` on a
    BMS log: the extra terminal power of each parameter row of a model with the effect over
    the fitted bus's, per bin."""
    at = TRACE.index("battery_power_w")
    base = bins.means([r[:, at] for r in base_runs])

    def signatures_of(model, rows):
        runs = anchored_runs(model, profiles, rows, ("battery_power_w",), bins.lag)
        return bins.means([r[:, :, 0] for r in runs]) - base[None, :]
    return signatures_of


def outside_forms(profiles, bins: Bins, base_runs: list[np.ndarray]) -> list[Form]:
    """Unknown loads by operating mode, after the doors close, and a resisting force."""
    out = []
    for j, mode in enumerate(MODES):
        share = bins.mode_share[:, j]
        if share.sum() * bins.seconds < 600.0:  # ten minutes at least
            continue
        # on a charger, a charger that gives less than the log's rating draws the same
        # (a rating stated on the grid side): the log cannot tell them apart
        also = " (or a charger short of its logged rating)" if mode == "charging" else ""
        out.append(Form(f"load while {mode}", "outside", 1e3 * share[None, :],
                        f"an unknown load of a kW while {mode}{also}"))
    doors, force, switched = [], [], []
    v_at, p_at = TRACE.index("speed_mps"), TRACE.index("battery_power_w")
    for p, run in zip(profiles, base_runs, strict=True):
        every = max(1, int(round(1.0 / p.dt_s)))
        n = len(run)
        plugged = p.channel("charger_connected")[::every][:n] > 0.5
        standing = mode_masks(run, plugged, p.channel("speed_ref_mps")[::every][:n])[:, 0] > 0
        switched.append(switched_on(log_power([p])[0][:n] - run[:, p_at], standing))
        door = p.channel("door_open")[::every][:n] > 0.5
        closed = np.flatnonzero(door[:-1] & ~door[1:]) + 1
        after = np.zeros(n)
        for c in closed:
            after[c:c + int(AFTER_DOORS_S)] = 1.0
        doors.append(after)
        force.append(run[:, v_at])
    if np.any([d.any() for d in doors]):
        out.append(Form("load after the doors close", "outside",
                        1e3 * bins.means(doors)[None, :],
                        f"an unknown load of a kW for {AFTER_DOORS_S:.0f} s after each door "
                        "closing (an air compressor)"))
    # a minute on, over several stops; a SoC-only log's power has no steps to show
    if sum(float(x.sum()) for x in switched) >= 60.0 and not bins.by_window:
        out.append(Form("load switching on and off while standing", "outside",
                        1e3 * bins.means([x.astype(float) for x in switched])[None, :],
                        "a load of a kW that switches on and off while the bus stands, seen "
                        "as steps in the pack's power that the model does not make (an air "
                        "compressor, a pump, a heater stage)"))
    out.append(Form("resisting force", "outside", 1e3 * bins.means(force)[None, :],
                    "an unknown force of a kN against the motion (a dragging brake, soft "
                    "tyres), power F v"))
    return out


def switched_on(missing_w: np.ndarray, still: np.ndarray) -> np.ndarray:
    """The seconds at a stop when a load the model lacks is on: within each stop (``still``,
    its first and last :data:`EDGE_S` seconds left out) whose missing power (3-s median)
    steps by :data:`SWITCH_W` or more, the seconds it stands half of :data:`SWITCH_W` or more
    above its lowest. The steps are read from the log itself, like the doors: a stop without one marks
    nothing, so noise, and a load that stays on, mark nothing."""
    on = np.zeros(len(missing_w), bool)
    edges = np.flatnonzero(np.diff(np.r_[0, still.astype(np.int8), 0]))
    for start, stop in zip(edges[::2] + EDGE_S, edges[1::2] - EDGE_S, strict=True):
        if stop - start < 6:
            continue
        smooth = median_filter(missing_w[start:stop], size=3, mode="nearest")
        if np.max(np.abs(smooth[2:] - smooth[:-2])) >= SWITCH_W:
            on[start:stop] = smooth - smooth.min() >= 0.5 * SWITCH_W
    return on


def from_day(form: Form, bins: Bins, day: int) -> Form:
    """``form`` acting only from ``day`` on."""
    on = (bins.day >= day).astype(float)
    return Form(form.name, form.kind, form.signatures_w * on[None, :], form.meaning,
                form.strengths, form.strength_param, form.effect, day)
