"""``demtool fuse`` in tiles: each tile reads only its window of every DEM.

The fused grid is cut into tiles (:func:`demtool.tiling.plan_tiles`); a tile samples
each DEM (and its error raster) on its outer window only — the source window its cells
fall in, read with :func:`demtool.tiling.read_window` — shifted by that DEM's
co-registration, computes the border weights there and combines the core
(:func:`demtool.fuse.core.combine`).  Sampling and combination are cell-local; the
border weights depend on the cells within ``--blend`` of a cell, so a margin of
``--blend + 2 × --gap + 2`` cells makes a tile's core equal, to the last bit, to the same cells of
the untiled run (which is this job on one tile covering the grid).  Peak memory is one
tile's outer window × (DEMs × ~8 float64 arrays) per worker, never the grid; 2 workers
on two 8192² DEMs: bench/fuse_memory.py.

Inside one tile (the untiled run's single tile included) the work runs on every core the
tile may use (:func:`demtool.tiling.distributed.usable_threads`): a tile of at least
:data:`THREADED_CELLS` cells is cut into row strips, each with the same margin, computed on
a pool of threads (numpy, scipy's distance transform, GDAL's reads and the compiled
sampler release the GIL) and stacked; by the margin argument above the strips give the
tile's numbers to the last bit.  A smaller tile (the demo's) runs as one strip.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from demtool.tiling import Tile, plan_tiles, read_window

PROCESS_BYTES = 200 * 2**20  # a worker process with numpy, numba, scipy and rasterio
BYTES_PER_CELL_PER_DEM = 80  # values, weights, errors, EDT, sampling coordinates (float64)
#: A tile's core with fewer cells runs in one thread: below this the strips' margins and
#: the pool cost more than the second core saves (the demo's 512² grids).
THREADED_CELLS = 1 << 20
STRIPS_PER_THREAD = 1  # strips per thread (each strip recomputes its margins)


@dataclass(frozen=True)
class GridSpec:
    """A picklable grid: ``shape`` (rows, columns), the affine transform's 6 numbers
    (a, b, c, d, e, f) and the CRS as WKT (None: no CRS)."""

    shape: tuple[int, int]
    transform: tuple[float, float, float, float, float, float]
    crs_wkt: str | None = None

    @classmethod
    def of(cls, shape, transform, crs) -> GridSpec:
        t = transform
        return cls((int(shape[0]), int(shape[1])), (t.a, t.b, t.c, t.d, t.e, t.f),
                   None if crs is None else crs.to_wkt())

    def affine(self):
        from affine import Affine

        return Affine(*self.transform)

    def crs(self):
        if self.crs_wkt is None:
            return None
        from rasterio.crs import CRS

        return CRS.from_wkt(self.crs_wkt)

    def grid(self):
        """The :class:`demtool.compare.grids.Grid` of this spec."""
        from demtool.compare.grids import Grid

        return Grid(shape=self.shape, transform=self.affine(), crs=self.crs())


def sample_on_grid(path: str | os.PathLike, src: GridSpec, dst: GridSpec,
                   window: tuple[int, int, int, int], shift: Sequence[float] = (0, 0, 0),
                   *, what: str = "DEM") -> np.ndarray:
    """A raster resampled onto cells ``window`` of ``dst``, shifted, read by window.

    Parameters
    ----------
    path : path-like
        The raster, on grid ``src``.
    src, dst : GridSpec
    window : (row0, row1, col0, col1)
        Cells of ``dst``, half-open.
    shift : (dx_px, dy_px, dz)
        Co-registration: ``out[r, c] = raster(r − dy, c − dx) + dz`` in ``dst`` cells (x
        right, y down) and metres (pass dz = 0 for an error raster).
    what : str
        What the raster is, for messages.

    Returns
    -------
    (row1 − row0, col1 − col0) float64
        NaN-aware bilinear samples (:func:`demtool.compare.grids.sample_bilinear`);
        NaN outside the raster.  A cell's value does not depend on the window.
    """
    from affine import Affine

    from demtool.compare.grids import Grid, sample_bilinear, source_pixels

    dx, dy, dz = (float(v) for v in shift)
    shifted = Grid(shape=dst.shape, transform=dst.affine() @ Affine.translation(-dx, -dy),
                   crs=dst.crs())
    rows, cols = source_pixels(src.grid(), shifted, window)
    out = np.full(rows.shape, np.nan)
    finite = np.isfinite(rows) & np.isfinite(cols)
    if not finite.any():
        return out
    height, width = src.shape
    r0 = max(0, int(math.floor(rows[finite].min())) - 1)
    r1 = min(height, int(math.floor(rows[finite].max())) + 2)
    c0 = max(0, int(math.floor(cols[finite].min())) - 1)
    c1 = min(width, int(math.floor(cols[finite].max())) + 2)
    if r0 >= r1 or c0 >= c1:
        return out
    values = read_window(path, (r0, r1, c0, c1), what=what)
    return sample_bilinear(values, rows - r0, cols - c0) + dz


@dataclass(frozen=True)
class FuseTileJob:
    """Fuse one tile (picklable: paths and plain values only).

    ``errors[i]`` is DEM i's error raster (None: none); ``grids[i]`` its grid;
    ``shifts[i]`` its (dx_px, dy_px, dz) on ``target``.
    """

    dems: tuple[str, ...]
    errors: tuple[str | None, ...]
    grids: tuple[GridSpec, ...]
    shifts: tuple[tuple[float, float, float], ...]
    target: GridSpec
    method: str
    outlier_k: float
    blend: float
    gap: float
    weights_exponent: float
    min_error: float
    scale_floor: float = 0.0
    stage: str = "fuse"
    # local --workers: tiles on threads (demtool.tiling.local_threads; audited: nogil
    # kernels, numba threads per thread, strips on usable_threads())
    thread_safe: ClassVar[bool] = True
    bands: tuple[str, ...] = ("dem", "count", "spread", "error")

    def compute(self, tile: Tile, threads: int) -> tuple[np.ndarray, dict[str, Any]]:
        """Fuse ``tile``'s core: ``(4, rows, cols)`` float32 bands and counts; in row
        strips on threads where the tile is large (see the module docstring)."""
        from demtool.tiling.distributed import usable_threads

        start, cpu = time.perf_counter(), time.process_time()
        # numba's count and usable_threads(): a worker's share, set by tiling's compute_tile
        strips = row_strips(tile, self.target.shape, exact_margin(self.blend, self.gap),
                            usable_threads())
        parts = on_threads(self._compute_strip, strips)
        bands = np.concatenate([p[0] for p in parts], axis=1)
        info = {key: sum(p[1][key] for p in parts) for key in ("cells", "kept", "offered")}
        info.update({"strips": len(strips), "seconds": time.perf_counter() - start,
                     "cpu_seconds": time.process_time() - cpu})
        return bands, info

    def _compute_strip(self, tile: Tile) -> tuple[np.ndarray, dict[str, Any]]:
        from demtool.fuse.core import border_weights, combine

        values, weights, errors = [], [], []
        use_errors = all(e is not None for e in self.errors)
        for i, path in enumerate(self.dems):
            dem = sample_on_grid(path, self.grids[i], self.target, tile.outer, self.shifts[i])
            valid = np.isfinite(dem)
            weight = border_weights(valid, blend_px=self.blend, exponent=self.weights_exponent,
                                    gap_px=self.gap)
            crop = tile.crop
            values.append(dem[crop])
            weights.append(weight[crop])
            if use_errors:
                dx, dy, _ = self.shifts[i]
                errors.append(sample_on_grid(self.errors[i], self.grids[i], self.target,
                                             tile.core, (dx, dy, 0.0), what="error raster"))
        result = combine(np.stack(values), np.stack(weights),
                         np.stack(errors) if use_errors else None, method=self.method,
                         outlier_k=self.outlier_k, min_error=self.min_error,
                         scale_floor=self.scale_floor)
        count = result.count
        info = {"cells": int(np.count_nonzero(count > 0)),
                "kept": float(count.sum()),
                "offered": float(sum(np.count_nonzero(np.isfinite(v)) for v in values))}
        return np.stack([result.dem, result.count, result.spread, result.error]), info

    def memory_bytes(self, tile: Tile) -> int:
        h, w = tile.outer_shape
        return PROCESS_BYTES + BYTES_PER_CELL_PER_DEM * h * w * len(self.dems)


def exact_margin(blend: float, gap: float) -> int:
    """The border weights' reach, cells (blending length plus the gap closing's two
    passes) plus two: a tile or strip with this margin gives the untiled numbers."""
    return int(math.ceil(blend + 2 * gap)) + 2


def margin(params: Any) -> int:
    """The margin of a fuse tile, cells: ``--tile-overlap``, or :func:`exact_margin`."""
    if params.tile_overlap is not None:
        return int(params.tile_overlap)
    return exact_margin(params.blend, params.gap)


def on_threads(function: Callable[[Any], Any], items: Sequence[Any]) -> list[Any]:
    """``[function(item) for item in items]``, on threads when there are two items or
    more and cores for them (:func:`demtool.tiling.rows.ordered_map` on
    ``min(usable_threads(), len(items))`` threads, each call with its share of numba's
    threads, as on the calling thread), else in order here.

    For independent jobs of similar size, such as the co-registration of each DEM to the
    reference: each runs as it would alone, with the same numbers (the compiled
    reductions sum per row, whatever the thread count).  In order here too where numba's
    threading layer cannot launch kernels from several threads at once
    (:func:`demtool.tiling.local_threads.kernels_run_concurrently`, which starts the
    layer without compiling a kernel).
    """
    from demtool.tiling.distributed import usable_threads
    from demtool.tiling.local_threads import kernels_run_concurrently
    from demtool.tiling.rows import ordered_map

    threads = min(usable_threads(), len(items))
    if threads < 2 or not kernels_run_concurrently():
        threads = 1
    return list(ordered_map(function, items, threads=threads))


def row_strips(tile: Tile, shape: tuple[int, int], margin: int, threads: int) -> list[Tile]:
    """``tile``'s core cut into row strips for ``threads`` threads, each strip's outer
    window its core ± ``margin`` rows (clipped to the grid ``shape``) and the tile's outer
    columns; ``[tile]`` itself for one thread or a core under :data:`THREADED_CELLS`."""
    rows, cols = tile.core_shape
    if threads < 2 or rows * cols < THREADED_CELLS:
        return [tile]
    height = max(4 * max(margin, 1), math.ceil(rows / (STRIPS_PER_THREAD * threads)))
    count = max(1, math.ceil(rows / height))
    if count == 1:
        return [tile]
    bounds = np.linspace(tile.core[0], tile.core[1], count + 1).round().astype(int)
    r0, r1, c0, c1 = tile.core
    return [Tile(tile.index, (int(a), int(b), c0, c1),
                 (max(0, int(a) - margin), min(shape[0], int(b) + margin), tile.outer[2],
                  tile.outer[3]))
            for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


def single_tile(shape: tuple[int, int]) -> Tile:
    """The untiled run's one tile covering the grid."""
    window = (0, int(shape[0]), 0, int(shape[1]))
    return Tile(0, window, window)


