"""A nominal 12 m battery-electric city bus and the per-day random draw of its base parameters.

Road load is written as a coast-down polynomial, ``F = A + B v + C v^2`` (the form of SAE J2263
/ EPA coast-down target coefficients):

* ``A = c_rr0 m g`` and ``B = c_rr0 m g k_v`` from a speed-dependent rolling coefficient
  ``c_rr(v) = c_rr0 (1 + k_v v)``; for radial truck and bus tyres Wong (Theory of Ground
  Vehicles, 4th ed., 2008, Sec. 1.2.3) gives ``f_r = 0.0041 + 0.000041 V`` (V in km/h), i.e.
  ``k_v = 0.01 per km/h = 0.036 per m/s``. ``c_rr0`` 0.0065 is an EU tyre-label class C/D
  value for C3 (bus and truck) tyres (Regulation (EU) 2020/740, Annex I, Part A: class C
  5.1-6.0, class D 6.1-7.0 N/kN), city-bus tyres with deep tread on city streets.
* ``C = rho c_d A_f / 2`` with ``c_d A_f`` = 5.0 m^2: the 2.55 m width limit of Directive
  96/53/EC (Annex I, 1.2) times ~3.0 m height less the rounded corners gives ~7 m^2, and
  ``c_d`` ~0.7 for a box-shaped city bus (Hucho, Aerodynamics of Road Vehicles, 4th ed., 1998,
  Ch. 9: buses 0.5-0.8).

Mass: curb mass 13,000 kg, in the 12.5-14.5 t curb weights that the Altoona bus test reports
(Larson Transportation Institute, Penn State) list for 40-ft battery-electric buses.
Rotating inertia enters as an equivalent mass ``m_rot = (6 J_wheel + J_motor i^2) / r^2`` with
six 22.5" wheels (J ~10 kg m^2 each), a motor of J 0.6 kg m^2, ratio i 12 and r 0.48 m,
about 670 kg (5 % of the curb mass).

Drivetrain: one fixed DC-to-wheel efficiency for traction and regeneration (0.86 nominal: motor
0.93 x inverter 0.97 x axle 0.955), traction power 200 kW and force 24 kN at the wheel,
regenerative power 150 kW at the wheel. Brake blending gives the motor at most 0.8 m/s^2 of
deceleration (the range of e-bus "retarder" regeneration on pedal release, 0.5-1 m/s^2, as
in UITP/ZeEUS operator reports); the pneumatic friction brakes add the rest.

Battery packs are built from the cell OCV tables in ``sim.py``: 250 kWh LFP (opportunity
charging) or 200 kWh NMC, about 650 V, charged up to the cells' data-sheet charge voltage
(3.65 V LFP, 4.20 V NMC) at 2 C (LFP) or 1.5 C (NMC). Pack resistance: ohmic ``R0`` plus one RC pair
(``R1``, ``tau1``), 10-s DC resistance ``R0 + R1`` about 0.1 ohm (LFP) and 0.11 ohm (NMC).

Voltage window per cell, which the BMS holds (``sim.py``):

* LFP 2.5-3.65 V, and 2.0 V at or below 0 degC: the charge voltage and discharge end
  voltages of the Lishen LP54173207 202 Ah LFP traction cell (product specification, Rev. 0,
  2020-03-09, Table 1: charge voltage 3.65 V; discharge end voltage 2.5 V above 0 degC,
  2.0 V at or below 0 degC), a prismatic cell of the size used in bus packs;
* NMC 2.8-4.2 V: the Samsung INR-21700-40T data sheet (whose OCV the truth uses) gives a
  charge voltage of 4.20 V and a discharge cut-off of 2.5 V; a pack BMS stops above the
  cell's cut-off, at the 2.7-2.8 V that automotive NMC/NCA cells list as their minimum (the
  cell table of foxBMS's battery-system design sheet, Fraunhofer IISB: 2.70-2.80 V).
"""

from __future__ import annotations

import numpy as np

GRAVITY_MPS2 = 9.81
AIR_DENSITY_KG_PER_M3 = 1.2
CHEMISTRIES = ("LFP", "NMC")

NOMINAL_12M = {
    "curb_mass_kg": 13000.0,
    "rotating_mass_kg": 670.0,
    "c_rr0": 0.0065,
    "c_rr_speed_per_mps": 0.036,
    "cda_m2": 5.0,
    "drive_efficiency": 0.86,
    "traction_power_w": 200e3,
    "traction_force_n": 24e3,
    "regen_power_w": 150e3,
    "regen_max_decel_mps2": 0.8,  # brake blending: deceleration the motor alone gives
    "regen_full_speed_mps": 3.0,  # regen fades linearly to zero between this speed ...
    "regen_zero_speed_mps": 1.0,  # ... and this one (friction brakes take over)
    "aux_base_w": 4500.0,
    "charger_efficiency": 0.94,
}

PACKS = {
    # series cells, capacity [Ah], R0 [ohm], R1 [ohm], tau1 [s], max charge C-rate, the cells'
    # voltage window [V] (and the LFP floor at or below 0 degC)
    "LFP": {"cells_series": 200, "capacity_ah": 385.0, "r0_ohm": 0.060, "r1_ohm": 0.040,
            "tau1_s": 40.0, "max_charge_c": 2.0, "cell_v_max": 3.65, "cell_v_min": 2.5,
            "cell_v_min_cold": 2.0,
            "coulombic_efficiency": 0.998},
    "NMC": {"cells_series": 176, "capacity_ah": 310.0, "r0_ohm": 0.065, "r1_ohm": 0.045,
            "tau1_s": 30.0, "max_charge_c": 1.5, "cell_v_max": 4.20, "cell_v_min": 2.8,
            "coulombic_efficiency": 0.997},
}


def nominal(chemistry: str = "LFP") -> dict[str, float]:
    """The nominal bus with the pack of ``chemistry``."""
    if chemistry not in PACKS:
        raise ValueError(f"chemistry {chemistry!r} is not one of {CHEMISTRIES}")
    return {**NOMINAL_12M, **PACKS[chemistry], "chemistry": chemistry}


def draw_base(rng: np.random.Generator, chemistry: str) -> dict[str, float]:
    """Base parameters of one day's bus, drawn uniformly over the spreads of a real fleet:
    curb mass +-15 %, c_rr0 +-30 %, c_d A +-20 %, drivetrain efficiency +-5 points, base
    auxiliaries 2-9 kW, capacity +-10 %, resistances +-50 % (R0 and R1 together)."""
    base = nominal(chemistry)
    base["curb_mass_kg"] *= rng.uniform(0.85, 1.15)
    base["c_rr0"] *= rng.uniform(0.7, 1.3)
    base["cda_m2"] *= rng.uniform(0.8, 1.2)
    base["drive_efficiency"] += rng.uniform(-0.05, 0.05)
    base["aux_base_w"] = rng.uniform(2000.0, 9000.0)
    base["capacity_ah"] *= rng.uniform(0.9, 1.1)
    r_scale = rng.uniform(0.5, 1.5)
    base["r0_ohm"] *= r_scale
    base["r1_ohm"] *= r_scale
    return base
