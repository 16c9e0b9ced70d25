"""``demtool mapproject`` on the tile engine: the map grid in tiles, each an independent task.

The output map grid is cut into tiles of ``--tile-size`` cells with no margins (every
map cell depends only on its own ground point and the image around where it projects);
each tile computes its cells' heights (a window of the DEM), their image coordinates
(:func:`demtool.mapproject.core.image_coordinates`) and reads only the image window its
samples touch (:func:`demtool.mapproject.core.image_window`).  :func:`project_window` is that
work for one window; the in-process loop of :func:`demtool.mapproject.run.run_mapproject`
(the default path) calls it on the same windows, so a run on the engine writes the same
values as one in this process (tests/test_tiled_mapproject.py checks they are equal).

The engine (:func:`demtool.tiling.jobs.run_tiled`) is used when :func:`engine_tile_size` says
so: ``--workers N`` (N ≥ 1: 1 = the tiles one after the other in this process, cached in
a work folder so a killed run resumes; N ≥ 2 = a local Dask cluster), ``--scheduler`` or
``--dry-run``, and a grid larger than one tile.
"""

from __future__ import annotations

import contextlib
import functools
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from demtool.tiling import Tile

PROCESS_BYTES = 250 * 2**20  # a worker process with numpy, numba, pyproj and rasterio
CELL_BYTES = 60  # heights, x, y, image coordinates, lattice buffers, the output (float64)
ANGLE_BANDS = ("incidence_deg", "emission_deg", "phase_deg")


def engine_tile_size(shape: tuple[int, int], params: Any) -> int:
    """The tile size of an engine run, or 0 for the in-process loop (the default).

    ``--scheduler`` and ``--dry-run`` always use the engine; ``--workers N`` (N ≥ 1) uses
    it when the grid is larger than one tile of ``--tile-size`` cells.
    """
    height, width = shape
    size = int(params.tile_size)
    if params.scheduler or params.dry_run:
        return size
    if params.workers >= 1 and (height > size or width > size):
        return size
    return 0


def _stamp(path: str) -> tuple[str, int, int]:
    """A file's path, modification time and size: a cache key that a rewritten file
    misses."""
    try:
        stat = os.stat(path)
    except OSError:  # not there: the reader says so (an error is never cached)
        return str(path), -1, -1
    return str(path), stat.st_mtime_ns, stat.st_size


def _sensor(path: str, radii: tuple[float, float] | None = None,
            image_size: tuple[int, int] | None = None):
    """The sensor model of ``path``, read once per process and file version (the runner
    and its tiles share it; read-only)."""
    return _sensor_of(_stamp(path), radii, image_size)


@functools.lru_cache(maxsize=4)
def _sensor_of(stamp: tuple[str, int, int], radii: tuple[float, float] | None,
               image_size: tuple[int, int] | None):
    from demtool.mapproject.tsai_body import with_image_size
    from demtool.sensors import read_sensor

    return with_image_size(read_sensor(stamp[0], radii=radii), image_size)


#: surfaces a runner holds in memory (:meth:`demtool.mapproject.surface.DemSurface.holding`)
#: while its tiles run in this process (:func:`holding_surface`), by :func:`_surface`'s key
_HELD: dict[tuple, Any] = {}


def _surface(dem_path: str, sensor_path: str, radii: tuple[float, float] | None = None,
             image_size: tuple[int, int] | None = None):
    """The DEM surface, read once per process and file versions (within
    :func:`holding_surface`: the runner's, with the DEM under the footprint in memory)."""
    key = (_stamp(dem_path), _stamp(sensor_path), radii, image_size)
    held = _HELD.get(key)
    return held if held is not None else _surface_of(*key)


@contextlib.contextmanager
def holding_surface(job: MapprojectTileJob, surface: Any) -> Iterator[None]:
    """Within the block, ``job``'s tiles computed in this process get ``surface`` (the
    runner's, holding the DEM under the footprint: the same values as read from the file;
    worker processes read the file)."""
    if job.dem_path is None or surface is None or surface.held is None:
        yield
        return
    key = (_stamp(job.dem_path), _stamp(job.sensor_path), job.sensor_radii,
           job.sensor_image_size)
    _HELD[key] = surface
    try:
        yield
    finally:
        _HELD.pop(key, None)


@functools.lru_cache(maxsize=4)
def _surface_of(dem: tuple[str, int, int], sensor: tuple[str, int, int],
                radii: tuple[float, float] | None, image_size: tuple[int, int] | None):
    from demtool.mapproject.core import sensor_body
    from demtool.mapproject.surface import read_dem_surface

    return read_dem_surface(dem[0], sensor[0],
                            sensor_body(_sensor(sensor[0], radii, image_size)))


