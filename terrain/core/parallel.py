"""Compiled kernels over blocks of work on every core, the bytes the same on any number.

A kernel compiled with ``numba.njit(nogil=True)`` takes a range of blocks ``(first, last)``
and writes only what those blocks own; :func:`run_blocks` calls it on ranges of the blocks
from a pool of threads. The blocks, not the threads, decide what is computed together, so
the result is the same, bit for bit, on one thread or many.

Threads, not numba's ``prange``: a process that has run numba's OpenMP loops may not fork
(numba ends such a child), and craterscape forks (stack edits, worker pools). The number of
threads is ``NUMBA_NUM_THREADS`` (every core by default; a Dask worker of craterscape's gets
1), or what :func:`limited` sets. The threads are started once and kept (a size class of
craters calls :func:`run_blocks` dozens of times, and starting threads each time cost more
than some of the calls); a child made by ``fork`` starts its own when it first needs them.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor

import numba

__all__ = ["limited", "run_blocks", "threads"]

#: Ranges handed out per thread: more than one, so a thread that finishes early takes more.
#: The work of a block varies (a band of rows under one large crater, or none): two threads
#: composing the craters of the 4097^2 benchmark tile lose about 8 % of their time waiting
#: for each other at the end of a call with 4, about 2 % with 16; each range costs a
#: dispatch (tens of microseconds).
RANGES_PER_THREAD = 8
_limit: list[int] = []
#: The kept pools, by their number of threads.
_pools: dict[int, ThreadPoolExecutor] = {}
_pools_lock = threading.Lock()


def _forget_pool() -> None:
    """Drop the parent's pools in a forked child, whose copies have no threads behind them."""
    global _pools_lock
    _pools.clear()
    _pools_lock = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool)


def _executor(n: int) -> ThreadPoolExecutor:
    """Return the kept pool of ``n`` threads (started on first use)."""
    with _pools_lock:
        pool = _pools.get(n)
        if pool is None:
            pool = _pools[n] = ThreadPoolExecutor(n, thread_name_prefix="craterscape-blocks")
        return pool


def threads() -> int:
    """Return the number of threads :func:`run_blocks` uses (at least 1; :func:`limited` sets it).

    >>> with limited(1):
    ...     threads()
    1
    """
    if _limit:
        return _limit[-1]
    return max(1, int(getattr(numba.config, "NUMBA_NUM_THREADS", 1)))


@contextlib.contextmanager
def limited(n: int) -> Iterator[None]:
    """Run the block with ``n`` threads (a one-thread baseline, or a test of determinism)."""
    _limit.append(max(1, int(n)))
    try:
        yield
    finally:
        _limit.pop()


def run_blocks(kernel: Callable, blocks: int, *args) -> None:
    """Call ``kernel(*args, first, last)`` over ranges covering blocks ``0 .. blocks - 1``.

    Parameters
    ----------
    kernel : callable
        A kernel that releases the GIL and writes only what blocks ``first .. last - 1`` own.
    blocks : int
        Number of blocks.
    *args
        The kernel's other arguments, first.
    """
    n = min(threads(), blocks)
    if n <= 1:
        if blocks > 0:
            kernel(*args, 0, blocks)
        return
    parts = min(blocks, n * RANGES_PER_THREAD)
    bounds = [blocks * k // parts for k in range(parts + 1)]
    pool = _executor(n)
    for future in [pool.submit(kernel, *args, bounds[k], bounds[k + 1]) for k in range(parts)]:
        future.result()
