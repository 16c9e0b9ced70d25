"""``demtool match`` in tiles: each tile matched by :func:`demtool.match.match` on its window.

Tiles need the rectified pair (as ``demtool rectify`` writes it) and ``--rectify``: its
``disparity_range`` widens every tile's window so the right image's columns
``c0 − d_max … c1 − d_min`` are inside it, and its seed matches (rectified inliers)
that fall in a tile's window seed that tile (with the SIFT and corner seeds the matcher
finds there itself).  A tile where fewer than 3 seeds are found (no texture, outside
the images) stays NaN and is counted in the summary.

Default margin: the coarsest pyramid level's template, ``template · 2^(levels−1)``, plus
one full-resolution template, so every core pixel sees the same image content at every
level as in an untiled run.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from demtool.tiling import Tile, plan_tiles, raster_shape, read_window, wants_tiles

PROCESS_BYTES = 300 * 2**20


def default_overlap(params: Any) -> int:
    """The margin of a match tile, px: the coarsest level's template + one template."""
    return params.template * 2 ** (params.levels - 1) + params.template


@dataclass(frozen=True)
class MatchTileJob:
    """Match one tile of a rectified pair (picklable: paths, seeds and plain values)."""

    left_path: str
    right_path: str
    seeds_left: tuple[tuple[float, float], ...]   # (x, y) in the full rectified frame
    seeds_right: tuple[tuple[float, float], ...]
    disparity_range: tuple[float, float]
    options: tuple[tuple[str, Any], ...]  # keywords of demtool.match.match
    stage: str = "match"
    bands: tuple[str, ...] = ("disparity", "correlation", "sigma")
    preload: tuple[str, ...] = ("demtool.match",)  # imported once by the workers' forkserver

    def compute(self, tile: Tile, threads: int) -> tuple[np.ndarray, dict[str, Any]]:
        from demtool.errors import ParameterError, ProcessingError
        from demtool.match import match

        # numba's thread count: a worker's share, set by tiling.tasks.compute_tile
        r0, r1, c0, c1 = tile.outer
        left = read_window(self.left_path, tile.outer, what="left image")
        right = read_window(self.right_path, tile.outer, what="right image")
        rows, cols = tile.crop
        out = np.full((3, *tile.core_shape), np.nan, dtype=np.float32)
        seeds = None
        if self.seeds_left:
            pl, pr = np.asarray(self.seeds_left), np.asarray(self.seeds_right)
            inside = ((pl[:, 0] >= c0) & (pl[:, 0] <= c1 - 1) & (pl[:, 1] >= r0)
                      & (pl[:, 1] <= r1 - 1) & (pr[:, 0] >= c0) & (pr[:, 0] <= c1 - 1)
                      & (pr[:, 1] >= r0) & (pr[:, 1] <= r1 - 1))
            if inside.any():
                shift = np.array([c0, r0], dtype=float)
                seeds = (pl[inside] - shift, pr[inside] - shift)
        try:
            result = match(left, right, seed_points=seeds, disparity_range=self.disparity_range,
                           **dict(self.options))
        except (ProcessingError, ParameterError) as exc:  # no texture / no seeds here
            return out, {"matched": 0, "skipped": str(exc).splitlines()[0][:200]}
        out[0] = result.disparity[rows, cols]
        out[1] = result.correlation[rows, cols]
        out[2] = result.sigma[rows, cols]
        valid = np.isfinite(out[0])
        return out, {"matched": int(valid.sum()),
                     "input_valid": int(np.isfinite(left[rows, cols]).sum()),
                     "min": float(out[0][valid].min()) if valid.any() else None,
                     "max": float(out[0][valid].max()) if valid.any() else None}

    def memory_bytes(self, tile: Tile) -> int:
        """The pyramids, the NCC and LSM buffers: ~40 float64 images of the window."""
        height, width = tile.outer_shape
        return PROCESS_BYTES + height * width * 8 * 40