@functools.lru_cache(maxsize=4)
def _crs(wkt: str):
    from pyproj import CRS

    return CRS.from_wkt(wkt)


@dataclass(frozen=True)
class MapprojectTileJob:
    """Map-project the cells of one map tile (picklable: paths and plain values only).

    Attributes
    ----------
    image_path, sensor_path : str
        The raw image and its sensor model.
    dem_path : str or None
        The DEM (heights above the body's sphere); None: ``height`` everywhere.
    height : float or None
        Constant surface height above the sphere, metres (with no DEM).
    crs_wkt : str
        The map grid's projected CRS (WKT).
    transform : 6 floats
        The map grid's affine transform (a, b, c, d, e, f).
    same_crs : bool
        The DEM is on the grid's CRS (heights read at map x, y, no lon/lat detour).
    step, tolerance, seed
        :func:`demtool.mapproject.core.image_coordinates`'s lattice options.
    angles : bool
        Also the incidence, emission and phase angles (three more bands).
    pixels_per_cell : float
        Image pixels per map cell (for the memory estimate).
    sensor_radii, sensor_image_size : tuple or None
        The body's (a, b) in metres and the image's (lines, samples) for a ``.tsai``
        file, which carries neither (:mod:`demtool.mapproject.tsai_body`); None otherwise.
    """

    image_path: str
    sensor_path: str
    dem_path: str | None
    height: float | None
    crs_wkt: str
    transform: tuple[float, ...]
    same_crs: bool
    step: int
    tolerance: float
    seed: int
    angles: bool = False
    pixels_per_cell: float = 1.0
    sensor_radii: tuple[float, float] | None = None
    sensor_image_size: tuple[int, int] | None = None
    stage: str = "mapproject"
    # local --workers: tiles on threads (demtool.tiling.local_threads; audited: nogil
    # kernels, numba threads per thread, the cached sensor model and DEM read-only)
    thread_safe: ClassVar[bool] = True
    # the outputs are written in tile order while the workers compute the later tiles
    # (demtool.tiling.jobs.run_tiled): compute() writes nothing through demtool.io
    stream_outputs: ClassVar[bool] = True
    preload: tuple[str, ...] = ("demtool.mapproject.core",)

    @property
    def bands(self) -> tuple[str, ...]:
        return ("ortho", *ANGLE_BANDS) if self.angles else ("ortho",)

    @property
    def crs(self):
        return _crs(self.crs_wkt)

    @property
    def affine(self):
        from affine import Affine

        return Affine(*self.transform)

    def compute(self, tile: Tile, threads: int) -> tuple[np.ndarray, dict[str, Any]]:
        # numba's thread count: the caller's (tiling.tasks.compute_tile sets a worker's)
        sensor = _sensor(self.sensor_path, self.sensor_radii, self.sensor_image_size)
        surface = (_surface(self.dem_path, self.sensor_path, self.sensor_radii,
                            self.sensor_image_size) if self.dem_path is not None else None)
        return project_window(self, sensor, surface, tile.core)

    def memory_bytes(self, tile: Tile) -> int:
        """The process, ~60 bytes a cell, and the image window (float32)."""
        cells = tile.core_shape[0] * tile.core_shape[1]
        return int(PROCESS_BYTES + cells * (CELL_BYTES + 4 * len(self.bands))
                   + 4 * cells * max(self.pixels_per_cell, 1.0))


