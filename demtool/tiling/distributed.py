"""Running tile jobs: in this process, on a local Dask cluster, or on a running scheduler.

- One worker (``--workers 0`` or ``1``, no ``--scheduler``): the tiles run one after the
  other in this process, the compiled kernels using every core; Dask is not imported.
- ``--workers N`` (N ≥ 2): N tiles at a time on N threads of this process
  (:mod:`demtool.tiling.local_threads`), the compiled kernels of a tile using
  ``cores // N`` threads; for a job not declared ``thread_safe`` (or a numba whose
  threading layer cannot run kernels from two threads), a
  ``dask.distributed.LocalCluster`` of N worker *processes* (one task each at a time, so
  one tile's memory per process), with the same share of the cores.
- ``--scheduler ADDRESS``: the tiles are submitted to a running scheduler (one started in
  a batch job, or by ``dask-jobqueue``'s ``SLURMCluster``; docs/stages/scale.md); the workers
  must see the input files and the work folder at the same paths (a shared file system).

Every task computes one tile and saves its core in the :class:`demtool.tiling.TileCache`
itself, so the results never travel through the scheduler and the calling process holds
no more than one tile.  Tiles already cached are not submitted.  A tile that raises (or
whose worker dies) stops the run with the tile's bounds in the message; the tiles that
finished stay cached.  Progress: tiles done / total on a terminal, a log line every
``max(1, total // 10)`` tiles otherwise.
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Sequence
from typing import Any

from demtool.errors import ProcessingError
from demtool.tiling import Tile, TileCache, TileJob
from demtool.tiling.tasks import (  # noqa: F401 - their home for the stages' imports
    _interrupted,
    available_cores,
    compute_tile,
    threads_limited,
    tile_failure,
    usable_threads,
)

# A test hook (issue 46): with this set to a file path, the calling process writes that
# file once the first tile of the run is done and then waits (at most HOLD_SECONDS) for
# a signal, so an interrupt test hits a run that is certainly mid-work however busy the
# machine is, instead of racing the remaining tiles.
HOLD_ENV = "DEMTOOL_TEST_HOLD_AFTER_FIRST_TILE"
HOLD_SECONDS = 300.0
CONNECT_TIMEOUT = "20s"  # waiting for a --scheduler that does not answer
# No dashboard; the scheduler's HTTP routes on a free port (not 8787, which another
# cluster on the machine may hold).
# Workers ignore Ctrl-C (demtool's process handles it) and Dask logs only what is fatal:
# an interrupt or a failed tile is reported by demtool in one line (issue 31).
LOCAL_CLUSTER_OPTIONS = {"dashboard_address": None, "processes": True,
                         "threads_per_worker": 1,
                         "scheduler_kwargs": {"dashboard_address": ":0"},
                         "preload": ["demtool.tiling.worker_signals"],
                         "silence_logs": logging.CRITICAL}
# Dask's own periodic work that a local cluster of equal tiles does not need: the
# workers' statistical profiler (a stack sample every 10 ms), the event-loop tick monitor
# of every server (every 20 ms) and work stealing (tasks are equal, one per worker at a
# time).  2048², tiles 1024, 2 workers, loaded machine, alternated: CPU of the process
# tree 8.5 / 9.5 s against 9.3 / 11.3 s with Dask's defaults.
LOCAL_CLUSTER_CONFIG = {"distributed.worker.profile.enabled": False,
                        "distributed.admin.tick.interval": "1s",
                        "distributed.scheduler.work-stealing": False}


class Progress:
    """Tiles done / total: a redrawn line on a terminal, a log line per step in batch."""

    def __init__(self, total: int, done: int, log: logging.Logger, what: str,
                 on_tile: Any = None) -> None:
        self.total, self.done, self.log, self.what = total, done, log, what
        self.on_tile = on_tile  # called (no arguments) in this thread after each tile
        self.step = max(1, total // 10)
        self.start = time.perf_counter()
        self.terminal = sys.stderr.isatty() and log.isEnabledFor(logging.INFO)
        self.held = False  # the test hook of HOLD_ENV ran

    def advance(self) -> None:
        self.done += 1
        elapsed = time.perf_counter() - self.start
        if self.terminal:
            sys.stderr.write(f"\r{self.what}: {self.done}/{self.total} tiles  {elapsed:6.1f} s")
            if self.done == self.total:
                sys.stderr.write("\n")
            sys.stderr.flush()
        elif self.done % self.step == 0 or self.done == self.total:
            self.log.info("%s: %d/%d tiles, %.1f s", self.what, self.done, self.total, elapsed)
        if self.on_tile is not None:
            self.on_tile()
        if not self.held:
            self.held = True
            hold_for_a_signal()


def hold_for_a_signal() -> None:
    """The test hook of :data:`HOLD_ENV`: announce "mid-run" in a file, then wait for the
    signal the test sends (which raises here, as anywhere else in the run)."""
    import os
    from pathlib import Path

    marker = os.environ.get(HOLD_ENV)
    if not marker:
        return
    Path(marker).write_text("holding\n")
    deadline = time.monotonic() + HOLD_SECONDS
    while time.monotonic() < deadline:
        time.sleep(0.05)


def run_tiles(job: TileJob, tiles: Sequence[Tile], cache: TileCache, *, workers: int = 0,
              scheduler: str | None = None, log: logging.Logger | None = None,
              on_tile: Any = None) -> list[dict[str, Any]]:
    """Compute every tile not yet in ``cache``; return the info of all of them.

    Parameters
    ----------
    job : TileJob
        The stage's tile computation (picklable, for worker processes).
    tiles : sequence of Tile
        The plan (:func:`demtool.tiling.plan_tiles`).
    cache : TileCache
        Where each finished tile's core is saved (and found again on a resumed run).
    workers : int
        0 or 1: one tile after the other in this process; N ≥ 2: N tiles at a time, on
        threads of this process (:func:`demtool.tiling.local_threads.runs_on_threads`)
        or on a local cluster of N processes.
    scheduler : str, optional
        Address of a running ``dask.distributed`` scheduler (overrides ``workers``).
    log : logging.Logger, optional
    on_tile : callable, optional
        Called without arguments in this thread once before the tiles are computed and
        after each one (e.g. to write the finished tiles in order while the others run).

    Returns
    -------
    list of dict
        Per tile, in index order: ``index``, ``seconds`` (compute time; cached tiles
        keep the time of the run that computed them) and the job's own info.

    Raises
    ------
    ProcessingError
        A tile failed (its bounds and reason; the finished tiles stay cached).
    """
    log = log or logging.getLogger("demtool.tiling")
    todo = [t for t in tiles if not cache.done(t)]
    if len(todo) < len(tiles):
        log.info("%d of %d tiles found in %s; computing %d", len(tiles) - len(todo),
                 len(tiles), cache.folder, len(todo))
    progress = Progress(len(tiles), len(tiles) - len(todo), log, job.stage, on_tile)
    if on_tile is not None:
        on_tile()  # the tiles found in the cache
    if todo:
        if scheduler:
            _run_on_client(job, todo, cache, progress, scheduler=scheduler, workers=0)
        elif workers >= 2:
            from demtool.tiling.local_threads import run_on_threads, runs_on_threads

            if runs_on_threads(job, workers, None):
                run_on_threads(job, todo, cache, progress, workers)
            else:
                _run_on_client(job, todo, cache, progress, scheduler=None, workers=workers)
        else:
            _run_here(job, todo, cache, progress)
    return [{"index": t.index, **cache.info(t)} for t in tiles]


def _run_here(job: TileJob, todo: Sequence[Tile], cache: TileCache, progress: Progress) -> None:
    finished = progress.done
    for tile in todo:
        try:
            compute_tile(job, tile, cache, 0)
        except Exception as exc:
            if _interrupted(exc):  # Ctrl-C / SIGTERM wrapped by numba: stop, not "failed"
                raise
            raise tile_failure(job, tile, exc, cache, finished) from exc
        finished += 1
        progress.advance()


def _forkserver_modules(preload: Sequence[str], job_module: str) -> list[str]:
    """What the workers' forkserver imports: Dask, the numeric stack and the job's own."""
    return ["distributed", "numpy", "scipy", "rasterio", "numba", job_module, *preload]


def prestart_local_workers(job_class: Any, workers: int, scheduler: str | None = None,
                           dry_run: bool = False) -> bool:
    """Start the forkserver of a local cluster's workers now, in the background.

    The server imports the job's modules (and runs what they run at import, e.g.
    :mod:`demtool.sgm.warm`) while this process goes on planning the tiles; the cluster
    started later (:func:`_run_on_client`) forks its workers from it.  Nothing for one
    worker, a ``--scheduler``, a dry run, a job whose tiles run on threads or a platform
    without forkserver.  Returns
    True when a server was started (or was running).
    """
    import multiprocessing

    if scheduler or dry_run or workers < 2:
        return False
    from demtool.tiling.local_threads import runs_on_threads

    if runs_on_threads(job_class, workers, scheduler):  # no processes to start
        return False
    if "forkserver" not in multiprocessing.get_all_start_methods():  # pragma: no cover
        return False
    from multiprocessing import forkserver

    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(_forkserver_modules(getattr(job_class, "preload", ()),
                                                       job_class.__module__))
    forkserver.ensure_running()  # returns once the server process is spawned
    return True


def _start_workers_from_a_forkserver(stack: Any, job: TileJob) -> None:
    """Local workers forked from one server process that imported the job's modules once.

    Dask spawns each worker process by default, and each imports numpy, rasterio and
    the stage's kernels again; a ``forkserver`` (a clean process, no threads inherited)
    imports them once and forks the workers from it.  Not on platforms without it.
    """
    import multiprocessing

    import dask

    if "forkserver" not in multiprocessing.get_all_start_methods():
        return
    stack.enter_context(dask.config.set({"distributed.worker.multiprocessing-method":
                                         "forkserver"}))
    from distributed.utils import get_mp_context

    get_mp_context().set_forkserver_preload(
        _forkserver_modules(getattr(job, "preload", ()), type(job).__module__))


def _run_on_client(job: TileJob, todo: Sequence[Tile], cache: TileCache, progress: Progress,
                   *, scheduler: str | None, workers: int) -> None:
    import contextlib

    from distributed import Client, LocalCluster, as_completed

    with contextlib.ExitStack() as stack:
        if scheduler:
            try:
                client = stack.enter_context(Client(scheduler, timeout=CONNECT_TIMEOUT))
            except (OSError, TimeoutError, ValueError) as exc:  # ValueError: not an address
                raise ProcessingError(f"--scheduler {scheduler}: cannot connect to the Dask "
                                      f"scheduler ({exc})") from None
            threads = 0  # the worker's own cores (start workers with --nthreads 1)
        else:
            threads = max(1, available_cores() // workers)
            import dask

            stack.enter_context(dask.config.set(LOCAL_CLUSTER_CONFIG))
            _start_workers_from_a_forkserver(stack, job)
            cluster = stack.enter_context(LocalCluster(
                n_workers=workers, memory_limit=0, **LOCAL_CLUSTER_OPTIONS))
            client = stack.enter_context(Client(cluster))
        import hashlib

        # Task keys unique to this work folder (so two runs on one scheduler never share).
        run_id = hashlib.sha256(str(cache.folder.resolve()).encode()).hexdigest()[:12]
        by_key = {}
        futures = []
        for tile in todo:
            future = client.submit(compute_tile, job, tile, cache, threads, pure=False,
                                   key=f"{job.stage}-{run_id}-tile-{tile.index}")
            by_key[future.key] = tile
            futures.append(future)
        finished = progress.done
        try:
            for future in as_completed(futures):
                tile = by_key[future.key]
                if future.status != "finished":
                    exc = future.exception()
                    client.cancel(futures)
                    raise tile_failure(job, tile, exc, cache, finished) from None
                finished += 1
                progress.advance()
        except KeyboardInterrupt:
            # Ctrl-C / SIGTERM: a shared scheduler must not go on with this run's queued
            # tiles (the ones running finish and land in the cache, written atomically)
            with contextlib.suppress(Exception):
                client.cancel(futures)
            raise
