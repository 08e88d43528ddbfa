"""Fingerprints of what the package computes: a simulated day, the environments' rollouts, a
study day and a calibration, each reduced to one SHA-256.

``tests/fixtures/behaviour.json`` holds them, and ``test_behaviour.py`` recomputes them: a
refactor must leave every one unchanged. A change of physics changes them on purpose; then
regenerate the file and commit it with the change::

    python -m tests.behaviour --update

Values are hashed as float32 (about 7 significant digits): any change of behaviour shows,
while a last-bit difference of a libm function between two machines does not. A value that
lies at a float32 rounding edge can still flip on another machine's BLAS kernels (OpenBLAS
picks them by CPU), so the fixture also keeps each array's means over :data:`BLOCKS` equal
parts: where the hash differs but every mean agrees within :data:`RTOL` of the array's scale,
the difference is the machine's, not the code's (:func:`same_behaviour`).
"""

from __future__ import annotations

import argparse
import hashlib
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

FIXTURE = Path(__file__).parent / "fixtures" / "behaviour.json"
BLOCKS = 8
RTOL = 1e-6


def fingerprint(parts: dict) -> str:
    """SHA-256 of named arrays (and scalars), each cast to float32, in name order."""
    h = hashlib.sha256()
    for name in sorted(parts):
        value = np.asarray(parts[name])
        h.update(name.encode())
        h.update(str(value.shape).encode())
        h.update(np.ascontiguousarray(value, dtype=np.float32).tobytes())
    return h.hexdigest()


def block_means(parts: dict) -> dict[str, list[float]]:
    """Each array's means over :data:`BLOCKS` equal parts (fewer for a shorter array)."""
    out = {}
    for name in sorted(parts):
        flat = np.asarray(parts[name], float).ravel()
        chunks = np.array_split(flat, min(BLOCKS, max(flat.size, 1)))
        out[name] = [float(np.mean(c)) if c.size else 0.0 for c in chunks]
    return out


def record(parts: dict) -> dict:
    """What the fixture keeps of a case: its fingerprint and its block means."""
    return {"sha256": fingerprint(parts), "blocks": block_means(parts)}


def same_behaviour(parts: dict, committed: dict) -> tuple[bool, str]:
    """Whether ``parts`` compute what the ``committed`` record says: the same fingerprint, or
    the same arrays with every block mean within :data:`RTOL` of the array's largest (NaNs
    in the same places). Returns the answer and, where it is no, which arrays moved."""
    if fingerprint(parts) == committed["sha256"]:
        return True, ""
    now, then = block_means(parts), committed["blocks"]
    if sorted(now) != sorted(then):
        return False, f"other arrays: {sorted(set(now) ^ set(then))}"
    moved = []
    for name, before in then.items():
        a, b = np.asarray(now[name], float), np.asarray(before, float)
        if a.shape != b.shape or not np.array_equal(np.isnan(a), np.isnan(b)):
            moved.append(name)
            continue
        scale = float(np.nanmax(np.abs(b), initial=0.0))
        if np.nanmax(np.abs(a - b), initial=0.0) > RTOL * scale:
            moved.append(name)
    return not moved, f"moved: {', '.join(moved)}" if moved else ""


def simulate_day() -> dict:
    """A 12 m bus through one hour of SORT 2 laps with its layover charge: the whole trace."""
    from ebus_env import load_bus, service_day

    bus = load_bus("12m")
    result = bus.build().simulate(service_day("sort2", 1.0, 0.1, bus.service), soc_start=0.9)
    frame = result.trace_frame()
    return {name: frame[name].to_numpy(float) for name in frame.columns}


def simulate_log() -> dict:
    """The BMW i3 replaying a measured trip: the whole trace."""
    from ebus_env import load_bus, load_log, paths

    log = load_log(paths.data("measured", "bmw_i3_tum", "TripB16_1hz.csv"), columns="bmw_i3_tum")
    frame = load_bus("bmw_i3").build().simulate(log.profile).trace_frame()
    return {name: frame[name].to_numpy(float) for name in frame.columns}


