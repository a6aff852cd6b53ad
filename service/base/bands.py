"""Run a compiled kernel over bands on several threads, without numba's parfor.

A ``parallel=True`` kernel pays numba's parfor passes at compile time: its
``prange`` body is typed and compiled once in the kernel and again, optimised,
as the parallel gufunc (``docs/compile-time.md``): ``scatter_bands`` took 29 s
of CPU to compile with ``parallel=True`` and 13.4 s without, the same body.  A
new user pays every compile on a fresh machine.  A kernel written for a range of
bands (``kernel(first, stop, *args)`` doing bands ``first .. stop - 1``),
compiled ``nogil=True`` without ``parallel``, and called here from a few threads
runs the same machine code per band at half the compile.

The threads are a small pool per thread count, kept for the process (like
numba's own pool) and dropped in a forked child, where they do not exist.  The
thread count defaults to :func:`numba.get_num_threads`, so a caller's
``numba.set_num_threads`` (thread-local) rules both kinds of kernel alike.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numba as nb
import numpy as np

#: Name prefix of the pool's threads (they live as long as the process).
THREAD_PREFIX = "bands"


@functools.cache
def _pool(workers: int) -> ThreadPoolExecutor:
    """The process's pool of ``workers`` threads (the caller's thread is one more)."""
    return ThreadPoolExecutor(workers, thread_name_prefix=THREAD_PREFIX)


# a forked child has none of its parent's threads: it makes its own pools
os.register_at_fork(after_in_child=_pool.cache_clear)


def chunks(bands: int, parts: int) -> list[tuple[int, int]]:
    """Split bands ``0 .. bands - 1`` into at most ``parts`` contiguous runs.

    Parameters
    ----------
    bands : int
        Number of bands (>= 0).
    parts : int
        Runs wanted (>= 1); their lengths differ by one band at most.

    Returns
    -------
    list of (int, int)
        ``(first, stop)`` of each non-empty run, in order; together they cover
        every band once.
    """
    parts = max(1, min(parts, bands))
    edges = [b * bands // parts for b in range(parts + 1)]
    return [(edges[i], edges[i + 1]) for i in range(parts) if edges[i] < edges[i + 1]]


def run_bands(
    kernel: Callable[..., object], bands: int, *args: object, threads: int | None = None
) -> None:
    """Call ``kernel(first, stop, *args)`` over all bands, one run of bands per thread.

    The calling thread does the first run and waits for the others; each run is
    one call, so a compiled kernel is entered once per thread.  The kernel must
    release the GIL (``nogil=True``) to run in parallel, and its runs must not
    write the same memory.

    Parameters
    ----------
    kernel : callable
        ``kernel(first, stop, *args)``; ``first`` and ``stop`` are ``np.int64``
        (typed integers: a Python int passed as a constant would not make numba
        compile another specialisation, but keep callers alike).
    bands : int
        Number of bands (0 calls nothing).
    *args
        Passed to every call.
    threads : int, optional
        Threads to use, the caller's included; default
        :func:`numba.get_num_threads`.

    Raises
    ------
    Exception
        The first run's exception (in band order) after every run has ended.
    """
    runs = chunks(int(bands), threads or nb.get_num_threads()) if bands > 0 else []
    if len(runs) <= 1:
        for first, stop in runs:
            kernel(np.int64(first), np.int64(stop), *args)
        return
    pool = _pool(len(runs) - 1)
    futures = [pool.submit(kernel, np.int64(a), np.int64(b), *args) for a, b in runs[1:]]
    error: BaseException | None = None
    try:
        kernel(np.int64(runs[0][0]), np.int64(runs[0][1]), *args)
    except BaseException as exc:  # noqa: BLE001 - re-raised once the others end
        error = exc
    for future in futures:
        exc = future.exception()
        if exc is not None and error is None:
            error = exc
    if error is not None:
        raise error
