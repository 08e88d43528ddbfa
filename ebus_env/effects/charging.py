"""Charging: the CC/CV protocol and the charger (depot AC or opportunity DC, optionally pulsed)."""

from __future__ import annotations

import math

from ebus_env.effects.base import Param, effect


@effect("cccv_taper", slot="charge_limit", drivers=("soc_frac",), params=[
    Param("cv_soc_pct", 87.5, "%", (50.0, 99.9), "CC/CV cutoff SoC_cv",
          "Hasan et al. 2023, tuned parameter (87.5-90 %)"),
    Param("decay_per_pct", 0.23, "1/%", (0.01, 1.0), "CV decay factor beta",
          "Hasan et al. 2023, tuned parameter; sign: docs/physics.md §5.4"),
    Param("cc_c_rate", 3.0, "1/h", (0.1, 10.0), "Constant-current charge rate in C",
          "LFP 3C (paper)"),
])
def cccv_taper(soc_frac: float, capacity_ah: float, cv_soc_pct: float, decay_per_pct: float,
               cc_c_rate: float) -> tuple[float, float]:
    """Constant current I_cc = c_cc Q and the CV taper factor::

        taper = 1                                     SoC <= SoC_cv
        taper = exp(-beta (SoC - SoC_cv))             SoC >  SoC_cv   (SoC in %)

    The paper prints the exponent without its minus sign, which would make the current grow
    tenfold by 100 % SoC; the decaying form is continuous at the cutoff (docs/physics.md §5.4).
    I_cc taper is what the pack accepts; a charger rated below it delivers its rating.
    """
    excess_pct = 100.0 * soc_frac - cv_soc_pct
    taper = 1.0
    if excess_pct > 0.0:
        taper = math.exp(-decay_per_pct * excess_pct)
    return cc_c_rate * capacity_ah, taper


@effect("grid_charger", slot="charger", drivers=("charger_connected",),
        handles={"charger_power_kw": "power_kw", "charger_efficiency": "efficiency",
                 "charge_pulse_duty": "pulse_duty"}, params=[
    Param("power_kw", 450.0, "kW", (1.0, 1000.0),
          "Rated DC power P_rated, used when the profile gives no charger rating",
          "Hasan et al. 2023: 450 / 290 kW opportunity, 18 kW depot; tuned parameter"),
    Param("efficiency", 0.95, "1", (0.8, 1.0), "Charger efficiency grid -> DC, eta_ch",
          "docs/physics.md §6.1: 0.93-0.96"),
    Param("delivered_frac", 1.0, "1", (0.5, 1.1),
          "DC power the charger delivers at its rating over the rating stated, k_del",
          "docs/physics.md §6.1: 1 for a DC rating, about eta_ch for a grid-side one"),
    Param("pulse_period_s", 10.0, "s", (0.2, 600.0), "Pulsed charging: period t_on + t_off"),
    Param("pulse_duty", 1.0, "1", (0.05, 1.0),
          "Pulsed charging: duty cycle d = t_on / period (1: continuous charging)"),
    Param("pulse_low_frac", 0.0, "1", (0.0, 1.0),
          "Pulsed charging: current during t_off as a fraction of the pulse current"),
])
def grid_charger(charger_connected: float, charger_rating_w: float, cc_current_a: float, cv_taper: float,
                 charge_current_max_a: float, ocv_v: float, resistance_ohm: float, motor_power_w: float,
                 dc_load_w: float, time_s: float, power_kw: float, efficiency: float,
                 delivered_frac: float, pulse_period_s: float, pulse_duty: float,
                 pulse_low_frac: float) -> tuple[float, float]:
    """DC power the charger delivers to the bus [W] and the grid power it draws [W].

    While connected, the charger feeds the bus loads and charges the pack with::

        I    = min(I_rated, I_cc taper, I_chg,max)   (docs/physics.md §6.1)
        I_rated: the current with which the pack takes P_rated - P_loads
        I    <- I * (1 if pulse on else low_frac)   pulse on for the first d of each period
        P_dc = min(I (OCV + R I) + P_loads, P_rated),  P_grid = P_dc / eta_ch
        P_rated = k_del (the profile's rating, else power_kw)

    Two separate limits: the charger's rating, and what the pack accepts, its CC/CV current
    I_cc taper (docs/physics.md §5.4) and its own limits I_chg,max (C-rate, SoC ceiling, cell
    voltage window). A depot charger rated below the pack's acceptance delivers its rating up
    to high SoC. When the loads exceed the rating, the pack supplies the difference. A
    rating stated on the grid side, or a charger that loses some in its cable or derates,
    delivers a share k_del < 1 of it.
    """
    if charger_connected < 0.5:
        return 0.0, 0.0
    rating_w = power_kw * 1e3
    if not math.isnan(charger_rating_w):
        rating_w = charger_rating_w
    rating_w *= delivered_frac
    loads_w = motor_power_w + dc_load_w
    spare_w = rating_w - loads_w
    current_a = 0.0
    if spare_w > 0.0:
        rated_a = 2.0 * spare_w / (ocv_v + math.sqrt(ocv_v * ocv_v + 4.0 * resistance_ohm * spare_w))
        current_a = min(rated_a, cc_current_a * cv_taper, charge_current_max_a)
        if pulse_duty < 1.0:
            phase_s = time_s - pulse_period_s * math.floor(time_s * (1.0 / pulse_period_s))
            if phase_s >= pulse_duty * pulse_period_s:
                current_a *= pulse_low_frac
    dc_w = min(current_a * (ocv_v + resistance_ohm * current_a) + loads_w, rating_w)
    dc_w = max(dc_w, 0.0)
    return dc_w, dc_w / efficiency
