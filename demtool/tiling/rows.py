"""Work on threads of this process: rows of one array on the calling thread and its
helper threads (:func:`on_row_parts`), and independent pieces in order on a pool
(:func:`ordered_map`).

A compiled kernel that works row by row and releases the GIL (numba ``nogil=True``)
is run over ``0 … count`` in contiguous parts, one per usable thread, by
:func:`on_row_parts`.  This is the serial alternative to numba's ``parallel=True``:
the same cores, the result of one thread bit for bit when each part writes only its
own rows, and a kernel that compiles in a fraction of the time (numba's parfor pass
and its gufunc wrapper are most of a ``parallel=True`` kernel's compile, which a fresh
install pays in its first run).

The parts follow the calling thread's limits: at most
:func:`demtool.tiling.tasks.usable_threads` (a tile job's share, a stage's
``--workers``) and at most numba's thread count of the calling thread (which a tile
job, ``NUMBA_NUM_THREADS`` or :func:`numba.set_num_threads` sets), as a
``parallel=True`` kernel would.
"""

from __future__ import annotations

import os
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from typing import TypeVar

from demtool.tiling.tasks import available_cores, usable_threads

T = TypeVar("T")
R = TypeVar("R")

#: Fewest rows worth a second thread (a part's start costs ~0.1 ms).
MIN_ROWS_PER_PART = 64

# helper threads, one pool per calling thread: tiles on threads
# (demtool.tiling.local_threads) each split their rows at once, and a pool shared by the
# process would queue one tile's parts behind another's
_HELPERS = threading.local()


def _helper_pool():
    """The calling thread's helper threads (one fewer than the process's cores), which
    run the parts after the first: started on the thread's first split and kept while
    the thread lives (its pool goes with the thread's locals); a new one after a fork,
    whose child has no threads."""
    from concurrent.futures import ThreadPoolExecutor

    pid, pool = getattr(_HELPERS, "pool", (None, None))
    if pool is None or pid != os.getpid():
        pool = ThreadPoolExecutor(max_workers=max(1, available_cores() - 1),
                                  thread_name_prefix="demtool-rows")
        _HELPERS.pool = (os.getpid(), pool)
    return pool


def _numba_threads() -> int:
    """numba's thread count of the calling thread."""
    import numba

    return numba.get_num_threads()


def row_parts(count: int, *, min_rows: int = MIN_ROWS_PER_PART,
              max_parts: int | None = None) -> list[tuple[int, int]]:
    """The ``(start, stop)`` parts :func:`on_row_parts` gives ``count`` rows: one per
    usable thread (numba's count of the calling thread and
    :func:`~demtool.tiling.tasks.usable_threads`, at most ``max_parts``), each of at
    least ``min_rows`` rows, contiguous and in order; ``[(0, count)]`` for one."""
    parts = min(usable_threads(), _numba_threads())
    if max_parts is not None:
        parts = min(parts, int(max_parts))
    parts = max(1, min(parts, count // max(1, int(min_rows))))
    return [(count * i // parts, count * (i + 1) // parts) for i in range(parts)]


def on_row_parts(work: Callable[[int, int], object], count: int, *,
                 min_rows: int = MIN_ROWS_PER_PART, max_parts: int | None = None) -> None:
    """Run ``work(start, stop)`` over the parts of ``0 … count`` (:func:`row_parts`),
    the first on the calling thread and the others on its helper threads at once.

    ``work`` should be a ``nogil`` kernel writing only rows ``start … stop − 1`` of its
    outputs (then the result is one thread's, bit for bit) and must not call
    :func:`on_row_parts` itself (its parts would queue behind its caller's on the
    thread's helpers).  The first exception of a part is raised after every part ended.
    """
    parts = row_parts(count, min_rows=min_rows, max_parts=max_parts)
    if len(parts) == 1:
        work(0, count)
        return
    from demtool.tiling.tasks import carried

    pool = _helper_pool()
    futures = [pool.submit(carried(lambda start=start, stop=stop: work(start, stop)))
               for start, stop in parts[1:]]
    try:
        work(*parts[0])
    finally:
        errors = [future.exception() for future in futures]
    for error in errors:
        if error is not None:
            raise error


def ordered_map(function: Callable[[T], R], items: Iterable[T], *,
                threads: int | None = None) -> Iterator[R]:
    """``map(function, items)`` on ``threads`` threads, results in the items' order.

    For independent pieces of work (map tiles, batches of ground points, a comparison's
    windows) whose compiled kernels, numpy loops and GDAL reads release the GIL.  At
    most ``threads + 1`` items are in flight (the memory of that many pieces); each
    call runs as on the calling thread (:func:`demtool.tiling.tasks.carried`: its
    context, so a ``threads_limited`` limit or an output transaction holds there too)
    with ``max(1, numba's count // threads)`` numba threads (default ``threads``:
    numba's count of the calling thread).  With one thread it is a plain loop in the
    calling thread.  An exception in a call is raised where its result would have been
    yielded, after the calls in flight finish; leaving the loop early cancels the calls
    not yet started and waits for the others.
    """
    total = _numba_threads()
    threads = total if threads is None else max(1, int(threads))
    share = max(1, total // threads)
    if threads == 1:
        for item in items:
            yield function(item)
        return
    from concurrent.futures import ThreadPoolExecutor

    from demtool.tiling.tasks import carried, numba_threads_at_most

    def call(item: T) -> R:
        with numba_threads_at_most(share):
            return function(item)

    pending: deque = deque()
    with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="demtool") as pool:
        try:
            for item in items:
                pending.append(pool.submit(carried(lambda item=item: call(item))))
                if len(pending) > threads:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()
        finally:
            for future in pending:
                future.cancel()
