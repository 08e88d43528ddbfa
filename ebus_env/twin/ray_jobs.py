"""The twin's heavy jobs (re-fits, cross-day fits with the day's diagnosis) as Ray tasks:
``ebus twin serve --ray`` starts a local Ray runtime, ``--address HOST:PORT`` joins a
cluster (``ray start --head`` / ``ray start --address=...``, docs/twin.md). A task gets the
samples it needs as a DataFrame and returns its result; the twin process stores it."""

from __future__ import annotations

_remote = {}


def connect(address: str | None) -> None:
    import ray

    if not ray.is_initialized():
        ray.init(address=address, include_dashboard=False, log_to_driver=False,
                 ignore_reinit_error=True)


def run_remote(fn, *args):
    """``fn(*args)`` as a Ray task (one CPU), retried once on a lost worker."""
    import ray

    task = _remote.get(fn)
    if task is None:
        task = _remote[fn] = ray.remote(num_cpus=1, max_retries=1)(fn)
    return ray.get(task.remote(*args))
