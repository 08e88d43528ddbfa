"""The diagnosis's decision rules against the truth bench, in minutes instead of hours.

A diagnosis spends its time calibrating the bus and computing the candidates' signatures; the
decision (``attribution.attribute``: which candidate, if any, is named) takes seconds. This
script does the slow part once per bench day and caches it, then decides every day again
under settings of the attribution's rules (its module constants) and prints, for each
setting, the hidden library effects named right, the wrong verdicts and the control days
with a verdict::

    python -m benchmarks.attribution_rules                   # the shipped rules and VARIANTS
    python -m benchmarks.attribution_rules --set CONFIDENCE=0.9 --set MIN_EXPLAINED=0.2
    python -m benchmarks.attribution_rules --oracle          # each hidden effect's own power too
    python -m benchmarks.attribution_rules --frontier        # the rules loosened step by step
    python -m benchmarks.attribution_rules --per-effect 2 --controls 3   # the bench's first days
    python -m benchmarks.attribution_rules --smoke           # CI: three 4 h days

The days are the truth bench's (``bench_diagnose.py --out-of-family``), diagnosed as there:
calibrated, from the 12 m bus without ``BASELINE_WITHOUT``. A verdict whose strength the fit
puts beyond its parameter's bound ends "implausible", as in the diagnosis (decided once per
day and candidate, in the cached part). With ``--oracle`` the candidate ``replayed_load`` of
the day's oracle log (its hidden effect's own power, ``bench_diagnose.py --oracle``) is added:
a day is right when the library's effect or that perfect form is named, or the two tie.
"""

from __future__ import annotations

import argparse
import pickle
import tempfile
import time
from collections import Counter
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from benchmarks import out_of_family as bench
from benchmarks.out_of_family import ORACLE, named_right, truth_cases, truth_day
from ebus_env.diagnostics import attribution

ROOT = Path(__file__).resolve().parent.parent

CACHE = Path(tempfile.gettempdir()) / "ebus-attribution-rules"
VARIANTS = (
    {},
    {"CONFIDENCE": 0.9},
    {"NUISANCE_STEPS": 2.0},
    {"MIN_EXPLAINED": 0.15, "MIN_GAIN": 0.03},
    {"NUISANCE_STEPS": 3.0, "MIN_EXPLAINED": 0.1, "MIN_GAIN": 0.02, "CONFIDENCE": 0.9},
)
"""The settings printed by default: the shipped rules, then each loosened towards naming more."""
LOOSE = {"MIN_EXPLAINED": 0.0, "MIN_GAIN": 0.0, "MIN_MARGIN": 0.0, "CONFIDENCE": 0.5,
         "MIN_SIGNIFICANCE": 0.0}
"""The rules at the loose end of ``--frontier``: an effect is named where it explains more of
the held-out missing power than re-adjusting the calibrated parameters alone in half the
resamples, and more than the runner-up."""
FRONTIER = (0.0, 0.25, 0.5, 0.75, 1.0)
"""The steps of ``--frontier``: the fraction of the way from the shipped rules to ``LOOSE``
(0: the shipped rules)."""
FIRST = "the effect ranked first"
"""Not a setting of the rules: the effect that explains the most of the held-out missing power
is the verdict on every day (the end of the frontier, where nothing is left to abstain)."""
RULES = ("MIN_EXPLAINED", "MIN_SIGNIFICANCE", "MIN_MARGIN", "MIN_GAIN", "TIE", "CONFIDENCE",
         "NUISANCE_STEPS", "HUBER_C")
"""The attribution's constants a setting may change."""
OUTSIDE = ("air_compressor", "battery_chiller")


def _candidate(c) -> dict:
    return {"name": c.name, "kind": c.kind, "signatures_w": c.signatures_w,
            "strengths": c.strengths, "step": c.step}