def project_window(job: MapprojectTileJob, sensor: Any, surface: Any,
                   window: tuple[int, int, int, int]) -> tuple[np.ndarray, dict[str, Any]]:
    """Orthoimage values (and angles) of one window of the map grid.

    Parameters
    ----------
    job : MapprojectTileJob
        The grid, the surface and the options.
    sensor : SensorModel
        The image's model (``job.sensor_path`` read).
    surface : demtool.mapproject.surface.DemSurface or None
        The DEM read in windows; None: ``job.height``.
    window : (row0, row1, col0, col1)
        Map grid cells.

    Returns
    -------
    values : (B, h, w) float32
        Band 0 the orthoimage (NaN where not seen); with ``job.angles`` bands 1–3 the
        incidence, emission and phase angles, degrees.
    info : dict
        ``valid`` (seen cells), ``skipped`` (the tile misses the image), ``step`` (the
        lattice spacing used, None when skipped) and ``max_error_px``.
    """
    from demtool import io as dio
    from demtool.mapproject.core import (
        illumination_angles,
        image_coordinates,
        image_window,
        resample_tile,
        tile_misses_image,
    )
    from demtool.maps import map_to_lonlat, map_to_xyz

    crs, t = job.crs, job.affine
    r0, r1, c0, c1 = window
    out = np.full((len(job.bands), r1 - r0, c1 - c0), np.nan, dtype=np.float32)
    cc, rr = np.meshgrid(np.arange(c0, c1) + 0.5, np.arange(r0, r1) + 0.5)
    x, y = t.a * cc + t.b * rr + t.c, t.d * cc + t.e * rr + t.f
    if surface is None:
        heights = np.full(x.shape, float(job.height))
    elif job.same_crs:
        heights = surface.heights_xy(x, y)
    else:
        heights = surface.heights_lonlat(*map_to_lonlat(crs, x, y))
    finite = heights[np.isfinite(heights)]
    skipped = {"valid": 0, "skipped": True, "step": None, "max_error_px": 0.0}
    if not finite.size or tile_misses_image(sensor, crs, t, window, finite.min(),
                                            finite.max()):
        return out, skipped
    coords = image_coordinates(sensor, crs, t, window, heights, step=job.step,
                               tolerance=job.tolerance, seed=job.seed)
    span = image_window(coords.line, coords.sample, sensor.lines, sensor.samples)
    if span is not None:
        pixels = dio.read_window(job.image_path, span, what="image")
        out[0] = resample_tile(pixels, (span[0], span[2]), coords.line, coords.sample,
                               sensor.lines, sensor.samples)
    if job.angles:
        xyz = map_to_xyz(crs, x, y, heights)
        seen = np.where(np.isfinite(out[0]), coords.line, np.nan)
        out[1:] = np.stack(illumination_angles(sensor, xyz, seen))
    return out, {"valid": int(np.isfinite(out[0]).sum()), "skipped": False,
                 "step": coords.step, "max_error_px": float(coords.max_error_px)}


def summarize_tiles(infos: list[dict[str, Any]], cells: int) -> dict[str, Any]:
    """The run's figures from the tiles' infos (valid fraction, lattice steps, worst error)."""
    steps: dict[str, int] = {}
    for info in infos:
        if info.get("step") is not None:
            steps[str(info["step"])] = steps.get(str(info["step"]), 0) + 1
    valid = sum(int(i.get("valid", 0)) for i in infos)
    return {"valid_cells": valid,
            "valid_fraction": round(valid / cells, 6) if cells else 0.0,
            "tiles": len(infos), "tiles_off_image": sum(bool(i.get("skipped")) for i in infos),
            "lattice_steps": dict(sorted(steps.items(), key=lambda kv: int(kv[0]))),
            "max_interpolation_error_px": round(max((float(i.get("max_error_px", 0.0))
                                                     for i in infos), default=0.0), 6)}


def mapproject_tiled(run: Any, job: MapprojectTileJob, grid: Any, tile_size: int, params: Any,
                     *, out_path: str | os.PathLike, angles_out: str | os.PathLike | None,
                     tags: dict[str, Any], inputs: list[str | os.PathLike],
                     extra_summary: dict[str, Any]):
    """The engine run of ``demtool mapproject`` (called by
    :func:`demtool.mapproject.run.run_mapproject`).

    Returns
    -------
    demtool.tiling.jobs.TiledResult
    """
    from demtool.errors import InputError
    from demtool.tiling import plan_tiles
    from demtool.tiling.jobs import TiledOutput, run_tiled

    tiling = plan_tiles(grid.height, grid.width, tile_size, overlap=0)
    # ZSTD, as the untiled path's demtool.io.raster_writer (deflate costs ~1.5x the CPU)
    outputs = [TiledOutput(out_path, 0, tags, "ortho", "zstd")]
    if angles_out is not None:
        outputs.append(TiledOutput(angles_out, (1, 2, 3), {**tags, "bands": list(ANGLE_BANDS)},
                                   list(ANGLE_BANDS), "zstd"))
    cells = grid.width * grid.height

    def summarize(infos: list[dict[str, Any]]) -> dict[str, Any]:
        summary = {**extra_summary, **summarize_tiles(infos, cells)}
        if summary["valid_cells"] == 0:  # raised before anything is written
            raise InputError(f"{job.image_path}: no map cell sees the image (check --dem, "
                             "--height and --bounds)")
        return summary

    parameters = {**params.as_dict(), "grid_transform": list(job.transform),
                  "grid_shape": [grid.height, grid.width], "grid_crs": job.crs_wkt,
                  "angles": job.angles}
    return run_tiled(run, job, tiling, outputs, inputs=[Path(p) for p in inputs],
                     parameters=parameters, transform=grid.transform, crs=grid.crs,
                     workers=params.workers, scheduler=params.scheduler,
                     dry_run=params.dry_run, summarize=summarize)
