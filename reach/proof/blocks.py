"""Rows computed in blocks, one per thread, by compiled loops that release the GIL (:mod:`softreach.filters.compiled`,
:func:`softreach.reach.proof.model_kernels.held_boxes`)."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable

import numpy as np

#: the fewest rows a thread takes: handing a block over costs as much as deciding many (``benchmarks/bench_filter.py``)
PARALLEL_MIN_ROWS = 256
_POOL: dict[str, Any] = {}


def default_threads() -> int:
    """Two threads where this process may run on two cores or more, else one."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    return min(2, cores)


def _pool(workers: int) -> ThreadPoolExecutor:
    """A pool of at least ``workers`` threads, made again in a forked child (whose copy of the pool has none)."""
    pool = _POOL.get("pool")
    if pool is None or _POOL["pid"] != os.getpid() or _POOL["workers"] < workers:
        pool = ThreadPoolExecutor(workers, thread_name_prefix="softreach-filter")
        _POOL.update(pool=pool, pid=os.getpid(), workers=workers)
    return pool


def check_threads(threads: Any) -> int:
    """``threads`` as an ``int``.

    :raises ValueError: ``threads`` is not a whole number of at least 1
    """
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
        raise ValueError(f"threads must be a whole number of at least 1, got {threads!r}")
    return int(threads)


def run_in_blocks(run: Callable[[int, int], None], rows: int, threads: int, min_rows: int = PARALLEL_MIN_ROWS) -> None:
    """Call ``run(lo, hi)`` on consecutive blocks covering ``range(rows)``, one per thread, at most ``threads`` with
    at least ``min_rows`` rows each; the calling thread takes the first. A block's exception is raised once all end.

    :param run: decides the rows ``lo`` to ``hi - 1``; it must release the GIL for the blocks to overlap
    :raises ValueError: ``threads`` is not a whole number of at least 1
    """
    k = max(1, min(check_threads(threads), rows // min_rows))
    cuts = [rows * i // k for i in range(k + 1)]
    others = [_pool(k - 1).submit(run, cuts[i], cuts[i + 1]) for i in range(1, k)]
    try:
        run(cuts[0], cuts[1])
    finally:
        for f in others:
            f.exception()  # waits: no block still writes into the outputs once this returns or raises
    for f in others:
        f.result()
