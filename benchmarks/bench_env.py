"""Environment speed (issue 5): decisions per second of EBus-v0 with random actions, 60 s
decisions of 600 physics steps each. Prints a table; no assertions.

    python benchmarks/bench_env.py            # full run
    python benchmarks/bench_env.py --smoke    # CI: same code paths, few steps
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import gymnasium as gym

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import ebus_env  # noqa: E402, F401


def decisions_per_s(env, steps: int, seed: int) -> float:
    env.reset(seed=seed)
    env.action_space.seed(seed)
    actions = [env.action_space.sample() for _ in range(steps)]
    t0 = time.perf_counter()
    done = 0
    for a in actions:
        _, _, terminated, truncated, _ = env.step(a)
        done += 1
        if terminated or truncated:
            env.reset()
    return done / (time.perf_counter() - t0)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--smoke", action="store_true")
    args = parser.parse_args()
    steps, repeats = (50, 1) if args.smoke else (3000, 3)
    print("EBus-v0, random actions, 60 s decisions (600 steps at 10 Hz); target >= 10,000/s")
    for label, env in (("gymnasium.make (checker and order wrappers)", gym.make("EBus-v0")),
                       ("the env itself (env.unwrapped)", gym.make("EBus-v0").unwrapped)):
        decisions_per_s(env, 5, 0)  # compile or load the kernels
        rates = [decisions_per_s(env, steps, seed) for seed in range(repeats)]
        print(f"  {label:50s} {statistics.median(rates):10,.0f} decisions/s")


if __name__ == "__main__":
    main()
