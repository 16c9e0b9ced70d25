"""``demtool dem`` in tiles: triangulation, gridding and gap filling over the output grid.

The calibrated disparity route (``--disparity`` + ``--rectify`` + ``--cameras``) of
:func:`demtool.dem.routes.dem_from_disparity_calibrated` scatters every disparity's
triangulated point onto the target image's grid, so the tiles are cores of the **output**
grid (the target image).  Four steps, each resumable in the work folder:

1. **statistics** (one pass over the tiles): each tile reads the disparity window whose
   points can land in its core ± :data:`MEASURE_MARGIN` px (the target rectangle mapped
   through the rectification homography; for a right-image target widened by the
   disparity range, ``x_right = x_left − d``), triangulates it and returns histograms of
   the local NMAD of every :data:`STATS_STRIDE`-th sample (the outlier test's floor is
   their median over the whole image) and of every sample's depth (the estimated GSD:
   median depth × pixel angle), each sample counted by the tile whose core holds its
   (clipped) pixel;
2. **measured grid**: the same window, the outlier test with the global floor, bilinear
   splatting onto the core (:func:`demtool.dem.grid.splat_bilinear`);
3. **coarse global solve**: the measured grid block-averaged by a factor ``f`` (1 while
   the grid has at most :data:`COARSE_MAX_CELLS` cells, else the smallest factor that
   fits), filled by :func:`demtool.imaging.interpolate.inpaint_springs` in one solve;
4. **fine solves** (the tiles :func:`demtool.tiling.jobs.run_tiled` writes): each tile fills its
   core ± the overlap from the measured grid, the one-cell ring around that window held
   at the coarse solution (bilinear) where unmeasured, then crops the core (and median
   filters it when ``--median`` asks).

Exactness: the spring system couples a cell only with its four neighbours, so with
``f = 1`` (grids up to :data:`COARSE_MAX_CELLS` cells) the ring carries the global
solution and every tile reproduces the untiled fill to the solver's tolerance, whatever
the overlap; with ``f > 1`` the ring's error (the coarse grid's) decays across the overlap
(default 16 f px).  The outlier test matches the untiled one when every core sample's
neighbours lie within the margin (dense disparities: a few px), up to the floor's
estimate (a quarter of the samples, 0.23 % histogram bins) and up to ties among
equidistant neighbours (a regular grid of samples has many; the k-d tree breaks them
by its own structure): a sample near the threshold can flip, a cell in 10⁵ here.
tests/dem/test_tiled_dem.py and bench/scale.py state the tolerances achieved.
"""

from __future__ import annotations

import contextlib
import math
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from demtool.dem.tiled_grids import (
    fill_core,
    histogram_median,
    log_histogram,
    prepare_fill,
)
from demtool.tiling import Tile, TileCache, plan_tiles, read_window, wants_tiles

MEASURE_MARGIN = 32  # px around a core: the outlier test's neighbours and the splat's reach
FILL_MARGIN = 64  # px: default overlap of the fine solves (any overlap is exact when f = 1)
COARSE_MAX_CELLS = 1024 * 1024  # cells of the coarse global solve (decimated beyond)
SWEEPS = 1  # fill sweeps before the final one when the coarse solve is decimated
STATS_STRIDE = 4  # the outlier floor from every 4th sample's local NMAD
PROCESS_BYTES = 250 * 2**20  # a worker process with numpy, scipy, rasterio
SAMPLE_BYTES = 700  # per disparity sample: correspondences, rays, points, the kNN query
CELL_BYTES = 200  # per cell of a fine solve: the spring system and its multigrid
NMAD_BINS_PER_DECADE = 1000  # histogram of the local NMADs (0.23 % bins)
DEPTH_BINS_PER_DECADE = 100_000  # histogram of the depths (0.0023 % bins)
STEP_BANDS = {"stats": ("samples",), "measure": ("measured",),
              "fill": ("height", "interpolated")}


