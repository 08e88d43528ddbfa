"""Where a study's scenarios run: in this process (the default) or as Ray tasks.

Either way each scenario's rows are written as soon as it finishes
(:func:`ebus_env.study.rows.write_rows`), so a stopped study resumes where it stopped. On
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
from ebus_env.outputs import write_text
from ebus_env.study.rows import finished, read_results, rows_dir, write_rows
from ebus_env.study.scenarios import scenarios
from ebus_env.study.study_file import StudySpec

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
        passes release the GIL), a scenario's days split over them when there are fewer
        scenarios than threads. None: every CPU (``$EBUS_THREADS``).
    """
    out = Path(out)
    if workers is not None and workers < 1:
        raise ConfigError(f"--workers {workers}: give a number of threads or CPUs >= 1, or "
                          "leave it out for every CPU.")
    done = finished(out)
    if done and not resume:
        raise ConfigError(f"{out} already holds the rows of {len(done)} scenario(s): add "
                          "--resume to finish that study, or give another --out folder.")
    keys = {s.key(spec) for s in scenarios(spec)}
    if done - keys:
        say(f"{len(done - keys)} scenario(s) in {rows_dir(out)} are not in this study (another "
            "study, or this one before an edit): left out of its summary")
    out.mkdir(parents=True, exist_ok=True)
    write_text(out / "study.yaml", yaml.safe_dump(spec.raw, sort_keys=False))
    todo = [s for s in scenarios(spec) if s.key(spec) not in done]
    say(f"study '{spec.name}': {len(scenarios(spec))} scenario(s) x {spec.days.count} day(s); "
        f"{len(scenarios(spec)) - len(todo)} already done, {len(todo)} to run "
        f"{'on Ray' if use_ray else 'in this process'}")
    t0 = time.perf_counter()

    from ebus_env.model.model import default_threads
    from ebus_env.study.runner import forget_batches, run_scenario

    # fewer scenarios than threads: each scenario's days are split over the idle threads
    # (every day is seeded on its own, so a part's rows equal the whole run's); a timetable
    # study's days are Ray's unit of work too (its blocks share chargers: a day is one task)
    if not todo:
        parts = 1
    elif use_ray:
        parts = spec.days.count if spec.gtfs is not None else 1
    else:
        parts = min(spec.days.count, -(-(workers or default_threads()) // len(todo)))
    days = [list(range(spec.days.count))[i::parts] for i in range(parts)]
    got: dict[int, list[dict]] = {}  # rows of the scenarios with days still running

    def finished_one(args: tuple, rows: list[dict]) -> None:
        scenario = args[1]
        got.setdefault(scenario.index, []).extend(rows)
        if len(got[scenario.index]) == spec.days.count:
            rows = sorted(got.pop(scenario.index), key=lambda r: r["day"])
            write_rows(out, scenario.key(spec), rows)
            say(f"  {scenario.name}: done")

    forget_batches()
    map_tasks(run_scenario, [(spec, s, d) for s in todo for d in days], finished_one,
              use_ray=use_ray, address=address, workers=workers)
    if todo:
        say(f"ran {len(todo)} scenario(s) in {time.perf_counter() - t0:.1f} s")
    return read_results(out, keys)


def map_tasks(task: Callable, args_list: list[tuple], on_result: Callable, *,
              use_ray: bool = False, address: str | None = None,
              workers: int | None = None) -> None:
    """Call ``task(*args)`` for each ``args``, ``on_result(args, result)`` (in this thread) as
    each one finishes: on a pool of ``workers`` threads (None: every CPU), or as Ray tasks of
    one CPU each, run again when their worker dies (``MAX_RETRIES``)."""
    if not args_list:
        return
    if use_ray:
        _map_ray(task, args_list, on_result, address, workers)
        return
    from concurrent.futures import ThreadPoolExecutor, as_completed

    from ebus_env.model.threads import call_with_threads, default_threads

    workers = workers or default_threads()
    # each task's share of the threads: a task's own batches may split over threads too, so
    # --workers N uses N CPUs in all (one task: all N; N tasks or more: one each)
    share = max(1, workers // min(workers, len(args_list)))
    with ThreadPoolExecutor(max_workers=workers) as pool:
        futures = {pool.submit(call_with_threads, share, task, *args): args
                   for args in args_list}
        try:
            for future in as_completed(futures):
                on_result(futures[future], future.result())
        except BaseException:
            for future in futures:
                future.cancel()
            raise


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


def _map_ray(task, args_list, on_result, address, workers) -> None:
    try:
        import ray
    except ImportError:
        ray = None
    ours = ray is None or not ray.is_initialized()  # a runtime this call joins, it also leaves
    ray = connect_ray(address, workers)  # without Ray: the error that says how to install it
    try:
        from ebus_env.model.threads import call_with_threads

        # a task holds one CPU, so its batches run on one thread
        remote = ray.remote(num_cpus=1, max_retries=MAX_RETRIES)(call_with_threads)
        pending = {remote.remote(1, task, *args): args for args in args_list}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            on_result(pending.pop(ready[0]), ray.get(ready[0]))
    finally:
        if ours:
            ray.shutdown()
