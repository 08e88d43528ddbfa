"""The model's vocabulary: input channels, sinks, slots and handles.

An effect's function names what it reads by argument name; these tables say what those names
mean. Sinks sum the contributions of any number of effects; slots take exactly one
implementation, and each slot's call sites say which signals that implementation must return.
The order in which the compiled step evaluates them is fixed in :mod:`ebus_env.model.template`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Input:
    """A per-step input channel of the model (one column of the input array).

    ``default`` fills the channel when the profile does not give it; NaN means "not given",
    and the effect reading it falls back on one of its parameters.
    """

    name: str
    unit: str
    default: float
    description: str


INPUTS: dict[str, Input] = {
    c.name: c
    for c in (
        Input("speed_ref_mps", "m/s", math.nan, "Reference speed the driver tracks"),
        Input("accel_ref_mps2", "m/s^2", 0.0,
              "Reference acceleration, (v_ref[k+1] - v_ref[k]) / dt (derived from the profile)"),
        Input("grade_frac", "1", 0.0, "Road grade, rise over run (> 0 uphill)"),
        Input("ambient_degc", "degC", 20.0, "Ambient air temperature"),
        Input("passenger_count", "1", math.nan,
              "Passengers on board; NaN: the passengers slot uses its load parameter"),
        Input("charger_connected", "1", 0.0, "1 while plugged into a charger, else 0"),
        Input("charger_rating_w", "W", math.nan,
              "Rated DC power of the connected charger; NaN: the charger's power parameter"),
        Input("door_open", "1", 0.0, "1 while the doors are open (derived: standing, not charging)"),
        Input("solar_w_per_m2", "W/m^2", 0.0, "Global solar irradiance on the bus"),
        Input("logged_load_w", "W", 0.0,
              "A load the log measures and the model does not compute (> 0 draws from the DC "
              "bus): an HVAC or compressor submeter"),
        Input("time_of_day_h", "h", 0.0, "Local time of day (derived from the profile's start)"),
    )
}

ALWAYS = {"dt_s": "Time step [s]", "time_s": "Time since the start of the profile [s]"}
"""Names every effect function may read."""


@dataclass(frozen=True)
class Sink:
    """A signal that is the sum of the contributions of any number of effects."""

    name: str
    unit: str
    description: str
    base: str | None = None  # a signal the sum starts from (else 0)

    @property
    def suffix(self) -> str:
        """Unit suffix of the sink's name (``_n``, ``_w``, ``_kg``), reused for contributions."""
        return self.name[self.name.rindex("_"):]


SINKS: dict[str, Sink] = {
    s.name: s
    for s in (
        Sink("mass_kg", "kg", "Vehicle mass: curb mass plus contributions", base="curb_mass_kg"),
        Sink("road_force_n", "N", "Road-load forces resisting motion at the wheels"),
        Sink("cabin_heat_w", "W", "Extra heat flows into the cabin (beyond the cabin model)"),
        Sink("dc_load_w", "W", "Electrical loads on the DC bus besides the traction motor"),
    )
}


@dataclass(frozen=True)
class Slot:
    """A role that exactly one effect fills.

    ``calls`` maps each call site to the signals the implementation must return there (in this
    order, followed by any extra signals the effect declares). ``optional`` names the call
    sites an implementation may leave out (they require no signals; the step then has no such
    call). ``none`` gives the constant outputs of the pass-through implementation, or None
    when the slot cannot be empty.
    """

    name: str
    description: str
    calls: dict[str, tuple[str, ...]]
    default: str
    none: dict[str, float] | None = field(default=None)
    optional: tuple[str, ...] = ()


SLOTS: dict[str, Slot] = {
    s.name: s
    for s in (
        Slot("vehicle", "Body: curb mass, rotating-mass factor, top speed, brake limit",
             {"main": ("curb_mass_kg", "rotational_mass_factor", "max_speed_mps",
                       "max_brake_decel_mps2")}, default="vehicle_body"),
        Slot("passengers", "Number of passengers on board",
             {"main": ("passengers",)}, default="passenger_load", none={"passengers": 0.0}),
        Slot("aging", "Battery ageing: capacity and resistance factors",
             {"main": ("capacity_factor", "resistance_factor")}, default="static_rcd",
             none={"capacity_factor": 1.0, "resistance_factor": 1.0}),
        Slot("battery_thermal", "Battery pack temperature (and its heating by the step's losses)",
             {"main": ("battery_temp_degc",), "heat": ()}, default="managed_temperature",
             optional=("heat",)),
        Slot("battery", "Battery pack: open-circuit voltage, resistance, limits, state of charge",
             {"pack": ("capacity_ah",),
              "state": ("ocv_v", "resistance_ohm", "charge_current_max_a", "charge_power_max_w",
                        "discharge_power_max_w"),
              "update": ("battery_current_a", "battery_voltage_v", "soc_frac_next",
                         "battery_loss_w", "coulombic_loss_w", "battery_shortfall_w")},
             default="rint_battery"),
        Slot("charge_limit", "Charging protocol: constant current and the CV taper factor",
             {"main": ("cc_current_a", "cv_taper")}, default="cccv_taper",
             none={"cc_current_a": math.inf, "cv_taper": 1.0}),  # inf: no limit
        Slot("driver", "Driver: wheel force demanded to track the reference speed",
             {"main": ("wheel_force_demand_n",)}, default="pi_driver"),
        Slot("drivetrain", "Motor limits and electric power of gearbox + motor + inverter",
             {"limits": ("traction_force_max_n", "regen_force_max_n"),
              "power": ("motor_power_w",)}, default="efficiency_map"),
        Slot("regen", "Share of the braking force the motor may take (regenerative braking)",
             {"main": ("regen_share",)}, default="regen_cutoff", none={"regen_share": 1.0}),
        Slot("charger", "Charger: DC power delivered to the bus and grid power drawn",
             {"main": ("charger_power_w", "grid_power_w")}, default="grid_charger",
             none={"charger_power_w": 0.0, "grid_power_w": 0.0}),
    )
}


@dataclass(frozen=True)
class CoreState:
    """A state the template itself integrates (not owned by an effect)."""

    name: str
    unit: str
    description: str


CORE_STATES: dict[str, CoreState] = {
    s.name: s
    for s in (
        CoreState("speed_mps", "m/s", "Vehicle speed"),
        CoreState("distance_m", "m", "Distance travelled"),
        CoreState("distance_ref_m", "m", "Distance of the reference profile"),
    )
}


@dataclass(frozen=True)
class Handle:
    """A parameter that a controller outside the model sets or reads (an env's action): an
    effect offers it by declaring ``handles={"<handle>": "<its parameter>"}``, so the env needs
    no effect's name. ``provider`` is the built-in effect that offers it."""

    name: str
    unit: str
    description: str
    provider: str


HANDLES: dict[str, Handle] = {
    h.name: h
    for h in (
        Handle("cabin_setpoint_degc", "degC", "cabin setpoint", "cabin_hvac"),
        Handle("charger_power_kw", "kW", "rated DC power of the charger", "grid_charger"),
        Handle("charger_efficiency", "1", "charger efficiency, grid to DC", "grid_charger"),
        Handle("charge_pulse_duty", "1", "pulse duty cycle of the charger (1: continuous)",
               "grid_charger"),
    )
}
