"""Compiled kernels over blocks of work on every core, the bytes the same on any number.

A kernel compiled with ``numba.njit(nogil=True)`` takes a range of blocks ``(first, last)``
and writes only what those blocks own; :func:`run_blocks` calls it on ranges of the blocks
from a pool of threads. The blocks, not the threads, decide what is computed together, so
the result is the same, bit for bit, on one thread or many.

Threads, not numba's ``prange``: a process that has run numba's OpenMP loops may not fork
(numba ends such a child), and craterscape forks (stack edits, worker pools). The number of
threads is ``NUMBA_NUM_THREADS`` (every core by default; a Dask worker of craterscape's gets
1), or what :func:`limited` sets.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor

import numba

__all__ = ["limited", "run_blocks", "threads"]

#: Ranges handed out per thread: more than one, so a thread that finishes early takes more.
RANGES_PER_THREAD = 4
_limit: list[int] = []


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
    with ThreadPoolExecutor(n) as pool:
        for future in [pool.submit(kernel, *args, bounds[k], bounds[k + 1])
                       for k in range(parts)]:
            future.result()