def coarse_factor(height: int, width: int, max_cells: int | None = None) -> int:
    """Decimation of the coarse solve: 1 when ``height × width ≤ max_cells``."""
    max_cells = COARSE_MAX_CELLS if max_cells is None else max_cells
    factor = 1
    while math.ceil(height / factor) * math.ceil(width / factor) > max_cells:
        factor += 1
    return factor


def default_overlap(median_px: int, factor: int) -> int:
    """Margin of the fine solves, px: 64 (16 f when decimated) + the median's half width."""
    return max(FILL_MARGIN, 16 * factor if factor > 1 else 0) + max(median_px, 0) // 2


def _widen(window: tuple[int, int, int, int], margin: int) -> tuple[int, int, int, int]:
    r0, r1, c0, c1 = window
    return r0 - margin, r1 + margin, c0 - margin, c1 + margin


# ------------------------------------------------------------------------------ the job
@dataclass(frozen=True)
class DemTileJob:
    """One tile of the calibrated disparity route (picklable: paths and plain values).

    ``step`` is ``"stats"``, ``"measure"`` or ``"fill"`` (module docstring); ``work`` the
    folder of the measured grid and the coarse solve (empty: a fill tile measures and
    fills its own window, the ``--dry-run`` calibration).
    """

    disparity_path: str
    H_left: np.ndarray
    H_right: np.ndarray
    left_camera: Any
    right_camera: Any
    side: str  # "left" or "right": the target
    shape: tuple[int, int]  # target image (height, width)
    shape_rect: tuple[int, int]  # rectified canvas (height, width)
    disparity_bounds: tuple[float, float]  # values outside are masked (demtool.imaging.checks)
    tile_size: int
    neighbours: int = 16
    threshold: float = 3.0
    floor: float | None = None
    median_px: int = 0
    factor: int = 1
    step: str = "fill"
    work: str = ""
    ring: str = ""  # the work folder's sub-folder of an earlier fill sweep ("" = coarse)
    stage: str = "dem"
    # local --workers: tiles on threads (demtool.tiling.local_threads; audited: nogil
    # kernels, the neighbour search on usable_threads(), cameras read-only)
    thread_safe: ClassVar[bool] = True
    bands: tuple[str, ...] = ("height", "interpolated")

    def at_step(self, step: str, **changes: Any) -> DemTileJob:
        """This job for another step (its bands follow)."""
        return replace(self, step=step, bands=STEP_BANDS[step], **changes)

    # ---------------------------------------------------------------- the samples
    def _rect_window(self, window: tuple[int, int, int, int]) -> tuple[int, int, int, int]:
        """The rectified window whose disparities can land in target ``window``."""
        r0, r1, c0, c1 = window
        corners = np.array([[c0 - 1.0, r0 - 1.0], [c1, r0 - 1.0], [c0 - 1.0, r1], [c1, r1]])
        H = self.H_left if self.side == "left" else self.H_right
        mapped = np.column_stack([corners, np.ones(4)]) @ np.asarray(H, dtype=np.float64).T
        xy = mapped[:, :2] / mapped[:, 2:3]
        x_low, x_high = xy[:, 0].min(), xy[:, 0].max()
        if self.side == "right":  # x_left = x_right + d
            x_low, x_high = x_low + self.disparity_bounds[0], x_high + self.disparity_bounds[1]
        height, width = self.shape_rect
        return (max(0, math.floor(xy[:, 1].min()) - 2), min(height, math.ceil(xy[:, 1].max()) + 3),
                max(0, math.floor(x_low) - 2), min(width, math.ceil(x_high) + 3))

    def samples(self, window: tuple[int, int, int, int]) -> dict[str, np.ndarray] | None:
        """Triangulated samples of the disparities that can land in target ``window``.

        Returns ``pixels`` (N, 2) target (x, y), ``heights`` (N,) m, ``depth`` (N,) m, or
        None when the window holds no valid disparity.
        """
        from demtool.dem.disparity import disparity_correspondences, triangulate
        from demtool.dem.points import heights_along_view

        rr0, rr1, rc0, rc1 = self._rect_window(window)
        if rr1 <= rr0 or rc1 <= rc0:
            return None
        disparity = read_window(self.disparity_path, (rr0, rr1, rc0, rc1), what="disparity")
        low, high = self.disparity_bounds
        with np.errstate(invalid="ignore"):
            disparity[(disparity < low) | (disparity > high)] = np.nan
        if not np.isfinite(disparity).any():
            return None
        shift = np.array([[1.0, 0.0, -rc0], [0.0, 1.0, -rr0], [0.0, 0.0, 1.0]])
        corr = disparity_correspondences(disparity, shift @ self.H_left, shift @ self.H_right)
        points, _ = triangulate(corr, self.left_camera, self.right_camera)
        camera = self.left_camera if self.side == "left" else self.right_camera
        heights = heights_along_view(points, camera)
        pixels = corr.left if self.side == "left" else corr.right
        with np.errstate(invalid="ignore"):  # cheirality: in front of both cameras
            front = ((self.left_camera.depth(points) > 0)
                     & (self.right_camera.depth(points) > 0))
        ok = np.isfinite(heights) & np.isfinite(pixels).all(axis=1) & front
        return {"pixels": pixels[ok], "heights": heights[ok],
                "depth": camera.depth(points[ok])}

    def _owned(self, tile: Tile, pixels: np.ndarray) -> np.ndarray:
        """Samples whose pixel, clipped into the image and rounded, is in the core."""
        height, width = self.shape
        col = np.rint(np.clip(pixels[:, 0], 0, width - 1))
        row = np.rint(np.clip(pixels[:, 1], 0, height - 1))
        r0, r1, c0, c1 = tile.core
        return (row >= r0) & (row < r1) & (col >= c0) & (col < c1)

    def measured(self, tile: Tile, window: tuple[int, int, int, int]
                 ) -> tuple[np.ndarray, dict[str, Any]]:
        """The measured grid on target ``window`` (NaN = unmeasured) and its counts.

        The samples are those that can land within :data:`MEASURE_MARGIN` px of the
        window (unclipped: samples just outside the image are neighbours too); the counts
        are of the samples ``tile`` owns (:meth:`_owned`).
        """
        from demtool.dem.grid import local_median_inliers, splat_bilinear

        r0, r1, c0, c1 = window
        found = self.samples(_widen(window, MEASURE_MARGIN))
        if found is None or len(found["heights"]) == 0:
            return np.full((r1 - r0, c1 - c0), np.nan), {"samples": 0, "outliers_removed": 0}
        pixels, heights = found["pixels"], found["heights"]
        keep = local_median_inliers(pixels, heights, neighbours=self.neighbours,
                                    threshold=self.threshold, floor=self.floor)
        local = pixels[keep] - np.array([c0, r0], dtype=np.float64)
        grid, _ = splat_bilinear(local, heights[keep], (r1 - r0, c1 - c0))
        owned = self._owned(tile, pixels)
        return grid, {"samples": int(owned.sum()),
                      "outliers_removed": int((owned & ~keep).sum())}

    # ---------------------------------------------------------------------- steps
    def compute(self, tile: Tile, threads: int) -> tuple[np.ndarray, dict[str, Any]]:
        if self.step == "stats":
            return self._stats(tile)
        if self.step == "measure":
            grid, info = self.measured(tile, tile.core)
            measured = np.isfinite(grid)
            info.update(cells_measured=int(measured.sum()))
            return grid[None].astype(np.float32), info
        return self._fill(tile)

    def _stats(self, tile: Tile) -> tuple[np.ndarray, dict[str, Any]]:
        from demtool.dem.grid import local_median_statistics

        counts = np.zeros(tile.core_shape, dtype=np.float32)
        found = self.samples(_widen(tile.core, MEASURE_MARGIN))
        if found is None or len(found["heights"]) < 4:
            return counts[None], {"samples": 0, "nmad": {}, "depth": {}}
        pixels = found["pixels"]
        owned = self._owned(tile, pixels)
        # The floor from every STATS_STRIDE-th owned sample (the neighbours among all).
        chosen = np.flatnonzero(owned)[::STATS_STRIDE]
        _, local_nmad = local_median_statistics(pixels, found["heights"],
                                                neighbours=self.neighbours, at=chosen)
        r0, _, c0, _ = tile.core
        height, width = self.shape
        inside = owned & (pixels[:, 0] > -0.5) & (pixels[:, 0] < width - 0.5) & (
            pixels[:, 1] > -0.5) & (pixels[:, 1] < height - 0.5)
        rows = np.rint(pixels[inside, 1]).astype(np.int64) - r0
        cols = np.rint(pixels[inside, 0]).astype(np.int64) - c0
        np.add.at(counts, (rows, cols), 1.0)
        return counts[None], {
            "samples": int(owned.sum()),
            "nmad": log_histogram(local_nmad, NMAD_BINS_PER_DECADE),
            "depth": log_histogram(found["depth"][owned], DEPTH_BINS_PER_DECADE)}

    def _fill(self, tile: Tile) -> tuple[np.ndarray, dict[str, Any]]:
        if not self.work:  # calibration: this window measured and filled on its own
            grid, info = self.measured(tile, tile.outer)
            core, measured = fill_core(tile, self.shape, self.tile_size, grid=grid,
                                       median_px=self.median_px)
        else:
            core, measured = fill_core(tile, self.shape, self.tile_size, work=self.work,
                                       ring=self.ring, factor=self.factor,
                                       median_px=self.median_px)
            info = TileCache(Path(self.work) / "measured").info(tile)
        out = np.stack([core, (~measured).astype(np.float64)]).astype(np.float32)
        return out, {"samples": int(info.get("samples", 0)),
                     "outliers_removed": int(info.get("outliers_removed", 0)),
                     "cells_measured": int(measured.sum()),
                     "height_min": float(core.min()), "height_max": float(core.max())}

    def memory_bytes(self, tile: Tile) -> int:
        """The disparity samples of the measuring window, or the fine solve's window."""
        r0, r1, c0, c1 = self._rect_window(_widen(tile.core, MEASURE_MARGIN))
        samples = max(r1 - r0, 0) * max(c1 - c0, 0)
        height, width = tile.outer_shape
        return PROCESS_BYTES + max(samples * SAMPLE_BYTES, height * width * CELL_BYTES)


