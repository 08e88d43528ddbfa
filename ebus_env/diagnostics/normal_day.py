"""A normal day of the same bus as the reference of a diagnosis.

Two different models of a bus never agree to the watt: a calibrated model leaves some power
missing on a day with nothing wrong (a bus's brake blending or drivetrain losses differ from
the model's), and where it is missing is the same on the bus's next day. With a known-good
day of the same bus, the diagnosis

1. calibrates the model on the reference day first and keeps its bus-to-bus values (mass,
   rolling resistance, auxiliary base load, efficiency, capacity, resistance), free on the
   suspect day only within ``REFERENCE_SPAN`` of them, so that a day's effect cannot be taken
   up by a heavier or thirstier bus; and
2. measures the power the calibrated model misses on the reference day in each operating
   mode, ``g_m`` with covariance ``C``, and breaks the suspect day's missing power down
   beyond what that predicts for each of its windows::

       P_missing'(w) = P_missing(w) - s(w) . g        s(w): the window's share of each mode
       sigma'(w)^2   = sigma(w)^2 + s(w) C s(w)^T

   The mode table, the bins and the mode clue are then relative to the reference. The
   attribution keeps the missing power itself: what it gains from the reference is the
   bus-to-bus search near the reference's values, and taking the gap off there as well would
   take off part of the effect a day adds to the normal one (docs/diagnostics.md, "Against a
   normal day of the same bus").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ebus_env.diagnostics import residual
from ebus_env.diagnostics.ladder import Freedom, nuisance_ranges

REFERENCE_SPAN = 0.1
"""Bus-to-bus values on the suspect day: within this share of the reference day's (the
auxiliary base load within ``REFERENCE_AUX_SPAN_W``), inside their bounds."""
REFERENCE_AUX_SPAN_W = 1000.0
"""The auxiliary base load swings with what a driver switches on, not as a share of it."""


@dataclass
class Reference:
    """What a normal day of the bus says: its calibrated bus-to-bus values, and the power the
    model calibrated on it misses per operating mode (:data:`residual.MODES`)."""

    logs: list[str]
    values: dict[str, float]  # the bus-to-bus parameters, calibrated on the reference day
    gap_w: np.ndarray  # per mode; NaN where the reference day never was in the mode
    cov_w2: np.ndarray
    held_out_nrmse: float

    def freedom(self, model, freedom: Freedom | None = None) -> Freedom:
        """``freedom`` with each bus-to-bus parameter's range narrowed around the reference
        day's value (a user's own range or fixed value is kept)."""
        known = (freedom or Freedom()).on(model)
        ranges = dict(known.ranges)
        for name, value in self.values.items():
            if name in known.fixed or name in ranges:
                continue
            low, high = model.bounds[model.param_index(name)]
            span = REFERENCE_AUX_SPAN_W if name.endswith("base_power_w") \
                else REFERENCE_SPAN * abs(value)
            ranges[name] = (max(low, value - span), min(high, value + span))
        return Freedom(known.params, ranges, known.fixed, known.categorical_load)

    def overlay(self) -> dict:
        """The reference's values as a bus-config overlay (the suspect day starts there)."""
        params: dict[str, dict[str, float]] = {}
        for name, value in self.values.items():
            effect, param = name.split(".", 1)
            params.setdefault(effect, {})[param] = float(value)
        return {"params": params}

    def expected_w(self, share: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The missing power a normal day shows in windows with mode ``share`` (n, modes),
        and its standard error. A mode the reference never visited counts as no gap, with
        no uncertainty added: the suspect day's own breakdown shows it."""
        seen = np.isfinite(self.gap_w)
        s = share[:, seen]
        gap = s @ self.gap_w[seen]
        var = np.einsum("ij,jk,ik->i", s, self.cov_w2[np.ix_(seen, seen)], s)
        return gap, np.sqrt(np.maximum(var, 0.0))

    def to_json(self) -> dict:
        return {"logs": self.logs, "values": self.values,
                "held_out_nrmse": self.held_out_nrmse,
                "missing_by_mode": [
                    {"mode": m, "missing_kw": g / 1e3, "stderr_kw": float(np.sqrt(c)) / 1e3}
                    for m, g, c in zip(residual.MODES, self.gap_w, np.diag(self.cov_w2),
                                       strict=True) if np.isfinite(g)]}


def mode_shares(anchored, windows) -> np.ndarray:
    """(n_windows, modes) share of each window's time in each operating mode."""
    labels = [residual.operating_modes(r) for r in anchored]
    return residual.fractions(labels, windows, anchored[0].record_every, len(residual.MODES))


def measure_reference(model, profiles, rung, res) -> Reference:
    """The reference from its calibrated ``rung`` and the residual ``res`` of that calibration
    (``diagnose``'s residual stage run on the reference day)."""
    share = mode_shares(res.anchored, res.windows)
    u = res.usable
    gap, cov = residual.decompose(res.missing_w[u], res.noise_w[u], share[u], covariance=True)
    values = {name: float(rung.values[name]) for name in nuisance_ranges(model, profiles)
              if name in rung.values}
    return Reference([p.name for p in profiles], values, gap, cov,
                     float(rung.held_out["nrmse"]))
