"""Where a study's scenarios run: in this process (the default) or as Ray tasks.

Either way each scenario's rows are written as soon as it finishes
(:func:`ebus_env.study.results.write_rows`), so a stopped study resumes where it stopped. On
Ray each scenario is one task; a task whose worker dies is run again by Ray (``max_retries``),
and since a scenario's rows depend only on the study file and its seeds, the retried rows equal
those of an undisturbed run.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import yaml

from ebus_env.errors import ConfigError
from ebus_env.io.atomic import write_text_atomic
from ebus_env.study.results import finished, read_results, write_rows
from ebus_env.study.scenarios import Scenario, scenarios
from ebus_env.study.spec import StudySpec, load_study

MAX_RETRIES = 3  # runs of a task whose worker died, after the first


def run_study(spec: StudySpec, out: str | Path, *, resume: bool = False, use_ray: bool = False,
              address: str | None = None, workers: int | None = None,
              say: Callable[[str], None] = print):
    """Run every scenario of ``spec`` not yet in ``out`` and return all rows (pandas).

    Parameters
    ----------
    resume
        Skip the scenarios whose rows ``out`` holds; without it ``out`` must hold none.
    use_ray, address, workers
        Run on Ray: join the cluster at ``address`` (``host:port``), else start a local
        runtime with ``workers`` CPUs. In this process: ``workers`` threads (the compiled
        passes release the GIL). None: every CPU (``$EBUS_THREADS``).
    """
    out = Path(out)
    done = finished(out)
    if done and not resume:
        raise ConfigError(f"{out} already holds the rows of {len(done)} scenario(s): add "
                          "--resume to finish that study, or give another --out folder.")
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / "study.yaml", yaml.safe_dump(spec.raw, sort_keys=False))
    todo = [s for s in scenarios(spec) if s.key(spec) not in done]
    say(f"study '{spec.name}': {len(scenarios(spec))} scenario(s) x {spec.days.count} day(s); "
        f"{len(scenarios(spec)) - len(todo)} already done, {len(todo)} to run "
        f"{'on Ray' if use_ray else 'in this process'}")
    t0 = time.perf_counter()
    if use_ray:
        _run_ray(spec, todo, out, address, workers, say)
    else:
        _run_threads(spec, todo, out, workers, say)
    if todo:
        say(f"ran {len(todo)} scenario(s) in {time.perf_counter() - t0:.1f} s")
    return read_results(out)


def _run_threads(spec: StudySpec, todo: list[Scenario], out: Path, workers, say) -> None:
    """The scenarios on a pool of threads; each one's rows written as it finishes."""
    from concurrent.futures import ThreadPoolExecutor, as_completed

    from ebus_env.model.model import default_threads
    from ebus_env.study.runner import run_scenario

    with ThreadPoolExecutor(max_workers=workers or default_threads()) as pool:
        futures = {pool.submit(run_scenario, spec, s): s for s in todo}
        try:
            for future in as_completed(futures):
                scenario = futures[future]
                write_rows(out, scenario.key(spec), future.result())
                say(f"  {scenario.name}: done")
        except BaseException:
            for future in futures:
                future.cancel()
            raise


def _scenario_task(raw: dict, source: str, index: int) -> tuple[str, list[dict]]:
    """A Ray task: rebuild the study from its mapping and run scenario ``index``."""
    from ebus_env.study.runner import run_scenario

    spec = load_study(raw)
    scenario = scenarios(spec)[index]
    return scenario.key(spec), run_scenario(spec, scenario)


def ray_remote(max_retries: int = MAX_RETRIES):
    """The scenario task as a Ray remote function (one CPU each)."""
    import ray

    return ray.remote(num_cpus=1, max_retries=max_retries)(_scenario_task)


def connect_ray(address: str | None = None, workers: int | None = None):
    """Join the cluster at ``address``, or start a local runtime (``workers`` CPUs)."""
    try:
        import ray
    except ImportError:
        raise ConfigError("--ray needs Ray: pip install -c constraints.txt -e '.[scale]'") \
            from None
    if not ray.is_initialized():
        if address:
            ray.init(address=address, log_to_driver=False)
        else:
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
    return ray


def _run_ray(spec: StudySpec, todo: list[Scenario], out: Path, address, workers, say) -> None:
    import ray as ray_module

    ours = not ray_module.is_initialized()  # a runtime this call joins, it also leaves
    ray = connect_ray(address, workers)
    try:
        task = ray_remote()
        pending = {task.remote(spec.raw, spec.source, s.index): s for s in todo}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            scenario = pending.pop(ready[0])
            key, rows = ray.get(ready[0])
            write_rows(out, key, rows)
            say(f"  {scenario.name}: done")
    finally:
        if ours:
            ray.shutdown()