# ------------------------------------------------------------------------ the runner
@dataclass(frozen=True)
class TiledPair:
    """What :func:`dem_tiled` needs of the runner's checked inputs."""

    disparity_path: str
    rectify_path: str
    cameras_path: str
    H_left: np.ndarray
    H_right: np.ndarray
    left_camera: Any
    right_camera: Any
    side: str
    target_name: str
    shape_rect: tuple[int, int]
    disparity_range: tuple[float, float]


def check_disparity_file(path: str, shape_rect: tuple[int, int],
                         disparity_range: tuple[float, float], *, source: str, log,
                         strip: int = 512) -> tuple[float, float]:
    """:func:`demtool.imaging.checks.check_disparity_range` over the whole file, strip by strip.

    Returns the bounds outside which values are masked; refuses the file as the untiled
    route does (most values outside the range, or none valid).
    """
    from demtool.errors import InputError
    from demtool.imaging.checks import check_disparity_range

    height, width = shape_rect
    finite = outside = 0
    low = high = math.nan
    for r0 in range(0, height, strip):
        data = read_window(path, (r0, min(height, r0 + strip), 0, width), what="disparity")
        count = int(np.isfinite(data).sum())
        if count == 0:
            continue
        checked = check_disparity_range(data, disparity_range, path, source=source,
                                        max_outside_fraction=1.0)
        finite, outside = finite + count, outside + checked.outside
        low, high = checked.low, checked.high
    if finite == 0:
        raise InputError(f"{path}: disparity has no valid value")
    if outside > 0.5 * finite:
        raise InputError(f"{path}: {100 * outside / finite:.0f} % of the disparities lie "
                         f"outside {low:g} … {high:g} px, the range of {source}; is it a "
                         "disparity of this pair?")
    if outside:
        log.warning("%s: %d disparities outside %.4g … %.4g px masked", path, outside, low,
                    high)
    return low, high


