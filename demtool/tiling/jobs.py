"""Tiled runs of the stages: one function that every tiled runner calls.

:func:`run_tiled` is the whole life of a tiled run once a stage has built its
:class:`demtool.tiling.TileJob` and :class:`demtool.tiling.Tiling`: take the output's
lock, find the work folder of these inputs and parameters, answer ``--dry-run`` (the
plan, the memory per worker, a calibration tile's time), compute the missing tiles
(:func:`demtool.tiling.distributed.run_tiles`), write every output window by window inside one
output transaction with the sidecar, then drop the work folder.  The per-stage jobs live
beside it (:mod:`demtool.sgm.tiled`, ...).

Adding a stage (e.g. ``mapproject``): write a picklable job class with ``stage``,
``bands``, ``compute(tile, threads) -> ((B, h, w) float32 core, info)`` and
``memory_bytes(tile)``; read only the tile's outer window of each input
(:func:`demtool.tiling.read_window`); plan the tiles with margins that cover the
stage's footprint (for ``mapproject``: the output grid is tiled, each tile reads the
image window its footprint needs, so margins are 0 and the input window comes from
projecting the tile's corners); then one call to :func:`run_tiled` from the runner when
:func:`demtool.tiling.wants_tiles` says so.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from demtool.tiling import (
    TileCache,
    TileJob,
    Tiling,
    cache_key,
    estimate_text,
    output_lock,
    work_folder,
    write_tiled_raster,
)


@dataclass
class TiledOutput:
    """One raster a tiled run writes: a band of the job's tiles (or several, for a
    multi-band file), its tags and name(s), and its compression (a key of
    :data:`demtool.tiling.COMPRESSIONS`: the one the stage's untiled path writes)."""

    path: str | os.PathLike
    band: int | Sequence[int]
    tags: Mapping[str, Any]
    band_name: str | Sequence[str]
    compress: str = "deflate"


@dataclass
class TiledResult:
    """What a tiled run did: the plan, per-tile infos, the summary, or the dry-run text."""

    tiling: Tiling
    tiles: list[dict[str, Any]] = field(default_factory=list)
    summary: dict[str, Any] = field(default_factory=dict)
    dry_run: str | None = None


def run_tiled(run: Any, job: TileJob, tiling: Tiling, outputs: Sequence[TiledOutput], *,
              inputs: Sequence[str | os.PathLike], parameters: Mapping[str, Any],
              transform=None, crs=None, workers: int = 0, scheduler: str | None = None,
              dry_run: bool = False, summarize=None, prepare=None) -> TiledResult:
    """Run ``job`` on ``tiling`` and write ``outputs`` (see the module docstring).

    Parameters
    ----------
    run : demtool.stagerun.StageRun
        The stage's run (its log and provenance).
    job, tiling
        What to compute on which tiles.
    outputs : sequence of TiledOutput
        The first is the main output (its sidecar ``<path>.json`` is written).
    inputs : sequence of path-like
        The files the tiles read (their SHA-256 keys the work folder).
    parameters : mapping
        The stage's parameters (they key the work folder too).
    transform, crs
        Georeferencing of the outputs.
    workers, scheduler
        See :func:`demtool.tiling.distributed.run_tiles`.
    dry_run : bool
        Plan and time one tile; write nothing.
    summarize : callable, optional
        ``summarize(tiles_info) -> dict``: the stage's summary for the sidecar.
    prepare : callable, optional
        ``prepare(job, folder) -> job``: earlier passes a stage needs before its tiles
        (``dem``: the samples' statistics, the measured grid, a coarse global solve),
        run under the lock when some tile is missing, with the work folder to keep
        their own resumable results in; returns the job to run.

    Raises
    ------
    InputError
        Another run holds the output's lock.
    ProcessingError
        A tile failed (nothing written, finished tiles stay cached).
    """
    from demtool import io as dio
    from demtool.outputs import check_output_paths
    from demtool.tiling.distributed import available_cores, run_tiles
    from demtool.tiling.local_threads import executor

    main = Path(outputs[0].path)
    declared_inputs = {label: path for label, paths in run.inputs.items()
                       for path in paths}
    declared_outputs = {f"output {i + 1}": o.path for i, o in enumerate(outputs)}
    declared_outputs["sidecar"] = f"{main}.json"
    # Before hours of tiles: an output over an input, or one that cannot be written.
    check_output_paths(declared_inputs, declared_outputs)
    key = cache_key(inputs, parameters, tiling, {"outputs": [o.band for o in outputs]})
    cache = TileCache(work_folder(main) / key)
    run.log.info("%s", tiling.describe())
    memory = max(job.memory_bytes(t) for t in tiling.tiles)
    if dry_run:
        tile = max(tiling.tiles, key=lambda t: t.outer_shape[0] * t.outer_shape[1])
        cached = sum(cache.done(t) for t in tiling.tiles)
        start = time.perf_counter()
        job.compute(tile, 0)
        seconds = time.perf_counter() - start
        text = estimate_text(tiling, memory, available_cores(), seconds, cached)
        run.log.info("dry run, nothing written:\n%s", text)
        return TiledResult(tiling, dry_run=text)
    with output_lock(main), contextlib.ExitStack() as streaming:
        start, process_cpu = time.perf_counter(), time.process_time()
        if prepare is not None and not all(cache.done(t) for t in tiling.tiles):
            job = prepare(job, cache.folder)
        writer = None
        where = executor(job, workers, scheduler)
        if getattr(job, "stream_outputs", False) and (scheduler or workers >= 2):
            # the outputs open in the transaction now; each tile is written as soon as it
            # and every tile before it are done, while the workers compute the rest
            streaming.enter_context(dio.output_transaction(declared_inputs, declared_outputs))
            writer = _InOrderWriter(streaming.enter_context(contextlib.ExitStack()), outputs,
                                    tiling, cache, transform, crs)
            if where == "threads":
                # the writer takes the tiles computed here from memory, not from their
                # files (written all the same, for a rerun); the next few only, so a
                # slow tile does not hold the later ones in memory
                cache.hand_over(2 * workers)
        infos = run_tiles(job, tiling.tiles, cache, workers=workers, scheduler=scheduler,
                          log=run.log, on_tile=writer.advance if writer else None)
        wall = time.perf_counter() - start
        process_cpu = time.process_time() - process_cpu
        seconds = [float(i.get("seconds", 0.0)) for i in infos]
        # a tile's "cpu_seconds" is its process's CPU while it ran: tiles on threads of
        # this process overlap, so their sum would count the run N times; there the run's
        # own process CPU is the tiles' CPU (workers' processes report their tiles')
        tile_cpu = (process_cpu if where in ("this process", "threads")
                    else sum(float(i.get("cpu_seconds", 0)) for i in infos))
        summary = dict(summarize(infos) if summarize else {})
        summary["tiling"] = {"tiles": len(tiling.tiles), "tile_size": tiling.tile_size,
                             "margins_top_bottom_left_right": list(tiling.margins),
                             "workers": workers, "scheduler": scheduler,
                             "executor": where,
                             "tile_seconds_sum": round(sum(seconds), 3),
                             "tile_seconds_max": round(max(seconds), 3),
                             "tile_cpu_seconds_sum": round(tile_cpu, 3),
                             "tiles_wall_s": round(wall, 3)}
        if writer is not None:
            tail = time.perf_counter()
            writer.finish()  # the rasters closed (laid out), then the sidecar
            summary["tiling"]["write_after_tiles_s"] = round(time.perf_counter() - tail, 3)
            run.provenance.write_sidecar(main, summary, outputs=[o.path for o in outputs])
            streaming.close()  # the transaction: every output appears now
        else:
            with dio.output_transaction(declared_inputs, declared_outputs):
                for output in outputs:
                    write_tiled_raster(output.path, tiling, cache, band=output.band,
                                       transform=transform, crs=crs, tags=output.tags,
                                       band_name=output.band_name,
                                       compress=output.compress)
                run.provenance.write_sidecar(main, summary,
                                             outputs=[o.path for o in outputs])
        cache.remove()
        _remove_stale_caches(work_folder(main), run.log)
    return TiledResult(tiling, infos, summary)


class _InOrderWriter:
    """The outputs of a tiled run, open while its tiles are computed: each call of
    :meth:`advance` writes the finished tiles that follow the last one written, in index
    order (the bytes of :func:`demtool.tiling.write_tiled_raster`'s file), so only the
    tiles after the last to finish and the overviews are left when the workers are done.
    """

    def __init__(self, stack: Any, outputs: Sequence[TiledOutput], tiling: Tiling,
                 cache: TileCache, transform: Any, crs: Any) -> None:
        from demtool.tiling import tiled_raster_output

        self.stack, self.tiling, self.cache = stack, tiling, cache
        self.writers = [stack.enter_context(tiled_raster_output(
            o.path, tiling, band=o.band, transform=transform, crs=crs, tags=o.tags,
            band_name=o.band_name, compress=o.compress)) for o in outputs]
        self.next = 0

    def advance(self) -> None:
        tiles = self.tiling.tiles
        while self.next < len(tiles) and self.cache.done(tiles[self.next]):
            for writer in self.writers:
                writer.write(tiles[self.next], self.cache)
            self.cache.release(tiles[self.next])
            self.next += 1

    def finish(self) -> None:
        """Write the tiles left, then close the rasters (overviews, layout)."""
        from demtool.errors import ProcessingError

        self.advance()
        if self.next != len(self.tiling.tiles):  # pragma: no cover - run_tiles' bug
            raise ProcessingError(f"tile {self.next} is missing from {self.cache.folder}")
        self.stack.close()


def _remove_stale_caches(folder: Path, log: Any) -> None:
    """After a finished run: the tile caches left in the output's work folder by runs of
    other inputs or parameters (they can only be reused by rerunning those), removed
    with a log line (issue 31: no cache of other inputs stays behind)."""
    import shutil

    if not folder.is_dir():
        return
    stale = sorted(p.name for p in folder.iterdir())
    if stale:
        log.info("removing %d tile cache(s) of other inputs or parameters from %s: %s",
                 len(stale), folder, ", ".join(stale))
    shutil.rmtree(folder, ignore_errors=True)
