"""The shared thread pool of batched runs: the compiled passes release the GIL, so chunks of
buses run in parallel on threads."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor, wait
from contextlib import contextmanager
from typing import Any

_POOL: ThreadPoolExecutor | None = None
_BUDGET = threading.local()  # this thread's share of the CPUs (thread_budget)


def cpu_threads() -> int:
    """Threads the machine offers: ``$EBUS_THREADS`` or the number of CPUs."""
    return max(1, int(os.environ.get("EBUS_THREADS", os.cpu_count() or 1)))


def default_threads() -> int:
    """Threads for batched runs: this thread's budget where one is set (a task that shares
    the CPUs with others, :func:`thread_budget`), else :func:`cpu_threads`."""
    return getattr(_BUDGET, "threads", None) or cpu_threads()


@contextmanager
def thread_budget(threads: int) -> Iterator[None]:
    """Within the block, batched runs started on this thread use at most ``threads``
    threads: a task on a pool of N workers gets its share, so that N workers mean N CPUs."""
    before = getattr(_BUDGET, "threads", None)
    _BUDGET.threads = max(1, int(threads))
    try:
        yield
    finally:
        _BUDGET.threads = before


def call_with_threads(threads: int, fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)`` within :func:`thread_budget` (a module-level function: Ray can ship it)."""
    with thread_budget(threads):
        return fn(*args)


def _pool() -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None:  # sized for the machine: a budget caps how many chunks go to it
        _POOL = ThreadPoolExecutor(max_workers=cpu_threads(), thread_name_prefix="ebus")
    return _POOL


def run_chunks(fn: Callable[[int, int], None], edges: Sequence[int]) -> None:
    """Call ``fn(lo, hi)`` for each chunk ``edges[i]..edges[i+1]``, all at once: the first on
    this thread (one hand-off fewer), the others on a shared pool (the compiled passes release
    the GIL). Returns when every chunk is done; re-raises the first error."""
    if len(edges) == 2:  # one chunk: no pool at all
        fn(edges[0], edges[1])
        return
    chunks = list(zip(edges[:-1], edges[1:], strict=True))
    futures = [_pool().submit(fn, lo, hi) for lo, hi in chunks[1:]]
    try:
        fn(*chunks[0])
    finally:
        wait(futures)  # no chunk may still write into the arrays when this returns
    for f in futures:
        f.result()
