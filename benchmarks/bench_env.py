"""Environment speed (issue 5): decisions per second with random actions, 60 s decisions of
600 physics steps each, and PPO's training throughput on the native vector env. Prints a
table; no assertions.

    python -m benchmarks.bench_env            # full run
    python -m benchmarks.bench_env --smoke    # CI: same code paths, few steps
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import gymnasium as gym

import ebus_env  # noqa: F401


def single_rate(env, steps: int, seed: int) -> float:
    env.reset(seed=seed)
    env.action_space.seed(seed)
    actions = [env.action_space.sample() for _ in range(steps)]
    t0 = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, _ = env.step(a)
        if terminated or truncated:
            env.reset()
    return steps / (time.perf_counter() - t0)


def vector_rate(venv, steps: int, seed: int) -> float:
    """Decisions per second over all sub-envs (autoreset inside)."""
    venv.reset(seed=seed)
    venv.action_space.seed(seed)
    actions = [venv.action_space.sample() for _ in range(steps)]
    t0 = time.perf_counter()
    for a in actions:
        venv.step(a)
    return steps * venv.num_envs / (time.perf_counter() - t0)


def ppo_rate(num_envs: int, steps: int, threads: int) -> float:
    """PPO (stable-baselines3 defaults, n_steps 128) env steps per second of learn(), torch on
    ``threads`` threads."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import Logger
    from stable_baselines3.common.vec_env import VecMonitor

    from ebus_env.envs.sb3 import SB3VecEnv

    venv = VecMonitor(SB3VecEnv(num_envs=num_envs))
    model = PPO("MlpPolicy", venv, n_steps=128, batch_size=256, seed=0, device="cpu")
    model.set_logger(Logger(None, []))  # no output (and no SB3-<time> folder in /tmp)
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        t0 = time.perf_counter()
        model.learn(steps)
        return steps / (time.perf_counter() - t0)
    finally:
        torch.set_num_threads(before)


def median(rate, repeats: int) -> float:
    return statistics.median(rate(seed) for seed in range(repeats))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--smoke", action="store_true")
    args = parser.parse_args()
    smoke = args.smoke
    steps, repeats = (20, 1) if smoke else (3000, 3)
    print("Random actions, 60 s decisions (600 steps at 10 Hz); medians of "
          f"{repeats} runs")
    print(f"  {'env':55s} {'decisions/s':>12s}  target")
    for label, env in (("EBus-v0, gymnasium.make (checker and order wrappers)",
                        gym.make("EBus-v0")),
                       ("EBus-v0, the env itself (env.unwrapped)", gym.make("EBus-v0").unwrapped)):
        single_rate(env, 5, 0)  # compile or load the kernels
        rate = median(lambda s, env=env: single_rate(env, steps, s), repeats)
        print(f"  {label:55s} {rate:12,.0f}  >= 10,000")
    for n in (1, 16, 64, 256):
        venv = gym.make_vec("EBus-v0", num_envs=n)
        vector_rate(venv, 3, 0)
        n_steps = max(5, (steps * 4) // n) if not smoke else 3
        rate = median(lambda s, venv=venv, k=n_steps: vector_rate(venv, k, s), repeats)
        label = f"EBus-v0 native vector env, {n} sub-envs (make_vec)"
        print(f"  {label:55s} {rate:12,.0f}  {'>= 100,000' if n == 64 else ''}")
    # stop-to-stop decisions: shorter on SORT 2 (46 s on average), each sub-env its own length
    env = gym.make("EBus-v0", decide_at_stops=True).unwrapped
    single_rate(env, 3, 0)
    rate = median(lambda s: single_rate(env, steps, s), repeats)
    print(f"  {'EBus-v0 decide_at_stops, the env itself':55s} {rate:12,.0f}")
    venv = gym.make_vec("EBus-v0", num_envs=64, decide_at_stops=True)
    vector_rate(venv, 3, 0)
    rate = median(lambda s: vector_rate(venv, 3 if smoke else steps * 4 // 64, s), repeats)
    print(f"  {'EBus-v0 decide_at_stops, vector env, 64 sub-envs':55s} {rate:12,.0f}")
    env = gym.make("EBusFleet-v0", config="fleet_sort2").unwrapped
    single_rate(env, 3, 0)
    rate = median(lambda s: single_rate(env, max(steps // 5, 3), s), repeats)
    label = "EBusFleet-v0, 6 buses (fleet decisions; x6 bus-decisions)"
    print(f"  {label:55s} {rate:12,.0f}")
    n_ppo, n_envs = (256, 2) if smoke else (65_536, 64)
    # torch's default is a thread per core; for a 64x64 MLP the threads mostly wait
    for threads in sorted({1, os.cpu_count() or 1}):
        label = f"PPO learn(), SB3VecEnv with {n_envs} sub-envs, torch {threads} thread(s)"
        print(f"  {label:55s} {ppo_rate(n_envs, n_ppo, threads):12,.0f}  env steps/s")


if __name__ == "__main__":
    main()
