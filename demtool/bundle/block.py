"""Adjust a block of images: scratch copies for COLMAP, mapping, self-calibration.

:func:`adjust_block` is the core of ``demtool bundle`` (arrays in, a
:class:`BlockAdjustment` out).  COLMAP reads images from a folder and keeps an SQLite
database, so the function works in a temporary folder it removes afterwards.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from demtool.bundle import calibration
from demtool.bundle.colmap import (
    KnownIntrinsics,
    SfmOptions,
    impose_intrinsics,
    mapping_threads,
    run_sfm,
)
from demtool.bundle.model import (
    BundleResult,
    image_report,
    reconstruction_to_result,
    reprojection_summary,
)
from demtool.errors import ProcessingError
from demtool.logs import get_logger

log = get_logger(__name__)


@dataclass(frozen=True)
class BlockAdjustment:
    """The outcome of :func:`adjust_block`.

    Attributes
    ----------
    result : BundleResult
        The largest model in demtool's conventions.
    summary : dict
        Registered / not registered images, points, reprojection statistics, the
        intrinsics report (``intrinsics``: which parameters were refined, their values
        and standard deviations, or the known ones) and the per-image report
        (``images``: observations and residuals).
    model_files : dict of str to bytes
        The COLMAP model (binary files by name) when asked for, else empty.
    """

    result: BundleResult
    summary: dict[str, Any]
    model_files: dict[str, bytes]


#: percentiles of the linear stretch of the scratch 8-bit copies COLMAP reads
COLMAP_PERCENTILES = (0.1, 99.9)


def adjust_block(images: Iterable[tuple[str, np.ndarray]], options: SfmOptions, *,
                 target: str | None = None, self_calibration: bool = True,
                 keep_model: bool = False, focal_only: bool = False,
                 intrinsics: Callable[[dict[str, tuple[int, int]]],
                                      Mapping[str, KnownIntrinsics] | None] | None = None,
                 ) -> BlockAdjustment:
    """Structure from motion and bundle adjustment of a block of images.

    Parameters
    ----------
    images : iterable of (str, (H, W) array)
        View name and image (any dtype; NaN = no data), consumed one at a time.
    options : SfmOptions
        With ``intrinsics`` (known, fixed unless their ``refine``) or without (free:
        mapped with SIMPLE_RADIAL, then :func:`calibration.self_calibrate`).
    target : str, optional
        The target view (must register); default the first registered view.
    self_calibration : bool
        Refine the principal point and radial terms where the block determines them
        (free intrinsics only).
    keep_model : bool
        Return COLMAP's binary model files too.
    focal_only : bool
        The known intrinsics give only the focal length (principal point at the image
        centre by default): with ``self_calibration``, the principal point and radial
        terms are then tested with f held (:func:`calibration.self_calibrate`).
    intrinsics : callable, optional
        Known intrinsics from the image shapes ((height, width) by view name), once
        the images are read; replaces ``options.intrinsics`` unless it returns None.

    Raises
    ------
    ProcessingError
        Fewer than two images registered (no overlap, no texture).
    """
    import cv2

    from demtool.imaging.features import to_uint8

    with tempfile.TemporaryDirectory(prefix="demtool-bundle-") as scratch:
        work = Path(scratch)
        folder = work / "images"
        folder.mkdir()
        files: dict[str, str] = {}
        shapes: dict[str, tuple[int, int]] = {}
        for name, data in images:
            shapes[name] = np.shape(data)
            file_name = f"{name}.png"
            image8, _ = to_uint8(np.asarray(data), percentiles=COLMAP_PERCENTILES, exact=True)
            if not cv2.imwrite(str(folder / file_name), image8):
                raise ProcessingError(f"cannot write a scratch copy of image {name} for "
                                      f"COLMAP in {folder}")
            files[file_name] = name
        names = list(files.values())
        known = intrinsics(shapes) if intrinsics is not None else None
        if known is not None:
            options = replace(options, intrinsics=known)
        models, mapping = run_sfm(folder, files, work, options)
        if not models or models[0].num_reg_images() < 2:
            registered = ([files[models[0].image(i).name] for i in models[0].reg_image_ids()]
                          if models else [])
            raise ProcessingError(
                f"reconstruction failed: {len(registered)} of {len(names)} images "
                f"registered ({', '.join(registered) or 'none'}); the images may not "
                f"overlap or lack texture (try more --max-features)")
        model = models[0]
        known = options.intrinsics
        threads = mapping_threads(options)
        if known and mapping["free_fallback"]:
            impose_intrinsics(model, known, files, workers=threads)
        if known and self_calibration and focal_only and not any(
                k.refine for k in known.values()):
            # a focal length alone (--focal-px, --focal-mm): the principal point and the
            # lens distortion are still the block's to determine, f held
            intrinsics = {"mode": "known focal length",
                          **calibration.self_calibrate(model, workers=threads,
                                                       robust=mapping["features"] == "rich",
                                                       focal_known=True)}
        elif known:
            intrinsics = {"mode": "known, imposed after free mapping" if mapping["free_fallback"]
                          else "known", "refined": ["f"] if any(k.refine for k in
                                                                known.values()) else []}
        elif self_calibration:
            intrinsics = {"mode": "estimated",
                          **calibration.self_calibrate(
                              model, workers=threads,
                              focal_prior_px=mapping["focal_start_px"],
                              robust=mapping["features"] == "rich")}
        else:
            intrinsics = {"mode": "estimated", "refined": ["f", "k1"]}
        if not known:
            intrinsics["focal_prior"] = (
                {"source": "the first model's focal length (a pass with standard features)",
                 "value_px": mapping["focal_start_px"]} if mapping["focal_start_px"]
                else {"source": "1.2 x the larger image side (COLMAP's default)"})
        result = reconstruction_to_result(model, files, names, target)
        per_image = image_report(model, files)
        registered = [str(n) for n in result.image_names]
        camera = model.camera(model.image(model.reg_image_ids()[0]).camera_id)
        summary: dict[str, Any] = {
            "images_given": names,
            "registered": registered,
            "not_registered": [n for n in names if n not in registered],
            "unregistered_reasons": mapping.pop("unregistered_reasons"),
            "registered_count": len(registered),
            "image_count": len(names),
            "models": len(models),
            "mapping": mapping,
            "points": int(len(result.points)),
            "mean_track_length": float(np.mean(result.track_length))
            if len(result.points) else 0.0,
            **reprojection_summary(result),
            "focal_px": [float(c.focal_px) for c in result.cameras],
            "camera_model": camera.model_name,
            "target": str(result.image_names[result.target_index]),
            "intrinsics": intrinsics,
            "images": {n: row for n in names
                       if (row := per_image.get(n)) is not None},
        }
        model_files: dict[str, bytes] = {}
        if keep_model:
            out = work / "model_out"
            out.mkdir()
            model.write(out)
            model_files = {p.name: p.read_bytes() for p in sorted(out.iterdir())}
    return BlockAdjustment(result=result, summary=summary, model_files=model_files)


#: the widest field of view (degrees, across the image's diagonal) of a pinhole camera:
#: the widest rectilinear lenses made cover about 130° (a 10 mm lens on a 36 × 24 mm
#: frame); a focal length giving more than this is a unit slip (µm typed as mm) or a
#: fisheye, which the pinhole models here do not describe
MAX_PINHOLE_FOV_DEG = 150.0


def check_focal_px(focal_px: float, shape: tuple[int, int], source: str) -> None:
    """Refuse a focal length (pixels) no pinhole camera of this image size can have.

    Parameters
    ----------
    focal_px : float
    shape : (height, width)
        Pixels of one image of the block.
    source : str
        The options that gave it, named in the error (``--focal-mm 14 / --pixel-mm 7``).

    Raises
    ------
    ParameterError
        Not a positive finite number, or a diagonal field of view beyond
        :data:`MAX_PINHOLE_FOV_DEG`.
    """
    from demtool.errors import ParameterError

    height, width = shape
    if not (np.isfinite(focal_px) and focal_px > 0):
        raise ParameterError(f"{source}: the focal length would be {focal_px:g} px; it must "
                             "be a positive number")
    fov = float(np.degrees(2 * np.arctan(np.hypot(width, height) / 2 / focal_px)))
    if fov > MAX_PINHOLE_FOV_DEG:
        raise ParameterError(
            f"{source}: a focal length of {focal_px:.4g} px gives the {width}×{height} px "
            f"images a field of view of {fov:.1f}° (a pinhole camera: at most "
            f"{MAX_PINHOLE_FOV_DEG:g}°); check the units (--pixel-mm is millimetres: "
            "7 µm is 0.007)")


def known_intrinsics(shapes: Mapping[str, tuple[int, int]], *, focal_px: float | None = None,
                     matrices: Mapping[str, np.ndarray] | None = None,
                     refine: bool = False) -> dict[str, KnownIntrinsics]:
    """Known intrinsics per view from one focal length (principal point at the image
    centre) or from intrinsic matrices; ``shapes`` are (height, width) per view."""
    intrinsics = {}
    for name, (height, width) in shapes.items():
        if focal_px is not None:
            K = np.array([[focal_px, 0, (width - 1) / 2], [0, focal_px, (height - 1) / 2],
                          [0, 0, 1.0]])
        else:
            K = np.asarray(matrices[name], dtype=np.float64)
        intrinsics[name] = KnownIntrinsics(K, refine)
    return intrinsics

