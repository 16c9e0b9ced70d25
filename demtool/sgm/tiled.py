"""``demtool sgm`` in tiles: each tile matched by :func:`demtool.sgm.sgm` on its window.

A left tile core ``[r0, r1) × [c0, c1)`` is matched on the window with ``overlap`` rows
and columns around it, widened by the disparity range (``x_right = x_left − d``: the
right columns ``c0 − d_max … c1 − d_min`` must be inside the window), and the core is
cropped out.  The disparity range is the global one (``--min-disparity`` /
``--num-disparities``), or, when it comes from ``--rectify``, each tile's own: the
range of the rectification's matches inside the tile's window widened by a margin
(:func:`tile_ranges`; the global range where a tile has too few matches), which on a
pair with a large global range cuts the cost volumes and the false matches.

Default margin (:mod:`demtool.sgm.margins`): the reach of SGM's paths, ⌈4 · P2 / ΔC̄⌉
with ΔC̄ the cost's contrast measured on four windows of the pair (census and "ad"; a
modelled weak texture for the MI costs), plus the cost's support and the filters'
reach: 57 px on bench/scale_out.py's census pair (87 px before, a fixed 64 + windows),
where tiled and untiled disparities are identical on all but a few pixels
(tests/tiling/test_tiling.py, docs/stages/scale.md).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from demtool.tiling import Tile, plan_tiles, read_window, wants_tiles

MIN_TILE_MATCHES = 8  # matches a tile needs for its own disparity range
RANGE_MARGIN = 8  # px added to both ends of a tile's match range (and 25 % of its width)
PROCESS_BYTES = 250 * 2**20  # a worker process with numpy, numba, rasterio and the kernels
MIN_DEFAULT_TILE = 512  # px: the smallest default tile core


def default_overlap(params: Any, contrast: dict[str, float] | None = None) -> int:
    """The margin of an sgm tile, px (:func:`demtool.sgm.margins.tile_margin`)."""
    from demtool.sgm.margins import tile_margin

    return tile_margin(params, contrast)[0]


def measured_contrast(left_path: str | os.PathLike, right_path: str | os.PathLike,
                      params: Any, shape: tuple[int, int], min_disparity: int,
                      num_disparities: int) -> dict[str, float]:
    """ΔC̄ of a census or "ad" run's cost on four windows of the pair
    (:func:`demtool.sgm.margins.cost_contrast`), by cost name; {} for the other costs or
    when no sampled pixel can be measured."""
    from demtool.sgm.margins import cost_contrast, sample_windows
    from demtool.sgm.matcher import CENSUS_WINDOWS, COST_DEFAULTS

    if params.cost not in ("census", "ad"):
        return {}
    name = params.cost
    window = int(params.cost_window or COST_DEFAULTS[name].window)
    census_shape = CENSUS_WINDOWS[params.census_window]
    boxes = sample_windows(*shape, num_disparities, window)
    pairs = ((read_window(left_path, box, what="left rectified image"),
              read_window(right_path, box, what="right rectified image")) for box in boxes)
    value = cost_contrast(pairs, cost=name, window=window, census_shape=census_shape,
                          min_disparity=min_disparity, num_disparities=num_disparities)
    return {} if value is None or value <= 0 else {name: value}


def sgm_tile_size(params: Any, shape: tuple[int, int], num_disparities: int) -> int:
    """The tile core of a run (0: untiled; :func:`demtool.tiling.wants_tiles` with
    :func:`default_tile_size` when ``--tile-size`` is not given)."""
    if params.tile_size:
        return wants_tiles(*shape, params)
    local = params.workers if not params.scheduler and params.workers >= 2 else 1
    return wants_tiles(*shape, params,
                       default_size=default_tile_size(params, num_disparities, local))


def default_tile_size(params: Any, num_disparities: int, workers: int = 1) -> int:
    """The tile core a run without ``--tile-size`` uses (``--scheduler``, ``--dry-run``).

    The largest multiple of 256 px whose outer window (core + the modelled margin on
    every side + the disparity range on one) keeps the aggregated cost S (uint16, 2
    bytes a cell) of one tile within ``max_memory_mb`` shared by ``workers`` local
    workers, so a tile is matched in one strip; at least :data:`MIN_DEFAULT_TILE`.
    Larger tiles spend less of their work on margins (the margin is fixed per tile).
    """
    margin = default_overlap(params)
    budget = params.max_memory_mb * 2**20 / max(1, workers) / (2 * num_disparities)
    # (t + 2m)(t + 2m + D) ≤ budget, solved for t
    side = (-num_disparities + math.sqrt(num_disparities**2 + 4 * budget)) / 2
    core = int((side - 2 * margin) // 256 * 256)
    return max(MIN_DEFAULT_TILE, core)


def tile_ranges(tiles, points_left: np.ndarray, points_right: np.ndarray,
                min_disparity: int, num_disparities: int) -> tuple[tuple[int, int], ...]:
    """Per tile (min_disparity, num_disparities) from the matches inside its window.

    A tile with at least :data:`MIN_TILE_MATCHES` rectified matches (x, y) in its outer
    window searches their disparities ``x_left − x_right`` widened by ``RANGE_MARGIN`` px
    plus 25 % of their spread on both sides, clipped to the global range; the others the
    global range.

    Parameters
    ----------
    tiles : sequence of Tile
    points_left, points_right : (N, 2) float
        Matches in the rectified left / right images, (x, y) px.
    min_disparity, num_disparities : int
        The global range.
    """
    low_global, high_global = min_disparity, min_disparity + num_disparities - 1
    disparity = points_left[:, 0] - points_right[:, 0]
    ranges = []
    for tile in tiles:
        r0, r1, c0, c1 = tile.outer
        inside = ((points_left[:, 0] >= c0) & (points_left[:, 0] < c1)
                  & (points_left[:, 1] >= r0) & (points_left[:, 1] < r1))
        if inside.sum() < MIN_TILE_MATCHES:
            ranges.append((min_disparity, num_disparities))
            continue
        low, high = float(disparity[inside].min()), float(disparity[inside].max())
        margin = RANGE_MARGIN + 0.25 * (high - low)
        low_tile = max(low_global, math.floor(low - margin))
        high_tile = min(high_global, math.ceil(high + margin))
        if high_tile <= low_tile:
            ranges.append((min_disparity, num_disparities))
        else:
            ranges.append((low_tile, high_tile - low_tile + 1))
    return tuple(ranges)


@dataclass(frozen=True)
class SgmTileJob:
    """Match one tile of a rectified pair (picklable: paths and plain values only)."""

    left_path: str
    right_path: str
    min_disparity: int
    num_disparities: int
    options: tuple[tuple[str, Any], ...]  # keywords of demtool.sgm.sgm (workers excluded)
    ranges: tuple[tuple[int, int], ...] = ()  # per tile (min, num); empty: the global one
    widenings: int = 0  # re-matches of a tile saturated at a bound (demtool.sgm.widen)
    limits: tuple[int | None, int | None] = (None, None)  # widening limits (calibrated)
    stage: str = "sgm"
    # local --workers: tiles on threads (demtool.tiling.local_threads; audited: nogil
    # kernels, per-call pools and buffers, no process-wide setting changed)
    thread_safe: ClassVar[bool] = True
    bands: tuple[str, ...] = ("disparity", "confidence")
    # imported once by the workers' forkserver; demtool.sgm.warm loads the kernels there
    preload: tuple[str, ...] = ("demtool.sgm", "demtool.sgm.warm")
    # the outputs are written in tile order while the workers compute the later tiles
    # (demtool.tiling.jobs.run_tiled): compute() writes nothing through demtool.io
    stream_outputs: bool = True

    def compute(self, tile: Tile, threads: int) -> tuple[np.ndarray, dict[str, Any]]:
        from demtool.sgm.widen import sgm_widening

        left = read_window(self.left_path, tile.outer, what="left rectified image")
        right = read_window(self.right_path, tile.outer, what="right rectified image")
        rows, cols = tile.crop
        out = np.full((2, *tile.core_shape), np.nan, dtype=np.float32)
        if not np.isfinite(left[rows, cols]).any() or not np.isfinite(right).any():
            return out, {"valid": 0}
        low, count = (self.ranges[tile.index] if self.ranges
                      else (self.min_disparity, self.num_disparities))
        # a widened range still fits the tile: matches beyond its window come out NaN,
        # and the core sits the overlap inside it
        result = sgm_widening(left, right, min_disparity=low, num_disparities=count,
                              widenings=self.widenings, lower_limit=self.limits[0],
                              upper_limit=self.limits[1], workers=threads,
                              **dict(self.options))
        low = result.parameters["min_disparity"]
        count = result.parameters["num_disparities"]
        out[0] = result.disparity[rows, cols]
        out[1] = result.confidence[rows, cols]
        return out, {"valid": int(np.isfinite(out[0]).sum()),
                     "sum": float(np.nansum(out[0])),
                     "sum_sq": float(np.nansum(out[0].astype(np.float64) ** 2)),
                     "min": float(np.nanmin(out[0])) if np.isfinite(out[0]).any() else None,
                     "max": float(np.nanmax(out[0])) if np.isfinite(out[0]).any() else None,
                     "input_valid": int(np.isfinite(left[rows, cols]).sum()),
                     "range": [low, low + count - 1],
                     "widened": len(result.parameters["range_widenings"])}

    def memory_bytes(self, tile: Tile) -> int:
        """S (uint16, 2 bytes a cell), ~16 float32 images, and the process (measured)."""
        height, width = tile.outer_shape
        count = self.ranges[tile.index][1] if self.ranges else self.num_disparities
        return PROCESS_BYTES + height * width * (count * 2 + 64)


def _summary(infos: list[dict[str, Any]], pixels: int) -> dict[str, Any]:
    valid = sum(int(i.get("valid", 0)) for i in infos)
    input_valid = sum(int(i.get("input_valid", 0)) for i in infos)
    summary: dict[str, Any] = {"valid_fraction": round(valid / max(pixels, 1), 4),
                               "valid_fraction_of_input": round(valid / max(input_valid, 1),
                                                                4)}
    if valid:
        mean = sum(float(i.get("sum", 0.0)) for i in infos) / valid
        square = sum(float(i.get("sum_sq", 0.0)) for i in infos) / valid
        summary.update(disparity_min=min(i["min"] for i in infos if i.get("min") is not None),
                       disparity_max=max(i["max"] for i in infos if i.get("max") is not None),
                       disparity_mean=mean,
                       disparity_std=math.sqrt(max(square - mean * mean, 0.0)))
    return summary


def sgm_tiled(run: Any, left_path: str | os.PathLike, right_path: str | os.PathLike,
              out: str | os.PathLike, params: Any, shape: tuple[int, int], *,
              min_disparity: int, num_disparities: int, source: str,
              confidence: str | os.PathLike | None = None, rectify=None):
    """The tiled ``demtool sgm`` (called by :func:`demtool.sgm.run.run_sgm`).

    Returns
    -------
    demtool.tiling.jobs.TiledResult
    """
    from demtool import io as dio
    from demtool.sgm.margins import tile_margin
    from demtool.sgm.volumes import reusing_volumes
    from demtool.tiling.distributed import prestart_local_workers
    from demtool.tiling.jobs import TiledOutput, run_tiled

    height, width = shape
    tile_size = sgm_tile_size(params, shape, num_disparities)
    # the workers' forkserver imports and loads the kernels while the tiles are planned
    prestart_local_workers(SgmTileJob, params.workers, params.scheduler, params.dry_run)
    margin_made: dict[str, Any] = {"margin_px": params.tile_overlap, "given": True}
    if params.tile_overlap is None:
        contrast = measured_contrast(left_path, right_path, params, shape, min_disparity,
                                     num_disparities)
        overlap, margin_made = tile_margin(params, contrast)
        if "path_reach_px" in margin_made:
            run.log.info("tile margin %d px: path reach %d px = 4 × P2 %d / the cost's "
                         "contrast %g (%s) + support and filters", overlap,
                         margin_made["path_reach_px"], margin_made["p2"],
                         margin_made["contrast"], margin_made["contrast_source"])
    else:
        overlap = params.tile_overlap
    max_disparity = min_disparity + num_disparities - 1
    tiling = plan_tiles(height, width, tile_size, overlap=overlap,
                        extra_left=max(max_disparity, 0), extra_right=max(-min_disparity, 0))
    options = params.matcher_options()
    for name in ("workers", "tile_size", "tile_overlap", "scheduler", "dry_run"):
        options.pop(name, None)
    ranges: tuple[tuple[int, int], ...] = ()
    limits: tuple[int | None, int | None] = (None, None)
    if rectify is not None and not params.range_given:
        from demtool.sgm.widen import limits_from_rectification

        content = dio.read_npz(rectify, "rectification")
        limits = limits_from_rectification(content)
        ranges = tile_ranges(tiling.tiles, np.asarray(content["points_left_rect"], float),
                             np.asarray(content["points_right_rect"], float), min_disparity,
                             num_disparities)
        own = sum(r != (min_disparity, num_disparities) for r in ranges)
        run.log.info("%d of %d tiles search the range of the matches inside them", own,
                     len(ranges))
    job = SgmTileJob(str(left_path), str(right_path), min_disparity, num_disparities,
                     tuple(sorted(options.items())), ranges, widenings=params.widenings,
                     limits=limits)
    with dio._open_dataset(Path(left_path), "left rectified image") as dataset:
        transform, frame = dataset.transform, dataset.tags().get("frame")
        crs = dataset.crs  # orthoimages: the disparity is on their map grid
    if transform.is_identity:
        transform = dio.image_frame_transform(1.0)
    tags = run.provenance.tags(frame=frame or f"image:{Path(left_path).stem}",
                               disparity_convention="x_right = x_left - d",
                               min_disparity=min_disparity, num_disparities=num_disparities,
                               cost=params.cost, tile_size=tile_size,
                               tile_margins=list(tiling.margins))
    outputs = [TiledOutput(out, 0, tags, "disparity")]
    if confidence is not None:
        outputs.append(TiledOutput(confidence, 1, {**tags, "quantity":
                                                   "sgm confidence (S2 - S1) / S2"},
                                   "confidence"))
    run.log.info("matching %s / %s in tiles: %d×%d px, disparities %d … %d (%s), cost %s",
                 left_path, right_path, width, height, min_disparity, max_disparity, source,
                 params.cost)

    def summarize(infos: list[dict[str, Any]]) -> dict[str, Any]:
        return {**_summary(infos, height * width), "min_disparity": min_disparity,
                "tile_ranges": [i.get("range") for i in infos],
                "tiles_widened": sum(1 for i in infos if i.get("widened")),
                "num_disparities": num_disparities, "disparity_range_source": source,
                "tile_margin": margin_made,
                "convention": "x_right = x_left - d, pixels, NaN = invalid"}

    inputs = [left_path, right_path] + ([rectify] if rectify is not None else [])
    # tiles computed in this process (in turn or on threads) reuse their thread's S
    with reusing_volumes():
        return run_tiled(run, job, tiling, outputs, inputs=inputs,
                         parameters={**params.as_dict(), "min_disparity": min_disparity,
                                     "num_disparities": num_disparities},
                         transform=transform, crs=crs, workers=params.workers,
                         scheduler=params.scheduler, dry_run=params.dry_run,
                         summarize=summarize)
