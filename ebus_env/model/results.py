"""Results of runs: figures with units, the energy breakdown, the trace, the SoC error.

Energy bookkeeping (all accumulated over the run, J in the kernel, kWh here)::

    battery (chemical) = inertia + sum(road loads) + friction brakes + drivetrain loss
                         + sum(DC loads) + battery ohmic + coulombic losses - charger DC energy

and ``consumed`` = battery + charger DC energy: everything the bus used, from its pack or
straight from a charger. kWh/km is consumed energy over distance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from ebus_env.units import J_PER_KWH

if TYPE_CHECKING:
    import pandas as pd

    from ebus_env.profile import Profile


class _Terms(Protocol):
    road_terms: list[str]
    load_terms: list[str]


class RunModel(Protocol):
    """What a result reads of the model that ran (a :class:`ebus_env.model.model.Model`)."""

    @property
    def state_names(self) -> list[str]: ...

    @property
    def accumulator_names(self) -> list[str]: ...

    @property
    def trace_names(self) -> list[str]: ...

    @property
    def layout(self) -> _Terms: ...


def _state(model: RunModel, vector: np.ndarray, name: str) -> float:
    return float(vector[model.state_names.index(name)])


def battery_energy_j(model: RunModel, acc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Energy out of the battery's terminals and out of its chemical store [J], from
    accumulators (one row per bus): terminal = motor + DC loads - charger;
    chemical = terminal - shortfall + ohmic + coulombic losses."""
    acc = np.atleast_2d(acc)
    col = {n: acc[:, i] for i, n in enumerate(model.accumulator_names)}
    terminal = col["motor"] + sum((col[t] for t in model.layout.load_terms), 0.0) - col["charger"]
    chemical = (terminal - col["battery_shortfall"] + col["battery_ohmic_loss"]
                + col["coulombic_loss"])
    return terminal, chemical


def summarize(model: RunModel, acc: np.ndarray, initial: np.ndarray, final: np.ndarray,
              profile: Profile) -> dict[str, Any]:
    """Figures of one run from its accumulators, its first/last state and its profile."""
    a = {k: float(v) for k, v in zip(model.accumulator_names, acc, strict=True)}
    kwh = {k: float(v) / J_PER_KWH for k, v in a.items()}
    road = model.layout.road_terms
    loads = model.layout.load_terms
    # derived exactly from the accumulated ones (see the step in ebus_env.model.template)
    # motor energy at the wheels = inertia + road loads + friction-brake loss
    wheel = kwh["inertia"] + sum(kwh[t] for t in road)
    kwh["friction_brake"] = (kwh["traction"] - kwh["regen_recovered"]) - wheel
    kwh["drivetrain_loss"] = kwh["motor"] - (kwh["traction"] - kwh["regen_recovered"])
    terminal, chemical = battery_energy_j(model, acc)
    kwh["battery_terminal"] = float(terminal[0]) / J_PER_KWH
    kwh["battery_chemical"] = float(chemical[0]) / J_PER_KWH
    kwh["charger_loss"] = kwh["grid"] - kwh["charger"]
    distance_km = _state(model, final, "distance_m") / 1000.0
    consumed = kwh["battery_chemical"] + kwh["charger"]
    breakdown = {"traction": kwh["traction"], "regen_recovered": kwh["regen_recovered"]}
    breakdown.update({t: kwh[t] for t in road})
    breakdown["inertia_net"] = kwh["inertia"]
    breakdown["friction_brake"] = kwh["friction_brake"]
    breakdown["drivetrain_loss"] = kwh["drivetrain_loss"]
    breakdown.update({t: kwh[t] for t in loads})
    breakdown["battery_ohmic_loss"] = kwh["battery_ohmic_loss"]
    breakdown["coulombic_loss"] = kwh["coulombic_loss"]
    breakdown["charging"] = kwh["charger"]
    breakdown["charger_loss"] = kwh["charger_loss"]
    summary = {
        "distance_km": distance_km,
        "duration_h": profile.duration_s / 3600.0,
        "battery_energy_kwh": kwh["battery_chemical"],
        "consumed_energy_kwh": consumed,
        "kwh_per_km": consumed / distance_km if distance_km > 0 else float("nan"),
        "soc_start_pct": 100.0 * _state(model, initial, "soc_frac"),
        "soc_end_pct": 100.0 * _state(model, final, "soc_frac"),
        "soc_min_pct": 100.0 * min(a["soc_min"], _state(model, final, "soc_frac")),
        "peak_grid_kw": max(a["peak_grid"], 0.0) / 1e3,
        "grid_energy_kwh": kwh["grid"],
        "charging_time_h": float(np.sum(profile.channel("charger_connected") > 0.5))
        * profile.dt_s / 3600.0,
        "max_behind_m": max(a["max_behind"], 0.0),
        # seconds in which the pack's limits (its cell voltage floor, an empty pack) cut the
        # traction the driver asked for, the bus falling behind (a flag summed times dt_s)
        "battery_limited_s": a["battery_limited"],
        "breakdown_kwh": breakdown,
    }
    if a["battery_shortfall"] > 0:
        summary["battery_shortfall_kwh"] = kwh["battery_shortfall"]
    if math.isfinite(a["stranded_at"]):  # the pack ran empty away from a charger
        summary["stranded_at_h"] = a["stranded_at"] / 3600.0
        summary["stranded_at_km"] = a["stranded_at_m"] / 1000.0
        summary["stranded_h"] = a["stranded"] / 3600.0
    return summary


