"""Runner of ``demtool sgm``: semi-global matching of a rectified pair."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from demtool.stagerun import StageRun, check_stereo_pair, sidecar_path

if TYPE_CHECKING:
    from demtool.sgm.params import SgmParams

PAIR_WHAT = ("left rectified image", "right rectified image")


def disparity_range_from_rectify(path: str | os.PathLike) -> tuple[int, int]:
    """(min_disparity, num_disparities) covering ``disparity_range`` of a rectify.npz."""
    from demtool import io as dio
    from demtool.errors import InputError

    content = dio.read_npz(path, "rectification")
    low, high = (float(v) for v in content["disparity_range"])
    if not (math.isfinite(low) and math.isfinite(high)) or high < low:
        raise InputError(f"{path}: disparity_range {low:g} … {high:g} is not a valid range")
    min_disparity = math.floor(low)
    return min_disparity, math.ceil(high) - min_disparity + 1


def ortho_pair_range(left, right) -> tuple[tuple[int, int], str, dict[str, Any]]:
    """(min_disparity, num_disparities), its source and summary entries for two
    orthoimages on one map grid (:func:`demtool.mapproject.stereo.ortho_pair_matches`)."""
    from demtool.mapproject.stereo import ortho_pair_matches

    found, source, stats = ortho_pair_matches(left, right, stage="sgm", allow_shift=True)
    min_disparity = math.floor(found.low)
    return (min_disparity, math.ceil(found.high) - min_disparity + 1), source, stats


def _first_kernel() -> None:
    import numpy as np

    from demtool.sgm.extremes import percentiles

    percentiles(np.arange(1024, dtype=np.float32), (0.5, 99.5))


def start_numba():
    """Start numba's CPU target (its first kernel call in a process: ~0.3 s, part of it
    in LLVM without the GIL) in a thread; returns the thread.

    The pair's reads (GDAL) and texture checks (numpy) run meanwhile: 2048² census,
    quiet machine, best of 4 alternated: the sidecar's prepare 0.39 -> 0.11 s, wall
    2.59 -> 2.40 s.  (Loading all of a census match's kernels there too, by matching a
    small random pair, saved another 0.07 s but raised the peak memory by 31 MB: the
    thread's own malloc arena.)
    """
    from demtool.tiling.side_threads import start_side_thread

    return start_side_thread(_first_kernel, "demtool-numba")


def run_sgm(left_path: str | os.PathLike, right_path: str | os.PathLike,
            out: str | os.PathLike, params: SgmParams | None = None, *,
            rectify: str | os.PathLike | None = None,
            confidence: str | os.PathLike | None = None,
            classes: str | os.PathLike | None = None,
            prior_dem: str | os.PathLike | None = None,
            resolved: dict[str, Any] | None = None):
    """Match LEFT_RECT and RIGHT_RECT; write the disparity GeoTIFF (and confidence).

    The disparity range is ``params.min_disparity/num_disparities`` when given, else
    the ``disparity_range`` of ``rectify``.  Writes ``out`` (float32 disparity in the left
    rectified image's frame, ``x_right = x_left − d``, NaN = invalid), optionally the
    confidence raster, and the sidecar ``<out>.json``, all in one output transaction.

    Large pairs run in tiles (``--tile-size``, ``--workers``, ``--scheduler``,
    ``--dry-run``; :mod:`demtool.sgm.tiled`), written window by window.

    With ``prior_dem`` (a DEM on the body's map, e.g. a fused DEM of the block) and a
    calibrated ``rectify``, the right image is warped by the disparity the DEM predicts
    and only the residual is searched, ± ``params.prior_search`` px
    (:mod:`demtool.sgm.prior`); OUT is the total disparity.

    Returns
    -------
    demtool.sgm.SGMResult, or demtool.tiling.jobs.TiledResult for a tiled run
    """
    import numpy as np

    from demtool import io as dio
    from demtool import tiling
    from demtool.errors import InputError, ParameterError
    from demtool.mapproject.stereo import is_ortho_pair
    from demtool.sgm.params import SgmParams
    from demtool.sgm.widen import sgm_widening

    params = params or SgmParams()
    run = StageRun("sgm", params, resolved=resolved,
                   inputs={"LEFT_RECT": left_path, "RIGHT_RECT": right_path,
                           "--rectify": rectify, "--prior-dem": prior_dem},
                   outputs={"--out": out, "--confidence": confidence, "--classes": classes,
                            "sidecar": sidecar_path(out)})
    log, provenance = run.log, run.provenance
    out_path = Path(out)
    sgm_options = params.matcher_options()
    min_disparity, num_disparities = params.min_disparity, params.num_disparities
    left_info = dio.raster_info(left_path, what="left rectified image")
    right_info = dio.raster_info(right_path, what="right rectified image")
    ortho = is_ortho_pair(left_info, right_info)
    if ortho and ((left_info.height, left_info.width) != (right_info.height, right_info.width)
                  or left_info.transform != right_info.transform):
        raise InputError(f"{left_path} and {right_path}: the orthoimages are on different "
                         "map grids; map-project the right one with --grid-like LEFT")
    left = right = None
    source = "--min-disparity/--num-disparities"
    ortho_stats: dict[str, Any] = {}
    if prior_dem is not None:
        if min_disparity is not None or num_disparities is not None or ortho:
            raise ParameterError(f"--prior-dem {prior_dem}: the search follows the prior DEM "
                                 "around a rectified pair; --min-disparity/--num-disparities "
                                 "and orthoimage pairs do not go with it")
        min_disparity, num_disparities = -params.prior_search, 2 * params.prior_search + 1
        source = f"--prior-dem {prior_dem} ± {params.prior_search} px"
    if min_disparity is None or num_disparities is None:
        if rectify is None and ortho:  # the range from the orthoimages' matches
            left, right = dio.read_raster_pair(left_path, right_path, what=PAIR_WHAT)
            from_file, source, ortho_stats = ortho_pair_range(left, right)
            min_disparity = from_file[0] if min_disparity is None else min_disparity
            num_disparities = from_file[1] if num_disparities is None else num_disparities
        elif rectify is None:
            from demtool.sensors.isis_map import refuse_cam2map_ortho

            for path, what in ((left_path, "the left image"), (right_path, "the right image")):
                refuse_cam2map_ortho(path, what)  # ISIS cam2map cubes: say what they lack
            raise ParameterError("give the disparity range: --rectify RECTIFY_NPZ, or both "
                                 "--min-disparity and --num-disparities (or two orthoimages "
                                 "from demtool mapproject)")
    limits: tuple[int | None, int | None] = (None, None)
    if min_disparity is None or num_disparities is None:
        from demtool.sgm.widen import limits_from_rectification

        from_file = disparity_range_from_rectify(rectify)
        min_disparity = from_file[0] if min_disparity is None else min_disparity
        num_disparities = from_file[1] if num_disparities is None else num_disparities
        source = f"{rectify} (disparity_range)"
        limits = limits_from_rectification(dio.read_npz(rectify, "rectification"))
        if limits[0] is not None:
            log.info("calibrated pair: disparity at infinity %d px; the range is never "
                     "widened below it", limits[0] + 1)
    shape = tiling.raster_shape(left_path, "left rectified image")
    right_shape = tiling.raster_shape(right_path, "right rectified image")
    if shape != right_shape:
        raise InputError(
            f"{left_path} and {right_path}: the rectified images differ in size "
            f"({shape[1]}×{shape[0]} and {right_shape[1]}×{right_shape[0]}, width×height); "
            "use the pair written by demtool rectify")
    width = shape[1]
    max_disparity = min_disparity + num_disparities - 1
    if num_disparities >= width or max(abs(min_disparity), abs(max_disparity)) >= width:
        raise ParameterError(f"disparity range {min_disparity} … {max_disparity} from {source} "
                             f"is wider than the images ({width} px)")
    from demtool.mapproject.stereo import ROW_SHIFT_TAG, shift_rows

    row_shift = ortho_stats.get(ROW_SHIFT_TAG)
    from demtool.sgm.tiled import sgm_tile_size

    if sgm_tile_size(params, shape, num_disparities):  # large: tiles (docs/stages/scale.md)
        if row_shift is not None:
            raise ParameterError(f"{right_path}: the orthoimages are offset by "
                                 f"{row_shift:.2f} rows, which untiled runs take out (give a "
                                 "larger --tile-size)")
        if prior_dem is not None:
            raise ParameterError(f"--prior-dem {prior_dem}: runs untiled (give a larger "
                                 "--tile-size)")
        if classes is not None:
            raise ParameterError(f"--classes {classes}: the class raster is written by "
                                 "untiled runs only (give a larger --tile-size)")
        from demtool.imaging.checks import check_rectification_matches
        from demtool.sgm.tiled import sgm_tiled

        if rectify is not None:  # the images are never read whole here: sizes only
            check_rectification_matches(dio.read_npz(rectify, "rectification"), rectify,
                                        {left_path: shape, right_path: shape}, rectified=True)

        return sgm_tiled(run, left_path, right_path, out, params, shape, source=source,
                         min_disparity=min_disparity, num_disparities=num_disparities,
                         confidence=confidence, rectify=rectify)
    loading = start_numba()  # meanwhile: the pair is read and checked
    try:
        if left is None:
            left, right = dio.read_raster_pair(left_path, right_path, what=PAIR_WHAT)
        check_stereo_pair(left, right, rectify)
    finally:  # also before a refusal's exit: no thread left inside numba's import
        loading.join()
    right_data, prior, summary_prior = right.data, None, {}
    if row_shift is not None:  # the pair's relative pointing, across map x
        right_data = shift_rows(right.data, row_shift)
    if prior_dem is not None:
        from demtool.sgm.prior import warp_right
        from demtool.sgm.run_prior import read_prior

        prior = read_prior(prior_dem, rectify, np.isfinite(left.data), params.prior_search,
                           log)
        right_data = warp_right(right.data, prior.disparity)
    log.info("matching %s / %s: %d×%d px, disparities %d … %d, cost %s, %d paths",
             left_path, right_path, width, left.data.shape[0], min_disparity, max_disparity,
             params.cost, params.paths)
    result = sgm_widening(left.data, right_data, min_disparity=min_disparity,
                          num_disparities=num_disparities, widenings=params.widenings,
                          lower_limit=limits[0], upper_limit=limits[1], **sgm_options)
    min_disparity = result.parameters["min_disparity"]
    num_disparities = result.parameters["num_disparities"]
    disparity = result.disparity
    if prior is not None:  # the residual around the prediction → the total disparity
        summary_prior = {**prior.summary, "residual_median_px": float(np.nanmedian(disparity))
                         if np.isfinite(disparity).any() else None}
        disparity = disparity + prior.disparity
        # the total range searched: the prediction's extremes plus the residual's bounds
        # (after any widening of the residual range)
        low = math.floor(float(np.nanmin(prior.disparity))) + min_disparity
        high = math.ceil(float(np.nanmax(prior.disparity))) + min_disparity + num_disparities - 1
        min_disparity, num_disparities = low, high - low + 1
    valid = np.isfinite(disparity)
    input_valid = np.isfinite(left.data)
    values = disparity[valid]
    stats: dict[str, Any] = {"valid_fraction": round(float(valid.mean()), 4),
                             "valid_fraction_of_input": round(
                                 float(valid.sum() / max(int(input_valid.sum()), 1)), 4)}
    if values.size:
        percentiles = np.percentile(values, [1, 50, 99])
        stats.update(disparity_min=float(values.min()), disparity_max=float(values.max()),
                     disparity_mean=float(values.mean()), disparity_std=float(values.std()),
                     disparity_p01=float(percentiles[0]), disparity_median=float(percentiles[1]),
                     disparity_p99=float(percentiles[2]),
                     confidence_mean=float(np.nanmean(result.confidence)))
    else:
        log.warning("no valid disparity: check the disparity range and the image pair")
    fractions = result.fractions
    if fractions:
        stats.update({f"{k}_fraction": v for k, v in fractions.items()
                      if isinstance(v, float) and k != "noise_sigma"})
        stats["lr_consistent_fraction"] = round(fractions["matched"]
                                                + fractions["at_range_bound"], 4)
        for key in ("cost_used", "cost_reason", "noise_sigma"):
            if key in fractions:
                stats[key] = fractions[key]
        log.info("of the valid left pixels: %.1f %% left-right consistent (%.1f %% of them "
                 "at a bound of the range), %.1f %% filled as occlusions, %.1f %% filled as "
                 "mismatches, %.1f %% without a disparity",
                 100 * stats["lr_consistent_fraction"],
                 100 * fractions["at_range_bound"], 100 * fractions["filled_occlusion"],
                 100 * fractions["filled_mismatch"], 100 * fractions["invalid"])
    log.info("%.1f %% of the pixels with a disparity (matched or filled); disparity %s; "
             "%.1f s (%s)", 100 * stats["valid_fraction"],
             f"{stats['disparity_min']:.1f} … {stats['disparity_max']:.1f}" if values.size
             else "none", result.timings["total"],
             ", ".join(f"{k} {v:.1f} s" for k, v in result.timings.items() if k != "total"))
    summary = {**stats, "min_disparity": min_disparity, "num_disparities": num_disparities,
               "disparity_range_px": [min_disparity, min_disparity + num_disparities - 1],
               "disparity_range_source": source,
               "widening_limits_px": list(limits),
               "range_widenings": result.parameters["range_widenings"],
               "resolved": result.parameters,
               **ortho_stats, **summary_prior, "timings_s": result.timings, "passes": result.levels,
               "convention": "x_right = x_left - d, pixels, NaN = invalid"}
    frame = left.tags.get("frame", f"image:{Path(left_path).stem}")
    tags = provenance.tags(frame=frame, disparity_convention="x_right = x_left - d",
                           min_disparity=min_disparity, num_disparities=num_disparities,
                           cost=result.parameters["cost"],
                           **({} if row_shift is None else {ROW_SHIFT_TAG: row_shift}))
    outputs: list[str | os.PathLike] = [out_path]
    with run.transaction():
        dio.write_raster(out_path, disparity, transform=left.transform, crs=left.crs,
                         tags=tags, band_names=["disparity"])
        if confidence is not None:
            dio.write_raster(confidence, result.confidence, transform=left.transform,
                             crs=left.crs,
                             tags={**tags, "quantity": "sgm confidence (S2 - S1) / S2"},
                             band_names=["confidence"])
            outputs.append(confidence)
        if classes is not None:
            dio.write_raster(classes, result.classes, transform=left.transform, crs=left.crs,
                             tags={**tags, "quantity": "sgm pixel class: 0 invalid, 1 matched, "
                                   "2 filled occlusion, 3 filled mismatch, 4 matched at a "
                                   "range bound"},
                             band_names=["class"])
            outputs.append(classes)
        provenance.write_sidecar(out_path, summary, outputs=outputs)
    return result
