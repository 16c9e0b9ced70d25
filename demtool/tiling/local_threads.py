"""Local ``--workers N``: the tiles on N threads of this process.

The compiled kernels of the tiled stages release the GIL (numba ``nogil``, numpy's
array loops, scipy.fft, GDAL's reads), so N tiles computed at once on N threads of one
process overlap as well as N worker processes do, without what a local Dask cluster
costs before its first tile: a scheduler, a nanny and a worker per process, their
imports and each worker loading the kernels again (3–6 CPU s and 2–4 s of wall time on
2 cores, issue 47).  Dask's own advice for code that releases the GIL is the same:
threads in one process.

Each tile runs in a copy of the calling thread's context (``contextvars``: the output
layout, numpy's error state), with :func:`demtool.tiling.distributed.usable_threads`
and numba's thread count (per thread in numba) at ``cores // N``.  The calling thread
alone reports progress and calls ``on_tile`` (the in-order writer); the pool threads
only compute and save their tile in the :class:`demtool.tiling.TileCache`.

Stopping: after a failed tile no queued tile starts; the tiles running finish (and
stay cached) before the one-line failure is raised.  After Ctrl-C/SIGTERM (raised in
the calling thread) no queued tile starts and the running ones are abandoned: the pool
threads are daemons, so the process exits at once; a tile finishing meanwhile lands in
the cache complete (:meth:`demtool.tiling.TileCache.store` renames a finished file) and
the outputs, written only in the run's output transaction, are rolled back.  Any other
failure of the calling thread (the in-order writer's) waits for the running tiles too.

A job runs here only if its class says ``thread_safe = True`` (audited: no process-wide
state changed by its compute, no GIL held for long); others, and every job when
numba's threading layer cannot launch parallel kernels from two threads at once
(``workqueue``), or when :data:`PROCESSES_ENV` is set, run on a local Dask cluster of
processes (:func:`demtool.tiling.distributed.run_tiles`).
"""

from __future__ import annotations

import contextvars
import logging
import queue
import threading
from collections.abc import Sequence
from typing import Any

from demtool.tiling import Tile, TileCache, TileJob

#: seconds between the calling thread's checks for signals while it waits for tiles
POLL_SECONDS = 0.1
#: set (to anything but 0) to run local ``--workers N`` on a Dask cluster of N processes
#: whatever the job (docs/stages/scale.md: isolating a tile that crashes its process)
PROCESSES_ENV = "DEMTOOL_TILE_PROCESSES"


def executor(job: TileJob, workers: int, scheduler: str | None) -> str:
    """Where the tiles of a run go: ``"this process"`` (one after the other),
    ``"threads"``, ``"processes"`` (a local Dask cluster) or ``"scheduler"``."""
    if scheduler:
        return "scheduler"
    if workers < 2:
        return "this process"
    return "threads" if runs_on_threads(job, workers, scheduler) else "processes"


def kernels_run_concurrently() -> bool:
    """Whether numba's threading layer takes parallel kernels launched from several
    threads at once (``omp``, ``tbb``; the ``workqueue`` fallback aborts the process).

    Starts the layer if no parallel kernel has run yet (no compilation: the layer's
    thread pool only)."""
    import numba

    try:
        return numba.threading_layer() != "workqueue"
    except ValueError:  # not started yet
        pass
    try:
        from numba.np.ufunc import parallel

        parallel._launch_threads()
        return numba.threading_layer() != "workqueue"
    except Exception:  # pragma: no cover - a numba without this (private) entry point
        return False


