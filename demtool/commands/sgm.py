"""`demtool sgm`: semi-global matching of a rectified pair (runner and command)."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import click

from demtool import options
from demtool.cli import STAGES

COST_CHOICES = ("hmi", "mi", "census", "ad")


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


def run_sgm(left_path: str | os.PathLike, right_path: str | os.PathLike,
            out: str | os.PathLike, *, rectify: str | os.PathLike | None = None,
            min_disparity: int | None = None, num_disparities: int | None = None,
            confidence: str | os.PathLike | None = None, params: dict[str, Any] | None = None,
            **sgm_options: Any):
    """Match LEFT_RECT and RIGHT_RECT; write the disparity GeoTIFF (and confidence).

    The disparity range is ``--min-disparity/--num-disparities`` when given, else the
    ``disparity_range`` of ``rectify``.  Writes ``out`` (float32 disparity in the left
    rectified image's frame, ``x_right = x_left − d``, NaN = invalid), optionally the
    confidence raster, and the sidecar ``<out>.json``, all in one output transaction.

    Returns
    -------
    demtool.sgm.SGMResult
    """
    import numpy as np

    from demtool import io as dio
    from demtool.errors import InputError, ParameterError
    from demtool.logs import get_logger
    from demtool.provenance import Provenance
    from demtool.sgm import sgm

    log = get_logger("demtool.sgm")
    out_path = Path(out)
    if confidence is not None and Path(confidence).resolve() == out_path.resolve():
        raise ParameterError(f"--confidence {confidence} is the same file as --out")
    if out_path.exists() and out_path.is_dir():
        raise InputError(f"{out_path}: --out must be a file name, but it is a folder")
    left = dio.read_raster(left_path, what="left rectified image")
    right = dio.read_raster(right_path, what="right rectified image")
    if left.data.shape != right.data.shape:
        raise InputError(
            f"{left_path} and {right_path}: the rectified images differ in size "
            f"({left.data.shape[1]}×{left.data.shape[0]} and {right.data.shape[1]}×"
            f"{right.data.shape[0]}, width×height); use the pair written by demtool rectify")
    source = "--min-disparity/--num-disparities"
    if min_disparity is None or num_disparities is None:
        if rectify is None:
            raise ParameterError("give the disparity range: --rectify RECTIFY_NPZ, or both "
                                 "--min-disparity and --num-disparities")
        from_file = disparity_range_from_rectify(rectify)
        min_disparity = from_file[0] if min_disparity is None else min_disparity
        num_disparities = from_file[1] if num_disparities is None else num_disparities
        source = f"{rectify} (disparity_range)"
    width = left.data.shape[1]
    max_disparity = min_disparity + num_disparities - 1
    if num_disparities >= width or max(abs(min_disparity), abs(max_disparity)) >= width:
        raise ParameterError(f"disparity range {min_disparity} … {max_disparity} from {source} "
                             f"is wider than the images ({width} px)")
    log.info("matching %s / %s: %d×%d px, disparities %d … %d, cost %s, %d paths",
             left_path, right_path, width, left.data.shape[0], min_disparity, max_disparity,
             sgm_options.get("cost", "hmi"), sgm_options.get("paths", 8))
    inputs = [left_path, right_path] + ([rectify] if rectify is not None else [])
    provenance = Provenance("sgm", params or {}, inputs)
    result = sgm(left.data, right.data, min_disparity=min_disparity,
                 num_disparities=num_disparities, **sgm_options)
    disparity = result.disparity
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
    log.info("%.1f %% of the pixels valid; disparity %s; %.1f s (%s)",
             100 * stats["valid_fraction"],
             f"{stats['disparity_min']:.1f} … {stats['disparity_max']:.1f}" if values.size
             else "none", result.timings["total"],
             ", ".join(f"{k} {v:.1f} s" for k, v in result.timings.items() if k != "total"))
    summary = {**stats, "min_disparity": min_disparity, "num_disparities": num_disparities,
               "disparity_range_source": source, "resolved": result.parameters,
               "timings_s": result.timings, "passes": result.levels,
               "convention": "x_right = x_left - d, pixels, NaN = invalid"}
    frame = left.tags.get("frame", f"image:{Path(left_path).stem}")
    tags = provenance.tags(frame=frame, disparity_convention="x_right = x_left - d",
                           min_disparity=min_disparity, num_disparities=num_disparities,
                           cost=result.parameters["cost"])
    outputs: list[str | os.PathLike] = [out_path]
    with dio.output_transaction():
        dio.write_raster(out_path, disparity, transform=left.transform, tags=tags,
                         band_names=["disparity"])
        if confidence is not None:
            dio.write_raster(confidence, result.confidence, transform=left.transform,
                             tags={**tags, "quantity": "sgm confidence (S2 - S1) / S2"},
                             band_names=["confidence"])
            outputs.append(confidence)
        provenance.write_sidecar(out_path, summary, outputs=outputs)
    return result


def _odd_or_none(ctx: click.Context, param: click.Parameter, value: int | None) -> int | None:
    if value is not None and (value < 1 or value % 2 == 0):
        raise click.BadParameter(f"must be an odd number ≥ 1, got {value}")
    return value


@click.command(name="sgm", help=STAGES["sgm"] + """

Reads the rectified pair LEFT_RECT and RIGHT_RECT (as written by demtool rectify; NaN
outside the warped images never matches) and writes OUT, the float32 disparity in the
left rectified image's frame (x_right = x_left - d, NaN = invalid), and OUT.json.  The
default cost is hierarchical mutual information (HMI, 1/16 → 1).""")
@options.input_file("left_rect")
@options.input_file("right_rect")
@options.out_file("Output disparity GeoTIFF.")
@click.option("--rectify", "rectify", type=click.Path(dir_okay=False), default=None,
              help="rectify.npz whose disparity_range sets the search range.")
@click.option("--min-disparity", type=int, default=None,
              help="Smallest disparity searched, px (overrides --rectify).")
@click.option("--num-disparities", type=click.IntRange(min=1), default=None,
              help="Number of disparities searched (overrides --rectify).")
@click.option("--cost", type=click.Choice(COST_CHOICES), default="hmi", show_default=True,
              help="hmi: hierarchical mutual information; mi: MI iterated at full "
                   "resolution from zero disparity; census; ad: absolute difference.")
@click.option("--census-window", type=click.Choice(["5x5", "9x7"]), default="5x5",
              show_default=True, help="Census window (width x height).")
@click.option("--cost-window", type=int, default=None, callback=_odd_or_none,
              help="Odd side of the window the pixel cost is summed over "
                   "[default per cost: 3 for MI, 5 for census and ad].")
@click.option("--paths", type=click.Choice(["8", "16"]), default="8", show_default=True,
              help="Aggregation paths.")
@click.option("--p1", type=click.IntRange(min=1), default=None,
              help="Penalty of a 1-px disparity step, cost units [default per cost].")
@click.option("--p2", type=click.IntRange(min=1), default=None,
              help="Penalty of a larger disparity step, cost units [default per cost].")
@click.option("--adaptive-p2/--no-adaptive-p2", default=True, show_default=True,
              help="Lower P2 across intensity edges (Hirschmüller 2008).")
@click.option("--mi-iterations", type=click.IntRange(min=1), default=3, show_default=True,
              help="MI iterations (mi: at full resolution; hmi: at the coarsest level).")
@click.option("--subpixel", type=click.Choice(["equiangular", "parabola", "none"]),
              default="equiangular", show_default=True, help="Sub-pixel fit of the cost.")
@click.option("--lr-check/--no-lr-check", default=True, show_default=True,
              help="Left-right consistency check (right disparity from the same cost).")
@click.option("--lr-threshold", type=click.FloatRange(min=0.0), default=1.0,
              show_default=True, help="Largest left-right difference kept, px.")
@click.option("--speckle-size", type=click.IntRange(min=0), default=100, show_default=True,
              help="Remove disparity regions smaller than this, px (0 = off).")
@click.option("--speckle-range", type=click.FloatRange(min=0.0), default=2.0,
              show_default=True, help="Largest disparity step within a region, px.")
@click.option("--median", type=int, default=3, show_default=True, callback=_odd_or_none,
              help="Side of the median filter of the disparity (1 = off).")
@click.option("--uniqueness", type=click.FloatRange(0.0, 1.0, max_open=True), default=0.0,
              show_default=True,
              help="Drop pixels whose confidence (S2-S1)/S2 is below this (0.1 = OpenCV's "
                   "uniquenessRatio 10).")
@click.option("--fill/--no-fill", default=True, show_default=True,
              help="Fill pixels left invalid from their neighbours (occlusions from the "
                   "background); they get confidence 0.")
@click.option("--confidence", "confidence", type=click.Path(dir_okay=False), default=None,
              help="Also write a confidence raster (0..1) here.")
@click.option("--max-memory-mb", type=click.FloatRange(min=64), default=1400.0,
              show_default=True,
              help="Budget of the aggregated-cost volumes (and row buffers) of the strips "
                   "matched at once, MiB; the image is cut into strips beyond it.")
@options.workers()
@options.seed()
@click.pass_context
def command(ctx: click.Context, left_rect: str, right_rect: str, out: str, paths: str,
            **kwargs) -> None:
    params = {**options.resolved_params(ctx), "paths": int(paths)}
    run_sgm(left_rect, right_rect, out, paths=int(paths), params=params, **kwargs)
