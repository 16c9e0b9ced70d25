"""`demtool match`: area-based dense matching of a stereo pair (runner and command)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import click

from demtool import option_types as ot
from demtool import options
from demtool.cli import STAGES


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
        if left.data.shape != right.data.shape:
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
        from demtool.homography import warp_to_rectified

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
              out: str | os.PathLike, *, rectify: str | os.PathLike | None = None,
              template: int = 17, threshold: float = 0.9, grid_spacing: int = 1,
              levels: int = 3, search_margin: float = 2.0, rounds: int = 2,
              max_vertical: float = 1.5, sift: bool = True, weighting: float = 3.0,
              correlation_out: str | os.PathLike | None = None,
              sigma_out: str | os.PathLike | None = None, workers: int = 0,
              params: dict[str, Any] | None = None):
    """Match a stereo pair; write the disparity GeoTIFF (+ correlation, sigma, sidecar).

    ``left_path``/``right_path`` are a rectified pair (as written by ``demtool
    rectify``), or — with ``rectify`` — the original pair, which is then warped onto
    the rectified canvas with the homographies of ``rectify.npz`` (bilinear, NaN
    outside).  ``rectify.npz`` also supplies seed matches (its rectified inliers) and
    the disparity range.  All outputs are written in one output transaction.

    Returns
    -------
    demtool.match.MatchResult
    """
    import numpy as np

    from demtool import io as dio
    from demtool.errors import ParameterError
    from demtool.logs import get_logger
    from demtool.match import check_parameters, check_seed_points, match
    from demtool.provenance import Provenance

    log = get_logger("demtool.match")
    check_parameters(template, threshold, grid_spacing, levels, search_margin, rounds,
                     weighting)
    out_path = Path(out)
    extra = {"--correlation-out": correlation_out, "--sigma-out": sigma_out}
    for option, path in extra.items():
        if path is not None and Path(path).resolve() == out_path.resolve():
            raise ParameterError(f"{option} {path} is the same file as --out")
    if correlation_out is not None and sigma_out is not None and \
            Path(correlation_out).resolve() == Path(sigma_out).resolve():
        raise ParameterError(f"--correlation-out and --sigma-out are the same file {sigma_out}")
    if out_path.is_dir():
        raise ParameterError(f"{out_path}: --out must be a file name, but it is a folder")
    if workers:
        import numba

        numba.set_num_threads(min(int(workers), numba.config.NUMBA_NUM_THREADS))

    left, right, left_rect, right_rect, rect, warped = _load_pair(left_path, right_path, rectify)
    seed_points = None
    disparity_range = None
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
             grid_spacing, levels)
    inputs = [left_path, right_path] + ([rectify] if rectify is not None else [])
    provenance = Provenance("match", params or {}, inputs)
    result = match(left_rect, right_rect, template=template, threshold=threshold,
                   grid_spacing=grid_spacing, levels=levels, search_margin=search_margin,
                   rounds=rounds, seed_points=seed_points, disparity_range=disparity_range,
                   use_sift=sift, max_vertical=max_vertical, weighting=weighting)

    if warped:
        frame = f"image:{Path(left_path).stem}_rect"
    else:
        frame = left.tags.get("frame", f"image:{Path(left_path).stem}")
    summary = {**result.summary, "input_rectified_here": warped,
               "convention": "x_right = x_left - d, pixels, NaN = not matched"}
    tags = provenance.tags(frame=frame, disparity_convention="x_right = x_left - d",
                           template=template, threshold=threshold, grid_spacing=grid_spacing,
                           completeness_percent=result.summary["completeness_percent"])
    transform = left.transform if not warped else dio.image_frame_transform(1.0)
    outputs: list[str | os.PathLike] = [out_path]
    with dio.output_transaction():
        dio.write_raster(out_path, result.disparity, transform=transform, tags=tags,
                         band_names=["disparity"])
        if correlation_out is not None:
            dio.write_raster(correlation_out, result.correlation, transform=transform,
                             tags={**tags, "quantity": "LSM correlation coefficient"},
                             band_names=["correlation"])
            outputs.append(correlation_out)
        if sigma_out is not None:
            dio.write_raster(sigma_out, result.sigma, transform=transform,
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


def _odd_template(ctx: click.Context, param: click.Parameter, value: int) -> int:
    if value % 2 == 0:
        raise click.BadParameter(f"must be odd (the template has a centre pixel), got {value}")
    return value


@click.command(name="match", help=STAGES["match"] + """

Matches LEFT and RIGHT, a rectified pair (as written by demtool rectify), or the
original pair together with --rectify RECTIFY_NPZ (then warped here onto the
rectified canvas).  Writes OUT, the float32 disparity in the left rectified frame
(x_right = x_left - d, NaN = not matched), and OUT.json.  Seeds: SIFT, Förstner
corners and the control points of --rectify, verified by LSM; a match is accepted
when its final LSM correlation coefficient reaches --threshold.""")
@options.input_file("left")
@options.input_file("right")
@options.out_file("Output disparity GeoTIFF.")
@click.option("--rectify", "rectify", type=click.Path(dir_okay=False), default=None,
              help="rectify.npz: seed matches, disparity range, and homographies to warp an "
                   "original (unrectified) pair.")
@click.option("--template", type=ot.IntRange(9, 25), default=17, show_default=True,
              callback=_odd_template, help="Template size, px (odd).")
@click.option("--threshold", type=ot.FloatRange(0.0, 1.0, min_open=True, max_open=True),
              default=0.9, show_default=True,
              help="Acceptance threshold on the LSM correlation coefficient (0.8 relaxed).")
@click.option("--grid-spacing", type=ot.IntRange(min=1), default=1, show_default=True,
              help="Pixels between template centres; pixels between four accepted nodes are "
                   "interpolated bilinearly, others stay NaN.")
@click.option("--levels", type=ot.IntRange(1, 8), default=3, show_default=True,
              help="Image pyramid levels (NCC coarse to fine).")
@click.option("--search-margin", type=ot.FloatRange(min=0.0), default=2.0,
              show_default=True,
              help="Pixels added to each side of a triangle's vertex-disparity range.")
@click.option("--rounds", type=ot.IntRange(min=0), default=2, show_default=True,
              help="Densification rounds: accepted matches join the triangulation and the "
                   "rejected nodes are matched again.")
@click.option("--max-vertical", type=ot.FloatRange(min=0.0, min_open=True), default=1.5,
              show_default=True, help="Largest row offset of an accepted match, px.")
@click.option("--weighting", type=ot.FloatRange(min=0.0), default=3.0, show_default=True,
              help="Gaussian LSM observation weights of this sigma, px (0 = uniform, the "
                   "HiRISE study's LSM). Centre weighting resolves fine relief that a "
                   "uniform template averages away.")
@click.option("--sift/--no-sift", default=True, show_default=True,
              help="Detect SIFT seed matches (besides Förstner corners and --rectify's).")
@click.option("--correlation-out", type=click.Path(dir_okay=False), default=None,
              help="Also write the LSM correlation coefficient of every evaluated template.")
@click.option("--sigma-out", type=click.Path(dir_okay=False), default=None,
              help="Also write the LSM standard deviation of the accepted disparities, px.")
@options.workers()
@click.pass_context
def command(ctx: click.Context, left: str, right: str, out: str, **kwargs) -> None:
    run_match(left, right, out, params=options.resolved_params(ctx), **kwargs)