def capture(job) -> Path:
    """Calibrate one bench day and keep what its decision needs (worker of the pool): the
    missing power and its uncertainty per window, every candidate's signatures, the
    calibrated (nuisance) parameters, which effects fit only beyond their strength's bounds,
    and on a day with a hidden effect the candidate of its oracle log."""

    from ebus_env.config import load_bus
    from ebus_env.diagnostics.candidates import (
        effect_candidates,
        estimate_strength,
        window_signatures,
    )
    from ebus_env.diagnostics.ladder import calibrate_rung, split_blocks, windows_in
    from ebus_env.diagnostics.stage04_residual import residual_stage
    from ebus_env.diagnostics.stage05_candidates import candidate_stage

    source, case, days, cache = job
    out = Path(cache) / f"{source}-{case.case_id}-{case.hours:g}h.pkl"
    if out.exists():
        return out
    profiles, truth = truth_day(source, case, Path(days))
    bus = load_bus("12m", without=list(bench.BASELINE_WITHOUT))
    dt_s = profiles[0].dt_s
    blocks = split_blocks(profiles)
    model = bus.build(dt_s)
    rung = calibrate_rung(bus, [], profiles, *blocks, dt_s, model=model)
    res = residual_stage(model, profiles, rung.values, None)
    candidates, _ = candidate_stage(bus, res, profiles, (), lambda text: None)
    oracle = []
    if case.hidden is not None:
        oracle_profiles = truth_day(source, case, Path(days), oracle=True)[0]
        signatures_of = window_signatures(oracle_profiles, res.windows, res.basis,
                                          res.energy_j, res.base_power_w)
        oracle = [(c, oracle_profiles) for c in effect_candidates(
            bus, dt_s, res.values, signatures_of)[0] if c.name == ORACLE]
    nuisance = tuple(n for n in rung.calibration_result.free
                     if any(c.name == n for c in candidates))
    moving = np.column_stack([c.signature_w for n in nuisance for c in candidates
                              if c.name == n]) if nuisance else None
    in_cal = windows_in(blocks[0], res.windows)
    fit = res.usable & in_cal
    implausible = {}
    for c, on in [(c, profiles) for c in candidates if c.kind != "parameter"] + oracle:
        strength = estimate_strength(c, on, res.windows, res.basis, res.energy_j,
                                     res.base_power_w, res.missing_w,
                                     attribution.weights(res.noise_w), fit, moving)
        implausible[c.name] = strength.at_bound
    record = {"source": source, "case": case.case_id, "hidden": case.hidden,
              "expected": truth["expected_verdict"], "nuisance": nuisance,
              "missing_w": res.missing_w, "noise_w": res.noise_w,
              "measurement_w": res.measurement_w, "usable": res.usable,
              "candidates": [_candidate(c) for c in candidates],
              "oracle": [_candidate(c) for c, _ in oracle], "implausible": implausible}
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_bytes(pickle.dumps(record))
    tmp.replace(out)
    return out


@contextmanager
def rules(setting: dict):
    """The attribution's constants set to ``setting`` for the duration."""
    before = {name: getattr(attribution, name) for name in setting}
    try:
        for name, value in setting.items():
            setattr(attribution, name, value)
        yield
    finally:
        for name, value in before.items():
            setattr(attribution, name, value)


def label(expected, verdict: str | None, status: str, effects: list[str], oracle: bool) -> str:
    """Whether a day's verdict is right, wrong or an abstention, or a control day's named or
    quiet (``effects``: the effect candidates, best first)."""
    if expected is None:
        return "control named" if verdict else "control quiet"
    if named_right(expected, verdict, status, effects, oracle):
        return "right"
    return "abstained" if verdict is None else "wrong"


def decide(job) -> tuple[str, str]:
    """One cached day decided under a setting (worker of the pool): the label of its verdict,
    and the label it would have if the effect ranked first were the verdict (:data:`FIRST`;
    of the rules only ``NUISANCE_STEPS`` and ``HUBER_C`` change the ranking)."""
    from ebus_env.diagnostics.candidates import Candidate

    path, setting, oracle = job
    r = pickle.loads(Path(path).read_bytes())
    pool = r["candidates"] + (r["oracle"] if oracle else [])
    candidates = [Candidate(c["name"], c["kind"], c["signatures_w"], c["strengths"],
                            step=c["step"]) for c in pool]
    with rules(setting):
        d = attribution.attribute(r["missing_w"], r["noise_w"], candidates, r["usable"],
                                  nuisance=r["nuisance"], measurement_w=r["measurement_w"])
    effects = [a.name for a in d.ranking if a.kind != "parameter"]
    verdict, status = d.verdict, d.status
    if verdict is not None and r["implausible"].get(verdict):
        verdict, status = None, "implausible"
    first = effects[0] if effects else None
    return (label(r["expected"], verdict, status, effects, oracle),
            label(r["expected"], first, "named", effects, oracle))


def loosened(t: float) -> dict:
    """The shipped rules moved the fraction ``t`` of the way to :data:`LOOSE`."""
    return {k: getattr(attribution, k) + t * (v - getattr(attribution, k))
            for k, v in LOOSE.items()}


def tally(records: list[tuple[str, str | None]], labels: list[str]):
    """Counts of the labels by (source, hidden effect), and (library effects right, library
    days, wrong verdicts, control days with a verdict, control days)."""
    groups: dict = {}
    for (source, hidden), lab in zip(records, labels, strict=True):
        groups.setdefault((source, hidden or "control"), Counter())[lab] += 1
    library = [k for k in groups if k[1] not in ("control",) + OUTSIDE]
    controls = [g for k, g in groups.items() if k[1] == "control"]
    named = sum(g["control named"] for g in controls)
    return groups, (sum(groups[k]["right"] for k in library),
                    sum(sum(groups[k].values()) for k in library),
                    sum(g["wrong"] for g in groups.values()), named,
                    named + sum(g["control quiet"] for g in controls))


