"""One forked-pool map for the diagnosis' pure jobs (losses, cell statistics): the inputs reach
the workers by the fork (module-level dicts set before it), only results travel back."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


def forked_map(job: Callable[[int], Any], n: int, jobs: int, chunksize: int = 1) -> list[Any]:
    """``[job(i) for i in range(n)]``, in order, in a forked pool of ``min(jobs, n)`` processes;
    serially when ``jobs`` or ``n`` is 1, inside a pool's worker (which may not fork), or when a
    pool cannot be made."""
    import multiprocessing as mp

    if jobs > 1 and n > 1 and not mp.current_process().daemon:
        try:
            pool = mp.get_context("fork").Pool(min(jobs, n))
        except (OSError, ValueError):
            pool = None
        if pool is not None:
            try:
                return list(pool.map(job, range(n), chunksize=chunksize))
            finally:
                pool.close()
                pool.join()
    return [job(i) for i in range(n)]