def runs_on_threads(job: TileJob, workers: int, scheduler: str | None) -> bool:
    """True when a run of ``job`` with ``--workers workers`` computes its tiles on
    threads of this process (:func:`run_on_threads`): N ≥ 2 local workers, a job whose
    class declares ``thread_safe = True``, :data:`PROCESSES_ENV` not set and a numba
    that runs kernels concurrently."""
    import os

    if scheduler or workers < 2 or not getattr(job, "thread_safe", False):
        return False
    if os.environ.get(PROCESSES_ENV, "").strip() not in ("", "0"):
        return False
    if not kernels_run_concurrently():
        logging.getLogger("demtool.tiling").info(
            "numba's threading layer is 'workqueue' (install tbb or use a numba with "
            "OpenMP for tiles on threads): the %d workers are processes", workers)
        return False
    return True


def run_on_threads(job: TileJob, todo: Sequence[Tile], cache: TileCache, progress: Any,
                   workers: int) -> None:
    """Compute ``todo`` on ``workers`` threads of this process, each tile saved in
    ``cache``; ``progress.advance()`` in the calling thread after each (see the module
    docstring for failures and interrupts).

    Raises
    ------
    ProcessingError
        A tile failed: its bounds, the reason, the tiles cached.
    """
    from rasterio.errors import NotGeoreferencedWarning

    from demtool.io.quiet import ignoring
    from demtool.tiling.tasks import _interrupted, available_cores, compute_tile, tile_failure

    threads = max(1, available_cores() // workers)
    pending: queue.SimpleQueue[Tile] = queue.SimpleQueue()
    for tile in todo:
        pending.put(tile)
    done: queue.SimpleQueue[tuple[Tile, BaseException | None]] = queue.SimpleQueue()
    stop = threading.Event()
    context = contextvars.copy_context()

    def work() -> None:
        while not stop.is_set():
            try:
                tile = pending.get_nowait()
            except queue.Empty:
                return
            try:
                context.copy().run(compute_tile, job, tile, cache, threads)
            except BaseException as exc:  # reported by the calling thread
                stop.set()  # no queued tile starts after a failure
                done.put((tile, exc))
                return
            done.put((tile, None))

    pool = [threading.Thread(target=work, name=f"demtool-tile-{i}", daemon=True)
            for i in range(min(workers, len(todo)))]
    finished = progress.done
    # GDAL's NotGeoreferencedWarning on every image-frame read: the readers hold the
    # filter with demtool.io.quiet.ignoring (threads may hold it at once, no filter list
    # is swapped); held here too, it stays in place for the whole run
    with ignoring(NotGeoreferencedWarning):
        try:
            for thread in pool:
                thread.start()
            for _ in range(len(todo)):
                tile, exc = _next_result(done, pool)
                if exc is not None:
                    if _interrupted(exc):  # raised inside a tile (numba wraps it)
                        raise exc
                    finished += _finish_running(done, pool)
                    raise tile_failure(job, tile, exc, cache, finished) from exc
                finished += 1
                progress.advance()
        except BaseException as exc:
            stop.set()  # queued tiles never start
            if not _interrupted(exc):
                # a failure here (the in-order writer's full disk): the running tiles end
                # before the run's transaction, lock and volumes go, not behind them
                _finish_running(done, pool)
            raise
        finally:
            stop.set()


def _next_result(done: queue.SimpleQueue, pool: list[threading.Thread]
                 ) -> tuple[Tile, BaseException | None]:
    """The next finished tile, waiting in short slices (so Ctrl-C/SIGTERM are handled
    at once in this thread)."""
    while True:
        try:
            return done.get(timeout=POLL_SECONDS)
        except queue.Empty:
            if not any(thread.is_alive() for thread in pool) and done.empty():
                # pragma: no cover - a thread ended without reporting (cannot happen)
                raise RuntimeError("the tile threads stopped without a result") from None


def _finish_running(done: queue.SimpleQueue, pool: list[threading.Thread]) -> int:
    """After a failure: wait for the tiles still running; how many of them finished."""
    for thread in pool:
        while thread.is_alive():
            thread.join(POLL_SECONDS)
    finished = 0
    while not done.empty():
        _, exc = done.get_nowait()
        finished += exc is None
    return finished