def fuse_tiled(run: Any, job: FuseTileJob, tile_size: int, params: Any,
               outputs: Sequence[tuple[str | os.PathLike, int, str, dict]],
               inputs: Sequence[str | os.PathLike], summary: dict[str, Any]):
    """Run ``job`` in tiles of ``tile_size`` and write ``outputs`` (path, band, name, tags).

    Returns the :class:`demtool.tiling.jobs.TiledResult`.
    """
    from demtool.tiling.jobs import TiledOutput, run_tiled

    tiling = plan_tiles(*job.target.shape, tile_size, overlap=margin(params))
    execution = ("workers", "scheduler", "dry_run")
    parameters = {k: v for k, v in params.as_dict().items() if k not in execution}
    parameters["shifts"] = [list(s) for s in job.shifts]

    def summarize(infos):
        cells = sum(i.get("cells", 0) for i in infos)
        kept = sum(i.get("kept", 0.0) for i in infos)
        offered = sum(i.get("offered", 0.0) for i in infos)
        return {**summary, "cells": int(cells),
                "rejected_fraction": float(1 - kept / offered) if offered else 0.0}

    return run_tiled(run, job, tiling,
                     [TiledOutput(path, band, tags, name) for path, band, name, tags in outputs],
                     inputs=inputs, parameters=parameters, transform=job.target.affine(),
                     crs=job.target.crs(), workers=params.workers, scheduler=params.scheduler,
                     dry_run=params.dry_run, summarize=summarize)
