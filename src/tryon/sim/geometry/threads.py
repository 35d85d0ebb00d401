"""Collision queries on every core: a list of independent work items (candidate pairs,
subtrees) is cut into fixed chunks that the numba kernels (compiled without the GIL)
process on worker threads.

The chunks do not depend on the number of threads and their results are joined in
chunk order, so a query returns the same thing on 1 thread as on 16. The thread count is
numba's (`NUMBA_NUM_THREADS`, `numba.set_num_threads`): the processes of a Ray or dataset
run that set it to 1 run these queries serially.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import numba
import numpy as np

T = TypeVar("T")

CHUNK = 8192  # work items per chunk: large enough that a chunk costs far more than handing it out

_pool: ThreadPoolExecutor | None = None
_pool_key: tuple[int, int] = (0, 0)  # (process id, threads) the pool was made for


def _executor(threads: int) -> ThreadPoolExecutor:
    global _pool, _pool_key
    key = (os.getpid(), threads)
    if _pool is None or _pool_key != key:  # a forked child cannot use its parent's threads
        _pool = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="tryon-collision")
        _pool_key = key
    return _pool


def chunked(work: Callable[[np.ndarray], T], items: np.ndarray, chunk: int | None = None) -> Sequence[T]:
    """[work(items[a:a+chunk]) for each chunk] (`CHUNK` items by default), on numba's
    threads when there are several chunks and threads; one call on all items otherwise."""
    chunk = chunk or CHUNK
    starts = range(0, len(items), chunk)
    threads = numba.get_num_threads()
    if len(starts) < 2 or threads < 2:
        return [work(items)]
    return list(_executor(threads).map(lambda a: work(items[a:a + chunk]), starts))
