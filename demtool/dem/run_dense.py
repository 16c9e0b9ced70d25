"""What ``dem --points bundle.npz --dense DISPARITY RECTIFY …`` reads and says: the block's
matched pairs checked against the bundle (:mod:`demtool.dem.dense` does the science)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

PathPair = tuple[str | os.PathLike, str | os.PathLike]


def read_dense_pairs(dense: Sequence[PathPair], cameras: dict, bundle_path, log) -> list:
    """The ``--dense`` pairs as :class:`demtool.dem.dense.DensePair`, each checked.

    A rectification must be uncalibrated (homographies of the original images), a
    disparity on its rectification's canvas and in its left rectified frame
    (:func:`demtool.dem.inputs.read_disparity`, :func:`demtool.dem.inputs.pair_names`), and
    both images of the pair must be registered in the bundle at the rectification's
    sizes (:func:`demtool.dem.inputs.check_pair_cameras`); InputError (one line naming
    the file) otherwise.
    """
    from demtool import io as dio
    from demtool.dem.dense import DensePair
    from demtool.dem.inputs import (
        check_pair_cameras,
        is_calibrated,
        pair_names,
        read_disparity,
    )
    from demtool.errors import InputError

    pairs = []
    for disparity_path, rectify_path in dense:
        rectification = dio.read_npz(rectify_path, "rectification")
        if is_calibrated(rectification):
            raise InputError(f"{rectify_path}: rectified with sensor models, whose images are "
                             "not homographies of the originals; triangulate that pair with "
                             "dem --disparity (--dense takes pairs of rectify without "
                             "--sensor-left/--sensor-right)")
        disparity = read_disparity(disparity_path, rectify_path, rectification,
                                   rectification["size_rect"], log)
        left, right, _, _ = pair_names(disparity_path, rectify_path, rectification,
                                       disparity.tags.get("frame", ""), None)
        check_pair_cameras(cameras, bundle_path, rectify_path, rectification, left, right)
        check_same_images(rectify_path, (left, right), bundle_path)
        pairs.append(DensePair(disparity.data, rectification["H_left"],
                               rectification["H_right"], left, right, str(disparity_path)))
    return pairs


def check_same_images(rectify_path, names: tuple[str, str], bundle_path) -> None:
    """Refuse a pair rectified from other images than the bundle's of the same names.

    Two blocks may name their views alike (``view_00`` …); a pair of the other block
    passes the names, sizes and even the ray-gap checks and densifies the DEM with another
    scene (issue 46: RMSE 2.78 m instead of 0.83 m).  The sidecars of ``rectify`` and
    ``bundle`` record each image's SHA-256 (:mod:`demtool.provenance`): the pair's two must
    be the bundle's images of those names.  Without the sidecars nothing is checked.

    Raises
    ------
    InputError
        One line naming the rectification, the image and both hashes' starts.
    """
    from pathlib import Path

    from demtool.errors import InputError
    from demtool.provenance import recorded_inputs

    in_block = {path.stem: digest for path, digest in recorded_inputs(bundle_path) if digest}
    for name, (path, digest) in zip(names, recorded_inputs(rectify_path)[:2], strict=False):
        if Path(path).stem != name:
            continue
        own = in_block.get(name)
        if digest and own and digest != own:
            raise InputError(f"{rectify_path}: its image {name} ({path}, SHA-256 "
                             f"{digest[:12]}…) is not the image {name} of the bundle "
                             f"{bundle_path} ({own[:12]}…): a pair of another block; rectify "
                             "this block's images")


def log_sources(log, report: dict[str, Any], cells: int) -> None:
    """One line: how many of the DEM's ``cells`` the tie points and the dense pairs measured,
    how many are interpolated, and how ties and dense samples agree."""
    ties, dense_only = report["cells_ties"], report["cells_dense_only"]
    interpolated = cells - report["cells_measured"]
    log.info("measured: %d cells by tie points (%.2f %%), %d more by the %d dense pair(s) "
             "(%.1f %%); interpolated %d (%.1f %%); outliers removed: %d ties, %d dense; "
             "tie − dense where both measured: median %s, NMAD %s", ties, 100 * ties / cells,
             dense_only, len(report["dense_pairs"]), 100 * dense_only / cells, interpolated,
             100 * interpolated / cells, report["tie_outliers"], report["dense_outliers"],
             _metres(report["tie_minus_dense_median_m"]),
             _metres(report["tie_minus_dense_nmad_m"]))


def _metres(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.3g} m"