def dem_tiled(run: Any, params: Any, out: str | os.PathLike, pair: TiledPair, *,
              mask_path: str | os.PathLike | None = None, gsd: float | None = None,
              gsd_source: str = "--gsd"):
    """The tiled calibrated disparity route (called by :func:`demtool.dem.run.run_dem`).

    ``gsd`` (metres) when known (``--gsd``, the scene); else estimated from the median
    depth of the samples (the statistics pass) × the target's pixel angle.  With
    ``--workers N`` (N ≥ 2) every pass runs on threads of this process (on one local
    cluster of processes, started once for every pass, where threads cannot be used).

    Returns
    -------
    demtool.tiling.jobs.TiledResult
    """
    with contextlib.ExitStack() as stack:
        return _passes(run, params, out, pair, mask_path=mask_path, gsd=gsd,
                       gsd_source=gsd_source, stack=stack)


def _local_cluster(stack: contextlib.ExitStack, job: DemTileJob, workers: int) -> str:
    """Start the ``--workers`` LocalCluster once for every pass; its scheduler's address."""
    from distributed import LocalCluster

    from demtool.tiling.distributed import LOCAL_CLUSTER_OPTIONS, _start_workers_from_a_forkserver

    _start_workers_from_a_forkserver(stack, job)
    cluster = stack.enter_context(LocalCluster(n_workers=workers, memory_limit=0,
                                               **LOCAL_CLUSTER_OPTIONS))
    return cluster.scheduler_address


