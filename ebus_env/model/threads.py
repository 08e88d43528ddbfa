"""The shared thread pool of batched runs: the compiled passes release the GIL, so chunks of
buses run in parallel on threads."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, wait

_POOL: ThreadPoolExecutor | None = None


def default_threads() -> int:
    """Threads for batched runs: ``$EBUS_THREADS`` or the number of CPUs."""
    return max(1, int(os.environ.get("EBUS_THREADS", os.cpu_count() or 1)))


def _pool() -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=default_threads(), thread_name_prefix="ebus")
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
