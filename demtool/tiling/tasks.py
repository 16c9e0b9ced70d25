"""One tile as a task: computing it within its share of the cores, and its failure's line.

Shared by every way of running tiles (:mod:`demtool.tiling.distributed`: in this
process, on a Dask cluster; :mod:`demtool.tiling.local_threads`: on threads of this
process).
"""

from __future__ import annotations

import contextvars
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

from demtool.errors import ProcessingError
from demtool.tiling import Tile, TileCache, TileJob

T = TypeVar("T")


def available_cores() -> int:
    """CPU cores this process may use."""
    import os

    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


#: Threads the work of this context may use (0: the process's cores); set by
#: :func:`threads_limited` from a stage's ``--workers`` and, by :func:`compute_tile`, from
#: a tile job's threads, so a tile job given one thread (a Dask worker) does not start a
#: second one.
_THREAD_LIMIT: contextvars.ContextVar[int] = contextvars.ContextVar("demtool_threads",
                                                                    default=0)


@contextmanager
def threads_limited(threads: int) -> Iterator[None]:
    """Within the block, :func:`usable_threads` is at most ``threads`` (≤ 0: no limit)."""
    token = _THREAD_LIMIT.set(int(threads))
    try:
        yield
    finally:
        _THREAD_LIMIT.reset(token)


def usable_threads() -> int:
    """Threads the calling work may use: the process's cores, or fewer within
    :func:`threads_limited`."""
    cores = available_cores()
    limit = _THREAD_LIMIT.get()
    return min(cores, limit) if limit > 0 else cores


@contextmanager
def numba_threads_at_most(threads: int) -> Iterator[None]:
    """Within the block, the calling thread's numba thread count is ``threads`` (≤ 0:
    unchanged); restored after it (numba keeps the count per thread)."""
    if threads <= 0:
        yield
        return
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))
    try:
        yield
    finally:
        numba.set_num_threads(before)


def carried(function: Callable[[], T]) -> Callable[[], T]:
    """``function`` to be called on another thread as on this one: in a copy of this
    thread's context (:func:`threads_limited`'s limit, an output transaction, the layout)
    and within this thread's numba thread count (numba keeps the count per thread: a new
    thread would get every core)."""
    import numba

    context = contextvars.copy_context()
    count = numba.get_num_threads()

    def run() -> T:
        with numba_threads_at_most(count):
            return context.run(function)

    return run


def compute_tile(job: TileJob, tile: Tile, cache: TileCache, threads: int) -> dict[str, Any]:
    """Compute one tile and store its core in the cache (the task a worker runs); within
    the job, :func:`usable_threads` and numba's thread count are ``threads`` (0: the
    process's cores; a job ignoring ``threads``, or sizing its pools from numba's count,
    stays within a Dask worker's share of the cores)."""
    start, cpu = time.perf_counter(), time.process_time()
    with threads_limited(threads), numba_threads_at_most(threads):
        values, info = job.compute(tile, threads)
    expected = (len(job.bands), *tile.core_shape)
    if values.shape != expected:  # pragma: no cover - a stage's bug, not the user's
        raise ProcessingError(f"{job.stage}: {tile.describe()} gave shape {values.shape}, "
                              f"expected {expected}")
    info = {**info, "seconds": round(time.perf_counter() - start, 3),
            "cpu_seconds": round(time.process_time() - cpu, 3)}  # of the whole process
    cache.store(tile, values, info)
    return {"index": tile.index, **info}


def tile_failure(job: TileJob, tile: Tile, exc: BaseException, cache: TileCache,
                 finished: int) -> ProcessingError:
    """The one-line error of a failed tile (its bounds, the reason, what was kept)."""
    reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return ProcessingError(
        f"{job.stage}: {tile.describe()} failed: {reason}; {finished} finished tiles are "
        f"cached in {cache.folder}, run the same command again to compute only the rest")


def _interrupted(exc: BaseException) -> bool:
    """True when ``exc`` is, or was caused by, a KeyboardInterrupt (numba wraps it)."""
    current: BaseException | None = exc
    for _ in range(100):
        if current is None:
            return False
        if isinstance(current, KeyboardInterrupt):
            return True
        current = current.__cause__ or current.__context__
    return False
