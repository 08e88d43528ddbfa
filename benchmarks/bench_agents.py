"""ECO rules on held-out days (issue 6): the README's table of kWh/km savings and peak grid
power, generated. Prints a Markdown table; no assertions.

    python benchmarks/bench_agents.py            # 8 days per case
    python benchmarks/bench_agents.py --smoke    # CI: 2 short days
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from ebus_env.agents.evaluate import FEATURES, evaluate  # noqa: E402
from ebus_env.agents.rules import RULES, rule  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--smoke", action="store_true")
    args = parser.parse_args()
    episodes, extra = (2, {"service_h": 1.0}) if args.smoke else (8, {})
    cases = [("sort2_day", "12m", -5.0), ("sort2_day", "12m", 15.0), ("sort2_day", "12m", 30.0)]
    print(f"ECO rules, {episodes} held-out days each (kWh/km; saving against the baseline)\n")
    print("| env | bus | daily mean | baseline kWh/km | ECO-driving | ECO-comfort | ECO-charging "
          "| all | ECO-driving share | peak grid kW, baseline -> ECO-charging |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for env, bus, ambient in cases:
        t0 = time.perf_counter()
        sheet = evaluate([rule(n) for n in RULES], env, episodes=episodes, bus=bus,
                         ambient_mean_degc=ambient, **extra)
        s, p = sheet.savings(), sheet.by_name()
        cells = [f"{-s[f]['saving_pct']:+.1f} %" for f in (*FEATURES, "eco_all")]
        share = s["eco_driving"].get("share_of_saving_pct", float("nan"))
        print(f"| {env} | {bus} | {ambient:g} degC | {p['baseline'].mean('kwh_per_km'):.3f} | "
              f"{' | '.join(cells)} | {share:.0f} % | {p['baseline'].mean('peak_grid_kw'):.0f} "
              f"-> {p['eco_charging'].mean('peak_grid_kw'):.0f} |  ({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