def _rollout(env, actions) -> tuple[dict, dict]:
    """Observations, rewards and flags of ``actions`` from a seeded reset; the last info."""
    obs, info = env.reset(seed=7)
    out = {"obs": [obs], "reward": [], "done": []}
    for action in actions:
        obs, reward, terminated, truncated, info = env.step(action)
        out["obs"].append(obs)
        out["reward"].append(reward)
        out["done"].append(np.logical_or(terminated, truncated))
    return {k: np.array(v, float) for k, v in out.items()}, info


def _actions(space, n: int) -> list:
    space.seed(3)
    return [space.sample() for _ in range(n)]


def env_rollout() -> dict:
    """``EBus-v0``: 40 decisions of seeded random actions."""
    import gymnasium as gym

    import ebus_env  # noqa: F401  (registers the environments)

    env = gym.make("EBus-v0", config="sort2_day")
    return _rollout(env, _actions(env.action_space, 40))[0]


def vector_env_rollout() -> dict:
    """The native vector env: 5 sub-envs, 40 decisions, episodes that end and restart."""
    import gymnasium as gym

    import ebus_env  # noqa: F401

    env = gym.make_vec("EBus-v0", num_envs=5, service_h=0.3)
    return _rollout(env, _actions(env.action_space, 40))[0]


def fleet_env_rollout() -> dict:
    """``EBusFleet-v0``: six buses sharing two plugs, 60 decisions, with the site's load."""
    import gymnasium as gym

    import ebus_env  # noqa: F401

    env = gym.make("EBusFleet-v0", config="fleet_sort2")
    out, info = _rollout(env, _actions(env.action_space, 60))
    out["site_load_kw"] = info["site_load_kw"]
    return out


def study_day() -> dict:
    """The shipped example study: each strategy on the first infrastructure, day 0."""
    from ebus_env.study.runner import run_scenario
    from ebus_env.study.scenarios import scenarios
    from ebus_env.study.study_file import load_study

    spec = load_study("example")
    out = {}
    for scenario in scenarios(spec)[:3]:
        (row,) = run_scenario(spec, scenario, days=[0])
        for key, value in row.items():
            if isinstance(value, (int, float, np.ndarray)) and not isinstance(value, bool):
                out[f"{scenario.index}.{key}"] = value
    return out


def calibration() -> dict:
    """A short seeded iSOPT fit of the BMW i3 on a measured trip: values, cost, fit."""
    from ebus_env import load_bus, load_log, paths
    from ebus_env.calibration.calibrate import calibrate
    from ebus_env.calibration.isopt import ISOPTSettings

    log = load_log(paths.data("measured", "bmw_i3_tum", "TripB16_1hz.csv"), columns="bmw_i3_tum")
    result = calibrate(load_bus("bmw_i3").build(), [log.profile],
                       settings=ISOPTSettings(population=8, iterations=4), polish_starts=1)
    out = {f"value.{k}": v for k, v in result.values.items()}
    out["cost"] = result.cost
    out.update({f"fit.{k}": v for k, v in result.fit.items() if isinstance(v, float)})
    return out


CASES: dict[str, Callable[[], dict]] = {
    "simulate_day": simulate_day,
    "simulate_log": simulate_log,
    "env": env_rollout,
    "vector_env": vector_env_rollout,
    "fleet_env": fleet_env_rollout,
    "study_day": study_day,
    "calibration": calibration,
}


def compute(names=None) -> dict[str, dict]:
    return {name: record(CASES[name]()) for name in names or CASES}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--update", action="store_true", help=f"write {FIXTURE.name}")
    args = parser.parse_args(argv)
    now = compute()
    before = json.loads(FIXTURE.read_text()) if FIXTURE.exists() else {}
    for name, rec in now.items():
        same = rec["sha256"] == before.get(name, {}).get("sha256")
        print(f"{name:14s} {rec['sha256'][:16]}  {'same' if same else 'CHANGED'}")
    if args.update:
        FIXTURE.parent.mkdir(exist_ok=True)
        lines = ",\n".join(f"  {json.dumps(name)}: {json.dumps(rec)}" for name, rec in now.items())
        FIXTURE.write_text("{\n" + lines + "\n}\n")  # a case a line: a change shows by case
        print(f"wrote {FIXTURE}")


if __name__ == "__main__":
    main()
