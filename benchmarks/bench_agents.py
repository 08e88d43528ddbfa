"""ECO rules and the shipped PPO agent on held-out days (issue 6): the README's tables,
generated. Prints Markdown tables; no assertions.

    python -m benchmarks.bench_agents            # 8 days per case, 20 for PPO vs the rules
    python -m benchmarks.bench_agents --smoke    # CI: 2 short days
"""

from __future__ import annotations

import argparse
import time

from agents.evaluate import FEATURES, evaluate
from agents.ppo import load_policy
from agents.rules import RULES, rule

SHOWN = ("reward", "kwh_per_km", "battery_kwh", "grid_kwh", "peak_grid_kw", "hvac_kwh",
         "comfort_kh", "late_min")


def ppo_versus_rules(episodes: int, extra: dict) -> None:
    """The shipped agent and every rule on the same held-out days of its training env."""
    t0 = time.perf_counter()
    sheet = evaluate([rule(n) for n in RULES] + [load_policy("ppo:default")], "sort2_day",
                     episodes=episodes, **extra)
    print(f"\nPPO (ppo:default) and the rules on sort2_day, {episodes} held-out days, "
          "mean +- 95 % CI\n")
    print("| policy | " + " | ".join(SHOWN) + " |")
    print("|---|" + "---|" * len(SHOWN))
    for p in sheet.policies:
        print(f"| {p.name} | " + " | ".join(f"{p.mean(k):.4g} +- {p.ci95(k):.2g}" for k in SHOWN)
              + " |")
    for name, d in sheet.versus_best_rule().items():
        print(f"| {name} - {d['versus']} (paired) | "
              + " | ".join(f"{d[k][0]:+.4g} +- {d[k][1]:.2g}" for k in SHOWN) + " |")
    print(f"({time.perf_counter() - t0:.0f} s)")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--smoke", action="store_true")
    args = parser.parse_args()
    episodes, extra = (2, {"service_h": 1.0}) if args.smoke else (8, {})
    cases = [("sort2", "12m", -5.0), ("sort2", "12m", 15.0), ("sort2", "12m", 30.0),
             ("sort2", "18m", 15.0)]
    cases += [(cycle, bus, 15.0) for bus in ("12m", "18m")
              for cycle in ("manhattan", "sort1", "sort3", "wvu_suburban", "arterial")]
    print(f"ECO rules, {episodes} held-out days each (kWh/km; saving against the baseline)\n")
    print("| cycle | bus | daily mean | baseline km/h, kWh/km | ECO-driving | ECO-comfort | ECO-charging "
          "| all | ECO-driving share | peak grid kW, baseline -> ECO-charging |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for cycle, bus, ambient in cases:
        t0 = time.perf_counter()
        # the 18 m bus's 120 kWh pack on 290 kW: 6 min layovers do not refill it, 10 min do
        layover = {"layover_min": 10.0} if bus == "18m" else {}
        sheet = evaluate([rule(n) for n in RULES], "sort2_day", episodes=episodes, bus=bus,
                         cycle=cycle, ambient_mean_degc=ambient, **layover, **extra)
        s, p = sheet.savings(), sheet.by_name()
        cells = [f"{-s[f]['saving_pct']:+.1f} %" for f in (*FEATURES, "eco_all")]
        share = s["eco_driving"].get("share_of_saving_pct", float("nan"))
        empty = [f"{n} {100 * q.mean('depleted'):.0f} %" for n, q in p.items()
                 if q.mean("depleted") > 0]
        base = p["baseline"]
        speed_kmh = base.mean("distance_km") / sheet.service_h
        print(f"| {cycle} | {bus} | {ambient:g} degC | {speed_kmh:.1f}, "
              f"{base.mean('kwh_per_km'):.3f} | "
              f"{' | '.join(cells)} | {share:.0f} % | {base.mean('peak_grid_kw'):.0f} "
              f"-> {p['eco_charging'].mean('peak_grid_kw'):.0f} |"
              + (f" days with an empty battery: {', '.join(empty)}" if empty else "")
              + f"  ({time.perf_counter() - t0:.0f} s)")
    ppo_versus_rules(2 if args.smoke else 20, extra)


if __name__ == "__main__":
    main()
