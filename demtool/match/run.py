"""Runner of ``demtool match``: area-based dense matching of a stereo pair."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from demtool.stagerun import StageRun, check_stereo_pair, sidecar_path

if TYPE_CHECKING:
    from demtool.match.params import MatchParams


def _load_pair(left_path: str | os.PathLike, right_path: str | os.PathLike,
               rectify: str | os.PathLike | None):
    """Read the pair; warp it onto the rectified canvas when it is the original pair.

    Returns
    -------
    left, right : Raster
        As read.
    left_rect, right_rect : (H, W) float arrays
        The rectified images that are matched.
    rect : dict or None
        Content of rectify.npz.
    warped : bool
        True when the pair was warped here with rectify.npz's homographies.
    """
    import numpy as np

    from demtool import io as dio
    from demtool.errors import InputError

    left = dio.read_raster(left_path, what="left image")
    right = dio.read_raster(right_path, what="right image")
    if rectify is None:
        from demtool.mapproject.stereo import is_ortho_pair

        # orthoimages: their grids are checked with their matches (ortho_pair_matches)
        if left.data.shape != right.data.shape and not is_ortho_pair(left, right):
            raise InputError(
                f"{left_path} and {right_path}: the rectified images differ in size "
                f"({left.data.shape[1]} x {left.data.shape[0]} and {right.data.shape[1]} x "
                f"{right.data.shape[0]}, width x height); give a rectified pair (demtool "
                "rectify) or the original pair with --rectify RECTIFY_NPZ")
        return left, right, left.data, right.data, None, False
    rect = dio.read_npz(rectify, "rectification")
    size_rect = tuple(int(v) for v in rect["size_rect"])
    size_left = tuple(int(v) for v in rect["size_left"])
    size_right = tuple(int(v) for v in rect["size_right"])
    shape_left = (left.data.shape[1], left.data.shape[0])
    shape_right = (right.data.shape[1], right.data.shape[0])
    tagged_rectified = "rectified_from" in left.tags and "rectified_from" in right.tags
    if tagged_rectified or (shape_left == shape_right == size_rect
                            and not (shape_left == size_left and shape_right == size_right)):
        if not shape_left == shape_right == size_rect:
            raise InputError(
                f"{left_path} and {right_path}: rectified images of {shape_left[0]} x "
                f"{shape_left[1]} and {shape_right[0]} x {shape_right[1]} px, but {rectify} "
                f"describes a {size_rect[0]} x {size_rect[1]} canvas; is it from this pair?")
        return left, right, left.data, right.data, rect, False
    if shape_left == size_left and shape_right == size_right:
        from demtool.imaging.homography import warp_to_rectified

        left_rect = warp_to_rectified(left.data, rect["H_left"], rect["size_rect"])
        right_rect = warp_to_rectified(right.data, rect["H_right"], rect["size_rect"])
        if not (np.isfinite(left_rect).any() and np.isfinite(right_rect).any()):
            raise InputError(f"{rectify}: the homographies map the images off the rectified "
                             "canvas; is it from this pair?")
        return left, right, left_rect, right_rect, rect, True
    raise InputError(
        f"{left_path} ({shape_left[0]} x {shape_left[1]}) and {right_path} ({shape_right[0]} x "
        f"{shape_right[1]}) match neither the original sizes ({size_left[0]} x {size_left[1]}, "
        f"{size_right[0]} x {size_right[1]}) nor the rectified canvas ({size_rect[0]} x "
        f"{size_rect[1]}) of {rectify}; is it from this pair?")


def run_match(left_path: str | os.PathLike, right_path: str | os.PathLike,
              out: str | os.PathLike, params: MatchParams | None = None, *,
              rectify: str | os.PathLike | None = None,
              correlation_out: str | os.PathLike | None = None,
              sigma_out: str | os.PathLike | None = None,
              resolved: dict[str, Any] | None = None):
    """Match a stereo pair (:func:`_run_match`) with ``params.workers`` numba threads in
    the calling thread for the run, restored after it (numba's count is per thread; an
    in-process caller keeps its own)."""
    from demtool.tiling.tasks import numba_threads_at_most

    with numba_threads_at_most(int((params or MatchParams()).workers or 0)):
        return _run_match(left_path, right_path, out, params, rectify=rectify,
                          correlation_out=correlation_out, sigma_out=sigma_out,
                          resolved=resolved)


def _run_match(left_path: str | os.PathLike, right_path: str | os.PathLike,
               out: str | os.PathLike, params: MatchParams | None = None, *,
               rectify: str | os.PathLike | None = None,
               correlation_out: str | os.PathLike | None = None,
               sigma_out: str | os.PathLike | None = None,
               resolved: dict[str, Any] | None = None):
    """Match a stereo pair; write the disparity GeoTIFF (+ correlation, sigma, sidecar).

    ``left_path``/``right_path`` are a rectified pair (as written by ``demtool
    rectify``), or — with ``rectify`` — the original pair, which is then warped onto
    the rectified canvas with the homographies of ``rectify.npz`` (bilinear, NaN
    outside).  ``rectify.npz`` also supplies seed matches (its rectified inliers) and
    the disparity range.  Two orthoimages of ``demtool mapproject`` on one map grid
    (no ``rectify``) are matched along map x, seeded by their SIFT matches, which also
    set the range (:func:`demtool.mapproject.stereo.ortho_pair_matches`); the disparity is then
    on the left orthoimage's grid (transform and CRS), for ``dem --mapprojected``.
    All outputs are written in one output transaction.

    Large pairs run in tiles (``--tile-size``, ``--workers``, ``--scheduler``,
    ``--dry-run``; :mod:`demtool.match.tiled`), written window by window.

    Returns
    -------
    demtool.match.MatchResult, or demtool.tiling.jobs.TiledResult for a tiled run
    """
    import numpy as np

    from demtool import io as dio
    from demtool.mapproject.stereo import is_ortho_pair, ortho_pair_matches
    from demtool.match import check_seed_points, match
    from demtool.match.params import MatchParams

    params = params or MatchParams()
    run = StageRun("match", params, resolved=resolved,
                   inputs={"LEFT": left_path, "RIGHT": right_path, "--rectify": rectify},
                   outputs={"--out": out, "--correlation-out": correlation_out,
                            "--sigma-out": sigma_out, "sidecar": sidecar_path(out)})
    log, provenance = run.log, run.provenance
    out_path = Path(out)
    template, threshold, grid_spacing = params.template, params.threshold, params.grid_spacing
    from demtool import tiling

    shape = tiling.raster_shape(left_path, "left image")
    if tiling.wants_tiles(*shape, params):  # large pairs: tiles, Dask (docs/stages/scale.md)
        from demtool.match.tiled import match_tiled

        return match_tiled(run, left_path, right_path, out, params, shape, rectify=rectify,
                           correlation_out=correlation_out, sigma_out=sigma_out)
    left, right, left_rect, right_rect, rect, warped = _load_pair(left_path, right_path, rectify)
    check_stereo_pair(left, right, rectify, rectification=rect, rectified=not warped)
    seed_points = None
    disparity_range = None
    ortho_stats: dict[str, Any] = {}
    if rect is None and is_ortho_pair(left, right):  # map-projected stereo (issue 12)
        found, source, ortho_stats = ortho_pair_matches(left, right, stage="match")
        seed_points = (found.points_left, found.points_right)
        disparity_range = (found.low, found.high)
        ortho_stats["disparity_range_source"] = source
        log.info("orthoimages on one map grid: %d seeds from their matches, disparity "
                 "%.2f … %.2f cells", found.matches, found.low, found.high)
    if rect is not None:
        seed_points = check_seed_points(rect["points_left_rect"], rect["points_right_rect"],
                                        left_rect.shape, right_rect.shape,
                                        what=f"{rectify} (points_left_rect/points_right_rect)")
        disparity_range = tuple(float(v) for v in rect["disparity_range"])
        if warped:
            log.info("warped %s and %s onto the %d x %d rectified canvas of %s", left_path,
                     right_path, left_rect.shape[1], left_rect.shape[0], rectify)
    log.info("matching %s / %s: %d x %d px, template %d, threshold %.2f, grid %d, %d level(s)",
             left_path, right_path, left_rect.shape[1], left_rect.shape[0], template, threshold,
             grid_spacing, params.levels)
    result = match(left_rect, right_rect, seed_points=seed_points,
                   disparity_range=disparity_range, **params.matcher_options())

    if warped:
        frame = f"image:{Path(left_path).stem}_rect"
    else:
        frame = left.tags.get("frame", f"image:{Path(left_path).stem}")
    summary = {**result.summary, **ortho_stats, "input_rectified_here": warped,
               "convention": "x_right = x_left - d, pixels, NaN = not matched"}
    tags = provenance.tags(frame=frame, disparity_convention="x_right = x_left - d",
                           template=template, threshold=threshold, grid_spacing=grid_spacing,
                           completeness_percent=result.summary["completeness_percent"])
    transform = left.transform if not warped else dio.image_frame_transform(1.0)
    crs = left.crs if not warped else None  # an orthoimage's map CRS
    outputs: list[str | os.PathLike] = [out_path]
    with run.transaction():
        dio.write_raster(out_path, result.disparity, transform=transform, crs=crs, tags=tags,
                         band_names=["disparity"])
        if correlation_out is not None:
            dio.write_raster(correlation_out, result.correlation, transform=transform,
                             crs=crs, tags={**tags, "quantity": "LSM correlation coefficient"},
                             band_names=["correlation"])
            outputs.append(correlation_out)
        if sigma_out is not None:
            dio.write_raster(sigma_out, result.sigma, transform=transform, crs=crs,
                             tags={**tags, "quantity": "LSM standard deviation of the "
                                                       "disparity, pixels"},
                             band_names=["sigma"])
            outputs.append(sigma_out)
        provenance.write_sidecar(out_path, summary, outputs=outputs)
    values = result.disparity[np.isfinite(result.disparity)]
    log.info("wrote %s: %.1f %% complete, disparity %s", out_path,
             result.summary["completeness_percent"],
             f"{values.min():.2f} … {values.max():.2f} px" if values.size else "none")
    return result