@dataclass
class SimulationResult:
    """One bus through one profile."""

    model: RunModel
    profile: Profile
    params: np.ndarray
    initial_state: np.ndarray
    final_state: np.ndarray
    accumulators: np.ndarray
    trace_array: np.ndarray | None
    record_every: int
    wall_time_s: float

    def summary(self) -> dict[str, Any]:
        """Figures with units in their keys (``distance_km``, ``kwh_per_km``, ...), the energy
        breakdown by effect (``breakdown_kwh``) and, when the profile carries measured SoC, the
        SoC error (``soc_rmse_pct``, ``soc_max_abs_error_pct``, ``soc_end_error_pct``)."""
        s = summarize(self.model, self.accumulators, self.initial_state, self.final_state,
                      self.profile)
        s.update(self.soc_error())
        s["wall_time_s"] = self.wall_time_s
        return s

    def trace(self, name: str) -> np.ndarray:
        """One recorded signal (float64), every ``record_every`` steps."""
        if self.trace_array is None:
            raise ValueError("This run kept no trace; simulate with record=True.")
        return self.trace_array[:, self.model.trace_names.index(name)].astype(float)

    @property
    def time_s(self) -> np.ndarray:
        return self.profile.time_s[:: self.record_every]

    def soc_error_samples(self) -> tuple[np.ndarray, float] | None:
        """(model - measured SoC [%-points] where measured, measured range [%]) or None."""
        measured = self.profile.measured.get("soc_frac")
        if measured is None or self.trace_array is None:
            return None
        meas = measured[:: self.record_every]
        ok = np.isfinite(meas)
        if not ok.any():
            return None
        err = 100.0 * (self.trace("soc_frac")[ok] - meas[ok])
        return err, 100.0 * float(np.max(meas[ok]) - np.min(meas[ok]))

    def soc_error(self) -> dict[str, float]:
        """SoC error against the profile's measured SoC, in %-points (empty if none); the
        NRMSE divides the RMSE by the measured SoC range (the paper's eq. 1)."""
        samples = self.soc_error_samples()
        if samples is None:
            return {}
        err, span = samples
        measured = self.profile.measured["soc_frac"]
        last = np.flatnonzero(np.isfinite(measured))[-1]
        end_model = self.trace("soc_frac")[last // self.record_every]
        rmse = float(np.sqrt(np.mean(err**2)))
        return {
            "soc_rmse_pct": rmse,
            "soc_nrmse": rmse / span if span > 0 else float("nan"),
            "soc_max_abs_error_pct": float(np.max(np.abs(err))),
            "soc_end_error_pct": float(100.0 * (end_model - measured[last])),
        }

    def trace_frame(self) -> pd.DataFrame:
        """The trace as a pandas DataFrame: ``time_s``, every signal, measured signals."""
        import pandas as pd

        if self.trace_array is None:
            raise ValueError("This run kept no trace; simulate with record=True.")
        # "no limit" is inf inside the kernel; a written trace gives it as a missing value
        frame = pd.DataFrame(np.where(np.isinf(self.trace_array), np.nan, self.trace_array),
                             columns=self.model.trace_names)
        frame.insert(0, "time_s", self.time_s)
        frame["soc_pct"] = 100.0 * frame["soc_frac"]
        frame["speed_kmh"] = 3.6 * frame["speed_mps"]
        for name, values in self.profile.measured.items():
            frame[f"measured_{name}"] = values[:: self.record_every]
        return frame


@dataclass
class BatchResult:
    """N parameter sets through one profile."""

    model: RunModel
    profile: Profile
    params: np.ndarray
    initial_states: np.ndarray
    final_states: np.ndarray
    accumulators: np.ndarray
    recorded: list[str]
    records: np.ndarray
    record_every: int
    wall_time_s: float

    def __len__(self) -> int:
        return len(self.params)

    def summary(self, i: int) -> dict[str, Any]:
        return summarize(self.model, self.accumulators[i], self.initial_states[i],
                         self.final_states[i], self.profile)

    def final(self, state: str) -> np.ndarray:
        return self.final_states[:, self.model.state_names.index(state)]

    def record(self, name: str) -> np.ndarray:
        """(N, n_records) trace of a recorded signal."""
        return self.records[:, :, self.recorded.index(name)].astype(float)
