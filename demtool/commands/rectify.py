"""`demtool rectify`: uncalibrated rectification of a stereo pair (runner and command)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import click

from demtool import options
from demtool.cli import STAGES

LEFT_RECT = "left_rect.tif"
RIGHT_RECT = "right_rect.tif"
RECTIFY_NPZ = "rectify.npz"


def run_rectify(left_path: str | os.PathLike, right_path: str | os.PathLike,
                out_dir: str | os.PathLike, *, min_matches: int = 30, ratio: float = 0.8,
                ransac_threshold: float = 1.0, max_vertical_residual: float = 1.0,
                shear: bool = True, disparity_margin: float = 2.0, max_features: int = 0,
                contrast_threshold: float = 0.04, seed: int = 0,
                disparity_range: tuple[float, float] | None = None,
                params: dict[str, Any] | None = None):
    """Rectify LEFT and RIGHT into ``out_dir``: left_rect.tif, right_rect.tif, rectify.npz.

    Reads both images, calls :func:`demtool.rectify.rectify_pair`, warps the images onto
    the common rectified canvas and writes everything (plus the sidecar
    ``rectify.npz.json``) in one output transaction.

    Returns
    -------
    demtool.rectify.Rectification
    """
    import numpy as np

    from demtool import io as dio
    from demtool.errors import InputError
    from demtool.logs import get_logger
    from demtool.provenance import Provenance
    from demtool.rectify import rectify_pair, warp_to_rectified

    log = get_logger("demtool.rectify")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: --out must be a folder, but a file of that name exists")
    left_image = dio.read_image(left_path, what="left image")
    right_image = dio.read_image(right_path, what="right image")
    left_name, right_name = Path(left_path).stem, Path(right_path).stem
    pair = f"{left_path} / {right_path}"
    if left_image.data.shape != right_image.data.shape:
        log.info("%s: the images differ in size (%d x %d and %d x %d); that is fine", pair,
                 left_image.data.shape[1], left_image.data.shape[0],
                 right_image.data.shape[1], right_image.data.shape[0])
    provenance = Provenance("rectify", params or {}, [left_path, right_path])
    result = rectify_pair(left_image.data, right_image.data, min_matches=min_matches,
                          ratio=ratio, ransac_threshold=ransac_threshold,
                          max_vertical_residual=max_vertical_residual, shear=shear,
                          disparity_margin=disparity_margin, max_features=max_features,
                          contrast_threshold=contrast_threshold, seed=seed,
                          disparity_range=disparity_range or None, what=pair)
    left_rect = warp_to_rectified(left_image.data, result.H_left, result.size_rect)
    right_rect = warp_to_rectified(right_image.data, result.H_right, result.size_rect)
    residuals = result.vertical_residuals
    summary = {
        "left": left_name,
        "right": right_name,
        "matches": result.n_matches,
        "ransac_inliers": result.n_ransac_inliers,
        "inliers": len(result.points_left),
        "outlier_iterations": result.iterations,
        "rms_vertical_residual_px": round(result.rms_vertical_residual, 4),
        "max_abs_vertical_residual_px": round(float(np.max(np.abs(residuals))), 4),
        "disparity_range_px": [round(float(v), 3) for v in result.disparity_range],
        "inlier_disparity_px": [round(float(result.disparities.min()), 3),
                                round(float(result.disparities.max()), 3)],
        "size_left": result.size_left.tolist(),
        "size_right": result.size_right.tolist(),
        "size_rect": result.size_rect.tolist(),
    }
    log.info("%s: %d matches, %d RANSAC inliers, %d control points after %d outlier "
             "pass(es)", pair, result.n_matches, result.n_ransac_inliers,
             len(result.points_left), result.iterations)
    log.info("RMS vertical residual %.3f px (max %.3f px); disparity range %.1f … %.1f px "
             "(inliers %.1f … %.1f); rectified canvas %d x %d",
             result.rms_vertical_residual, summary["max_abs_vertical_residual_px"],
             *result.disparity_range, *summary["inlier_disparity_px"], *result.size_rect)
    arrays = {
        "H_left": result.H_left, "H_right": result.H_right, "F": result.F,
        "size_left": result.size_left, "size_right": result.size_right,
        "size_rect": result.size_rect,
        "points_left": result.points_left, "points_right": result.points_right,
        "points_left_rect": result.points_left_rect,
        "points_right_rect": result.points_right_rect,
        "disparity_range": result.disparity_range,
        "left_name": np.asarray(left_name), "right_name": np.asarray(right_name),
        "vertical_residuals": residuals,
        "rms_vertical_residual": np.asarray(result.rms_vertical_residual),
        "n_matches": np.asarray(result.n_matches),
        "n_ransac_inliers": np.asarray(result.n_ransac_inliers),
        "iterations": np.asarray(result.iterations),
    }
    npz_path = out / RECTIFY_NPZ
    with dio.output_transaction():
        for path, image, name, H in ((out / LEFT_RECT, left_rect, left_name, result.H_left),
                                     (out / RIGHT_RECT, right_rect, right_name, result.H_right)):
            dio.write_raster(path, image, transform=dio.image_frame_transform(1.0),
                             tags=provenance.tags(frame=f"image:{name}_rect", rectified_from=name,
                                                  homography=H.tolist(),
                                                  disparity_range=result.disparity_range.tolist()))
        dio.write_npz(npz_path, "rectification", arrays)
        provenance.write_sidecar(npz_path, summary,
                                 outputs=[out / LEFT_RECT, out / RIGHT_RECT, npz_path])
    return result


@click.command(name="rectify", help=STAGES["rectify"] + """