def match_tiled(run: Any, left_path: str | os.PathLike, right_path: str | os.PathLike,
                out: str | os.PathLike, params: Any, shape: tuple[int, int], *,
                rectify: str | os.PathLike | None,
                correlation_out: str | os.PathLike | None = None,
                sigma_out: str | os.PathLike | None = None):
    """The tiled ``demtool match`` (called by :func:`demtool.match.run.run_match`).

    Raises
    ------
    ParameterError
        No ``--rectify`` (its disparity range sizes the windows).
    InputError
        The pair is not the rectified canvas of ``--rectify``.

    Returns
    -------
    demtool.tiling.jobs.TiledResult
    """
    from demtool import io as dio
    from demtool.errors import InputError, ParameterError
    from demtool.tiling.jobs import TiledOutput, run_tiled

    if rectify is None:
        raise ParameterError("--tile-size: tiled match needs --rectify RECTIFY_NPZ (its "
                             "disparity range sizes the tile windows)")
    rect = dio.read_npz(rectify, "rectification")
    size_rect = tuple(int(v) for v in rect["size_rect"])
    height, width = shape
    if size_rect != (width, height):
        raise InputError(f"{left_path}: tiled match needs the rectified pair ({size_rect[0]} "
                         f"x {size_rect[1]} px, written by demtool rectify), got {width} x "
                         f"{height} px")
    right_shape = raster_shape(right_path, "right image")
    if right_shape != shape:
        raise InputError(f"{left_path} and {right_path}: the rectified images differ in size "
                         f"({width} x {height} and {right_shape[1]} x {right_shape[0]} px)")
    low, high = (float(v) for v in rect["disparity_range"])
    margin = params.search_margin * 2 ** (params.levels - 1)
    tile_size = wants_tiles(height, width, params)
    overlap = default_overlap(params) if params.tile_overlap is None else params.tile_overlap
    tiling = plan_tiles(height, width, tile_size, overlap=overlap,
                        extra_left=max(math.ceil(high + margin), 0),
                        extra_right=max(math.ceil(-low + margin), 0))
    job = MatchTileJob(str(left_path), str(right_path),
                       tuple(map(tuple, np.asarray(rect["points_left_rect"], float).tolist())),
                       tuple(map(tuple, np.asarray(rect["points_right_rect"], float).tolist())),
                       (low, high), tuple(sorted(params.matcher_options().items())))
    with dio._open_dataset(Path(left_path), "left image") as dataset:
        transform, frame = dataset.transform, dataset.tags().get("frame")
    if transform.is_identity:
        transform = dio.image_frame_transform(1.0)
    tags = run.provenance.tags(frame=frame or f"image:{Path(left_path).stem}",
                               disparity_convention="x_right = x_left - d",
                               template=params.template, threshold=params.threshold,
                               grid_spacing=params.grid_spacing, tile_size=tile_size,
                               tile_margins=list(tiling.margins))
    outputs = [TiledOutput(out, 0, tags, "disparity")]
    if correlation_out is not None:
        outputs.append(TiledOutput(correlation_out, 1, {
            **tags, "quantity": "LSM correlation coefficient"}, "correlation"))
    if sigma_out is not None:
        outputs.append(TiledOutput(sigma_out, 2, {
            **tags, "quantity": "LSM standard deviation of the disparity, pixels"}, "sigma"))

    def summarize(infos: list[dict[str, Any]]) -> dict[str, Any]:
        matched = sum(int(i.get("matched", 0)) for i in infos)
        valid = sum(int(i.get("input_valid", 0)) for i in infos)
        return {"completeness_percent": round(100.0 * matched / max(valid, 1), 2),
                "tiles_skipped": [{"index": i["index"], "reason": i["skipped"]}
                                  for i in infos if "skipped" in i],
                "convention": "x_right = x_left - d, pixels, NaN = not matched"}

    run.log.info("matching %s / %s in tiles: %d x %d px, disparity range %.1f … %.1f px "
                 "(%s)", left_path, right_path, width, height, low, high, rectify)
    return run_tiled(run, job, tiling, outputs, inputs=[left_path, right_path, rectify],
                     parameters=params.as_dict(), transform=transform,
                     workers=params.workers, scheduler=params.scheduler,
                     dry_run=params.dry_run, summarize=summarize)
