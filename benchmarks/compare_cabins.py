"""The library's cabin against the truth sources' cabins on the truth bench's HVAC days.

    python -m benchmarks.compare_cabins [--cache DIR] [--source fastsim] [--cop]
    python -m benchmarks.compare_cabins --smoke   # CI: the bench's 4 h smoke days

Per HVAC day: the HVAC energy the truth logged, and the energy of the library's cabin
(``cabin_hvac`` at its configured values, added to the diagnosis's baseline bus, driven
through the day's log) at the truth's UA in the library's terms (the library's envelope UA that,
with its own fresh air and door air, loses the heat the truth's cabin loses over the day; "-"
where that lies below the library's range) and at the lowest UA of its range. Where
the library's cabin at its lowest UA still draws more than the truth's, the diagnosis can
only answer "the shape fits, the strength is implausible": it is the cabin's other terms
(fans, fresh air, occupants' heat, the heat pump's or air conditioner's COP) that differ.
``--cop`` re-runs each FASTSim day for its HVAC's mean COP, thermal over electric energy.
Prints a table; no assertions.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from benchmarks.out_of_family import (
    BASELINE_WITHOUT,
    DAYS_CACHE,
    SOURCES,
    truth_cases,
    truth_day,
    truth_module,
)
from ebus_env.config import load_bus

ROOT = Path(__file__).resolve().parent.parent

UA = "cabin_hvac.ua_w_per_k"
HVAC_DAYS = ("cabin_heating", "cabin_cooling")


def cabin_kwh(model, profiles, values: dict) -> float:
    """The cabin's electric energy over the profiles at parameter ``values`` [kWh]."""
    params = model.param_vector(model.carry_over(values))
    return sum(model.simulate(p, params).summary()["breakdown_kwh"]["cabin_hvac"]
               for p in profiles)


def fastsim_cop(case) -> float:
    """Thermal over electric energy of the FASTSim day's HVAC (the day re-run)."""
    from benchmarks.truth import fastsim_source

    _, _, clean = fastsim_source.generate_with_clean(case)
    return float(np.abs(clean["hvac_thermal_w"]).sum() / clean["hvac_elec_w"].sum())


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", type=Path, default=None,
                        help="folder of generated truth days (made when missing; by default "
                             "the bench's)")
    parser.add_argument("--source", choices=tuple(SOURCES), action="append")
    parser.add_argument("--cop", action="store_true", help="FASTSim's HVAC COP (slow)")
    parser.add_argument("--smoke", action="store_true",
                        help="the bench's smoke days (1 per effect, 4 h) only")
    args = parser.parse_args(argv)
    folder = args.cache or DAYS_CACHE
    folder.mkdir(parents=True, exist_ok=True)
    bus = load_bus("12m", without=list(BASELINE_WITHOUT)).with_effect("cabin_hvac")
    low = None
    print(f"{'day':34s} {'truth kWh':>10s} {'truth UA':>9s} {'library at UA':>14s} "
          f"{'at lowest UA':>13s}" + (f" {'COP':>5s}" if args.cop else ""))
    for source in args.source or tuple(SOURCES):
        module, why = truth_module(source)
        if module is None:
            print(why)
            continue
        for case in truth_cases(source, args.smoke):
            if case.hidden not in HVAC_DAYS:
                continue
            profiles, truth = truth_day(source, case, folder)
            model = bus.build(profiles[0].dt_s)
            low = model.bounds[model.param_index(UA)][0]
            ua = truth["strength"][UA]
            at_ua = f"{cabin_kwh(model, profiles, {UA: ua}):14.1f}" if ua >= low else f"{'-':>14s}"
            row = (f"{source + '/' + case.case_id:34s} {truth['summary']['effect_kwh']:10.1f} "
                   f"{ua:9.0f} {at_ua} {cabin_kwh(model, profiles, {UA: low}):13.1f}")
            if args.cop and source == "fastsim":
                row += f" {fastsim_cop(case):5.2f}"
            print(row, flush=True)
    if low is not None:
        print(f"(library: the 12 m bus's cabin at its configured values; lowest UA {low:g} W/K)")


if __name__ == "__main__":
    main()