def evaluate(paths: list[Path], records: list[tuple[str, str | None]], setting: dict,
             oracle: bool, workers: int) -> list[tuple[str, str]]:
    """Decide every cached day under ``setting``, print the tally, return :func:`decide`'s
    labels."""
    from concurrent.futures import ProcessPoolExecutor

    t0 = time.perf_counter()
    with ProcessPoolExecutor(workers) as pool:
        decided = list(pool.map(decide, [(p, setting, oracle) for p in paths]))
    groups, (right, total, wrong, named, controls) = tally(records, [d[0] for d in decided])
    name = ", ".join(f"{k}={v:g}" for k, v in setting.items()) or "the shipped rules"
    print(f"\n{name}{' + the hidden effects in a perfect form' if oracle else ''}: "
          f"library effects named right {right} of {total}, wrong verdicts {wrong}, "
          f"control days with a verdict {named} of {controls} "
          f"({time.perf_counter() - t0:.0f} s)")
    for (source, hidden), g in sorted(groups.items()):
        if hidden == "control":
            continue
        n = sum(g.values())
        print(f"  {source:9s} {hidden:16s} right {g['right']:2d} of {n:2d}"
              + (f", wrong {g['wrong']}" if g["wrong"] else ""))
    return decided


def frontier(paths, records, oracle: bool, workers: int) -> None:
    """The trade-off of the rules: each step of :data:`FRONTIER` from the shipped rules to
    :data:`LOOSE`, then :data:`FIRST`; a table of the library effects named right, the wrong
    verdicts and the control days with a verdict, after each step's tally."""
    rows, first = [], None
    for t in FRONTIER:
        decided = evaluate(paths, records, loosened(t), oracle, workers)
        rows.append(("shipped" if t == 0.0 else f"{100 * t:.0f} % loosened",
                     tally(records, [d[0] for d in decided])[1]))
        first = first or tally(records, [d[1] for d in decided])[1]  # the same at every step
    rows.append((FIRST, first))
    print("\n| rules | library effects named right | wrong verdicts | control days with a "
          "verdict |\n|---|---|---|---|")
    for name, (right, total, wrong, named, controls) in rows:
        print(f"| {name} | {right} of {total} ({100 * right / max(total, 1):.0f} %) | {wrong} "
              f"| {named} of {controls} |")


def parse_setting(items: list[str]) -> dict:
    setting = {}
    for item in items:
        name, _, value = item.partition("=")
        if name not in RULES:
            raise SystemExit(f"--set {item}: {name!r} is not a rule of the attribution; "
                             f"one of {', '.join(RULES)}")
        try:
            setting[name] = float(value)
        except ValueError:
            raise SystemExit(f"--set {item}: the value must be a number") from None
    return setting


def main() -> None:
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--set", action="append", default=[], metavar="RULE=VALUE",
                        help=f"one setting of the rules ({', '.join(RULES)}); default: VARIANTS")
    parser.add_argument("--oracle", action="store_true",
                        help="add each hidden effect in a perfect form (its own power)")
    parser.add_argument("--frontier", action="store_true",
                        help="the rules loosened step by step to LOOSE, then the effect "
                        "ranked first named on every day: a table of the trade-off")
    parser.add_argument("--source", choices=tuple(bench.SOURCES), action="append")
    parser.add_argument("--per-effect", type=int, default=None)
    parser.add_argument("--controls", type=int, default=None)
    parser.add_argument("--smoke", action="store_true",
                        help="three 4 h days of the truth simulator (grade, passengers, control)")
    parser.add_argument("--days", type=Path, default=bench.DAYS_CACHE,
                        help="where the bench's generated days are kept")
    parser.add_argument("--cache", type=Path, default=CACHE,
                        help="where each day's calibrated inputs of the decision are kept")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    settings = [parse_setting(args.set)] if args.set else list(VARIANTS)
    jobs = []
    for source in (("truthsim",) if args.smoke else tuple(args.source or bench.SOURCES)):
        module, why = bench.truth_module(source)
        if module is None:
            print(f"{why}: skipped")
            continue
        cases = truth_cases(source, args.smoke, args.per_effect, args.controls)
        if args.smoke:
            cases = [c for c in cases if c.hidden in ("road_grade", "passenger_mass")][:2] + \
                [c for c in cases if c.hidden is None][:1]
        jobs += [(source, c, str(args.days), str(args.cache)) for c in cases]
    args.days.mkdir(parents=True, exist_ok=True)
    args.cache.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.workers, mp_context=get_context("spawn")) as pool:
        paths = list(pool.map(capture, jobs))
    print(f"{len(paths)} days calibrated or read from {args.cache} "
          f"({time.perf_counter() - t0:.0f} s)")
    records = [(source, case.hidden) for source, case, *_ in jobs]
    if args.frontier:
        frontier(paths, records, args.oracle, args.workers)
        return
    for setting in settings:
        evaluate(paths, records, setting, args.oracle, args.workers)


if __name__ == "__main__":
    main()