def _passes(run: Any, params: Any, out: str | os.PathLike, pair: TiledPair, *, mask_path,
            gsd: float | None, gsd_source: str, stack: contextlib.ExitStack):
    """The body of :func:`dem_tiled`: the passes of the module docstring."""
    from demtool import io as dio
    from demtool.dem.points import pixel_angle
    from demtool.errors import ParameterError, ProcessingError
    from demtool.tiling import cache_key, work_folder
    from demtool.tiling.distributed import run_tiles
    from demtool.tiling.jobs import TiledOutput, run_tiled
    from demtool.tiling.local_threads import runs_on_threads

    if params.mask_band:
        raise ParameterError("--mask-band is not written in tiles: use --interpolated-mask")
    camera = pair.left_camera if pair.side == "left" else pair.right_camera
    shape = (camera.height, camera.width)
    tile_size = wants_tiles(*shape, params)
    factor = coarse_factor(*shape)
    overlap = (default_overlap(params.median, factor) if params.tile_overlap is None
               else params.tile_overlap)
    if params.median > 1 and overlap < params.median // 2:
        raise ParameterError(f"--tile-overlap must be >= {params.median // 2} px (half the "
                             f"--median window), got {overlap}")
    tiling = plan_tiles(*shape, tile_size, overlap=overlap)
    bounds = check_disparity_file(pair.disparity_path, pair.shape_rect, pair.disparity_range,
                                  source=pair.rectify_path, log=run.log)
    outliers = params.outliers()
    job = DemTileJob(pair.disparity_path, np.asarray(pair.H_left, dtype=np.float64),
                     np.asarray(pair.H_right, dtype=np.float64), pair.left_camera,
                     pair.right_camera, pair.side, shape, pair.shape_rect, bounds, tile_size,
                     neighbours=outliers.neighbours, threshold=outliers.threshold,
                     median_px=params.median, factor=factor)
    inputs = [pair.disparity_path, pair.rectify_path, pair.cameras_path]
    parameters = {**params.as_dict(), "gsd": gsd, "coarse_factor": factor}
    workers, scheduler = params.workers, params.scheduler
    if (workers >= 2 and not scheduler and not params.dry_run
            and not runs_on_threads(job, workers, None)):  # one cluster, every pass
        scheduler, workers = _local_cluster(stack, job, workers), 0
    stats_infos: list[dict[str, Any]] = []
    stats_cache = None
    if not params.dry_run:  # the outlier floor and the median depth, before the lock
        key = cache_key(inputs, parameters, tiling, {"pass": "stats"})
        stats_cache = TileCache(work_folder(out) / f"{key}-stats")
        stats_infos = run_tiles(job.at_step("stats"), tiling.tiles, stats_cache,
                                workers=workers, scheduler=scheduler, log=run.log)
        if sum(int(i.get("samples", 0)) for i in stats_infos) < 10:
            raise ProcessingError("fewer than 10 triangulated disparities in the target "
                                  "image; at least 10 are needed to interpolate a DEM")
        floor = histogram_median([i.get("nmad", {}) for i in stats_infos],
                                 NMAD_BINS_PER_DECADE)
        job = replace(job, floor=floor)
        if gsd is None:
            depth = histogram_median([i.get("depth", {}) for i in stats_infos],
                                     DEPTH_BINS_PER_DECADE)
            gsd, gsd_source = float(depth) * pixel_angle(camera), "estimated"
    gsd = float(gsd) if gsd is not None else 1.0

    def prepare(fill_job: DemTileJob, folder: Path) -> DemTileJob:
        return prepare_fill(fill_job.at_step("measure"), fill_job, tiling.tiles, shape,
                            factor, folder, workers=workers, scheduler=scheduler,
                            log=run.log, sweeps=SWEEPS)

    transform = dio.image_frame_transform(gsd)
    frame = f"image:{pair.target_name}"
    tags = run.provenance.tags(frame=frame, dem_route="disparity-calibrated", gsd_m=gsd,
                               units="metres, positive toward the camera",
                               target=pair.target_name, tile_size=tile_size,
                               tile_margins=list(tiling.margins), coarse_factor=factor)
    outputs = [TiledOutput(out, 0, tags, "height")]
    if mask_path is not None:
        outputs.append(TiledOutput(mask_path, 1, run.provenance.tags(
            frame=frame, meaning="1 = interpolated, 0 = measured"), "interpolated"))
    cells = shape[0] * shape[1]

    def summarize(infos: list[dict[str, Any]]) -> dict[str, Any]:
        measured = sum(int(i.get("cells_measured", 0)) for i in infos)
        return {"route": "disparity-calibrated", "target": pair.target_name,
                "shape": list(shape), "gsd_m": gsd, "gsd_source": gsd_source,
                "median_px": params.median,
                "height_min_m": min(float(i["height_min"]) for i in infos),
                "height_max_m": max(float(i["height_max"]) for i in infos),
                "interpolated_fraction": 1.0 - measured / cells,
                "measured_fraction": measured / cells, "cells_measured": measured,
                "disparities": sum(int(i.get("samples", 0)) for i in stats_infos),
                "outliers_removed": sum(int(i.get("outliers_removed", 0)) for i in infos),
                "outlier_nmad_floor_m": job.floor, "coarse_factor": factor}

    result = run_tiled(run, job, tiling, outputs, inputs=inputs, parameters=parameters,
                       transform=transform, workers=workers,
                       scheduler=scheduler, dry_run=params.dry_run,
                       summarize=summarize, prepare=prepare)
    if stats_cache is not None:
        stats_cache.remove()
    return result