Writes OUT/left_rect.tif and OUT/right_rect.tif (NaN outside the warped images),
OUT/rectify.npz (H_left, H_right, F, inlier control points, disparity range) and
OUT/rectify.npz.json.  Rectified rows correspond; disparity d = x_left - x_right,
centred on zero over the control points.""")
@options.input_file("left")
@options.input_file("right")
@options.out_dir("Output folder for left_rect.tif, right_rect.tif and rectify.npz.")
@click.option("--min-matches", type=click.IntRange(min=8), default=30, show_default=True,
              help="Fewest SIFT matches (and final control points) accepted.")
@click.option("--ratio", type=click.FloatRange(0.0, 1.0, min_open=True), default=0.8,
              show_default=True, help="Lowe's ratio-test threshold.")
@click.option("--ransac-threshold", type=click.FloatRange(0.0, min_open=True), default=1.0,
              show_default=True, help="Inlier threshold of the robust F (Sampson distance), px.")
@click.option("--max-vertical-residual", type=click.FloatRange(0.0, min_open=True),
              default=1.0, show_default=True,
              help="Drop control points whose rectified rows differ by more (px), re-estimate.")
@click.option("--shear/--no-shear", default=True, show_default=True,
              help="Loop-Zhang shear keeping rectified pixels square.")
@click.option("--disparity-margin", type=click.FloatRange(0.0), default=2.0, show_default=True,
              help="Least pixels added to each side of the inliers' robust disparity range "
                   "(1st-99th percentile; 10 % of its span when more).")
@click.option("--disparity-range", type=(float, float), default=None,
              metavar="MIN MAX", help="Disparity search range to record, px (default: from "
                                      "the control points).")
@click.option("--max-features", type=click.IntRange(min=0), default=0, show_default=True,
              help="SIFT keypoints kept per image, strongest first (0 = all).")
@click.option("--contrast-threshold", type=click.FloatRange(0.0, min_open=True), default=0.04,
              show_default=True, help="SIFT contrast threshold (lower: more keypoints).")
@options.seed()
@click.pass_context
def command(ctx: click.Context, left: str, right: str, out: str, **kwargs) -> None:
    run_rectify(left, right, out, params=options.resolved_params(ctx), **kwargs)
