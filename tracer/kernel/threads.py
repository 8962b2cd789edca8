"""A shared thread pool for running nogil kernels in parallel.

numba kernels here release the GIL, so Python threads give real parallelism. The work is split
by the caller into ``n`` interleaved parts; the thread count is an explicit setting (a Ray actor
sets it to the CPUs it reserved), never a hidden global of numba's.
"""

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

_pools: dict[int, ThreadPoolExecutor] = {}


def default_threads() -> int:
    """CPUs this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def run_parts(work: Callable[[int, int], None], threads: int | None = None) -> None:
    """Call ``work(part, n_parts)`` for every part, one part per thread, and wait for all."""
    n = threads or default_threads()
    if n == 1:
        work(0, 1)
        return
    pool = _pools.get(n)
    if pool is None:
        pool = _pools[n] = ThreadPoolExecutor(max_workers=n, thread_name_prefix="tracer")
    for future in [pool.submit(work, k, n) for k in range(n)]:
        future.result()
