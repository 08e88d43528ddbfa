"""A/B speed of two source trees under the same load: this checkout against another (a git
ref or a folder), on the calls that ``bench_core`` and ``bench_env`` time. Prints a table;
no assertions.

    python -m benchmarks.ab_speed --against main             # 200 rounds, a few minutes
    python -m benchmarks.ab_speed --against main --smoke     # CI: same code paths, 2 rounds

Both trees run at once, each in a process of its own that sets its envs and model up once;
the rounds then ask them in turn for one short burst of each workload (A B, then B A), so that
both see the same machine at the same moment. A figure is the median over the rounds of the
ratio of the two bursts of one round, in wall time and in CPU time (``time.process_time``, which
a busy machine disturbs less; on a shared machine it is the better comparison). Timing two
trees in separate runs one after the other instead compares the machine's load as much as the
code.

A git ref is exported with ``git archive`` into a temporary folder (its compiled passes are
compiled there on the first run); both trees use this checkout's Python and packages.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULT = "ab_speed:"  # the prefix of a worker's answer (anything else on stdout is ignored)


def workloads(smoke: bool) -> dict[str, Callable[[], None]]:
    """Each burst as a function, set up once: a 13.5 h SORT 2 day of the compiled core
    (``bench_core``'s single bus) and decisions under random actions of each env of
    ``bench_env``, continuing their episodes (reset at the end) from burst to burst."""
    import gymnasium as gym
    import numpy as np

    import ebus_env  # noqa: F401  (registers the envs)
    from ebus_env.config import load_bus
    from ebus_env.cycles import service_day

    rng = np.random.default_rng(0)

    def env_burst(env: gym.Env | gym.vector.VectorEnv, decisions: int) -> Callable[[], None]:
        env.reset(seed=0)
        actions = rng.uniform(-1.0, 1.0, (101, *env.action_space.shape)).astype(np.float32)
        done = [0]

        def run() -> None:
            for _ in range(decisions):
                _, _, terminated, truncated, _ = env.step(actions[done[0] % len(actions)])
                done[0] += 1
                if np.ndim(terminated) == 0 and (terminated or truncated):
                    env.reset()  # a vector env resets its sub-envs itself
        return run

    def n(decisions: int) -> int:  # a burst's decisions: 20-50 ms of work each
        return min(decisions, 2) if smoke else decisions

    bursts = {
        "EBus-v0, gymnasium.make": env_burst(gym.make("EBus-v0"), n(200)),
        "EBus-v0, the env itself": env_burst(gym.make("EBus-v0").unwrapped, n(200)),
        "vector env, 1 sub-env": env_burst(gym.make_vec("EBus-v0", num_envs=1), n(200)),
        "vector env, 64 sub-envs": env_burst(gym.make_vec("EBus-v0", num_envs=64), n(4)),
        "vector env, 256 sub-envs": env_burst(gym.make_vec("EBus-v0", num_envs=256), n(1)),
        "decide_at_stops, 64 sub-envs": env_burst(
            gym.make_vec("EBus-v0", num_envs=64, decide_at_stops=True), n(4)),
        "EBusFleet-v0, 6 buses": env_burst(
            gym.make("EBusFleet-v0", config="fleet_sort2").unwrapped, n(40)),
    }
    bus = load_bus("12m")
    model = bus.build()
    model.compile()
    day = service_day("sort2", 1.0 if smoke else 13.5, model.dt_s, bus.service)

    def core_day() -> None:
        model.simulate(day, soc_start=0.95, record=False)

    bursts["core, one bus's SORT 2 day"] = core_day
    for run in bursts.values():
        run()  # compile or load the kernels, first touch of the arrays
    return bursts


def worker(smoke: bool) -> None:
    """Serve bursts: a workload's name on stdin -> ``RESULT wall_s cpu_s`` on stdout."""
    bursts = workloads(smoke)
    print(RESULT, *bursts, sep="\t", flush=True)
    for line in sys.stdin:
        run = bursts[line.rstrip("\n")]
        t0, c0 = time.perf_counter(), time.process_time()
        run()
        print(RESULT, time.perf_counter() - t0, time.process_time() - c0, sep="\t", flush=True)


class Tree:
    """A worker process running the source tree ``path`` (its ``ebus_env`` first on the path)."""

    def __init__(self, path: Path, smoke: bool) -> None:
        cmd = [sys.executable, str(Path(__file__).resolve()), "--worker"] + (["--smoke"] if smoke
                                                                              else [])
        self.proc = subprocess.Popen(cmd, cwd=path, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     text=True, env={**os.environ, "PYTHONPATH": str(path)})
        self.names = self._answer()

    def _answer(self) -> list[str]:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            if line.startswith(RESULT):
                return line.rstrip("\n").split("\t")[1:]
        raise RuntimeError(f"the worker in {self.proc.args} stopped (exit {self.proc.wait()}); "
                           "its error is above")

    def burst(self, name: str) -> tuple[float, float]:
        assert self.proc.stdin is not None
        self.proc.stdin.write(name + "\n")
        self.proc.stdin.flush()
        wall, cpu = self._answer()
        return float(wall), float(cpu)

    def close(self) -> None:
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        self.proc.wait()


def exported(ref: str, into: Path) -> Path:
    """The git ref ``ref`` of this checkout, exported into ``into``."""
    archive = subprocess.run(["git", "archive", ref], cwd=ROOT, capture_output=True, check=True)
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive.stdout, check=True)
    return into


def compare(other: Path, rounds: int, smoke: bool) -> None:
    trees = {"other": Tree(other, smoke), "this": Tree(ROOT, smoke)}
    try:
        names = [n for n in trees["this"].names if n in trees["other"].names]
        times: dict[str, dict[str, list[tuple[float, float]]]] = {
            n: {"other": [], "this": []} for n in names}
        loads = []
        for r in range(rounds):
            loads.append(os.getloadavg()[0])
            for name in names:
                for which in (("other", "this") if r % 2 == 0 else ("this", "other")):
                    times[name][which].append(trees[which].burst(name))
    finally:
        for tree in trees.values():
            tree.close()
    print(f"{ROOT} (this) against {other} (other): {rounds} rounds on {os.cpu_count()} CPUs, "
          f"1-min load average {min(loads):.1f}-{max(loads):.1f}")
    print(f"  {'burst':32s} {'other ms':>9s} {'this ms':>9s} {'this/other wall':>16s} "
          f"{'this/other CPU':>15s}")
    for name in names:
        a, b = times[name]["other"], times[name]["this"]
        wall = statistics.median(y[0] / x[0] for x, y in zip(a, b, strict=True))
        cpu = statistics.median(y[1] / x[1] for x, y in zip(a, b, strict=True))
        print(f"  {name:32s} {1e3 * statistics.median(x[0] for x in a):9.2f} "
              f"{1e3 * statistics.median(y[0] for y in b):9.2f} {wall:16.3f} {cpu:15.3f}")
    print("  (medians over the rounds; a ratio below 1: this tree is faster)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--against", default="main", help="a git ref or a folder (default main)")
    parser.add_argument("--rounds", type=int, default=200)
    parser.add_argument("--smoke", action="store_true", help="small bursts, 2 rounds (CI)")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.smoke)
        return
    rounds = 2 if args.smoke else args.rounds
    if Path(args.against).is_dir():
        compare(Path(args.against).resolve(), rounds, args.smoke)
        return
    with tempfile.TemporaryDirectory(prefix="ab_speed_") as folder:
        compare(exported(args.against, Path(folder)), rounds, args.smoke)


if __name__ == "__main__":
    main()
