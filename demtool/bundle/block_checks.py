"""Checks of a ``bundle --sensors`` block before any matching (issue 31, class 5).

A block that cannot be right is refused in one line naming the file: models of more than
one body (a Mars model among Moon ones), a model that belongs to another image of the
block (models given in another order than the images), a camera implausibly far from
its body (positions in metres labelled km put it ~1000 radii out), and a reference DEM
whose heights no surface of the body can have (1e27 fill values, radii written as
heights).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from demtool.errors import InputError

#: radii differ between two models of one body by less than this (relative)
SAME_BODY_RTOL = 1e-3
#: a camera this many body radii from the body's centre is refused (the Earth–Moon
#: distance is 221 lunar radii; positions in metres labelled km give ~1000)
MAX_DISTANCE_RADII = 500.0


def check_one_body(models: Sequence[Any], paths: Sequence[Any]) -> None:
    """Refuse a block whose models carry the radii of different bodies."""
    first = next(((m, p) for m, p in zip(models, paths, strict=True) if m.radii is not None),
                 None)
    if first is None:
        return
    a0 = float(first[0].radii[0])
    for model, path in zip(models, paths, strict=True):
        if model.radii is None:
            continue
        a = float(model.radii[0])
        if abs(a - a0) > SAME_BODY_RTOL * a0:
            raise InputError(f"{path}: a model of a body of radius {a / 1e3:.6g} km, but "
                             f"{first[1]} is of one of {a0 / 1e3:.6g} km: a block holds the "
                             "images of one body")


def _model_names(model: Any, path: Any) -> set[str]:
    names = {Path(str(path)).stem}
    if getattr(model, "name", ""):
        names.add(str(model.name))
    return names


def check_models_match_images(models: Sequence[Any], paths: Sequence[Any],
                              image_names: Sequence[str], image_paths: Sequence[Any]) -> None:
    """Refuse a model whose name (its image identifier or file stem) is that of *another*
    image of the block: the models were given in another order than the images."""
    names = {str(n): i for i, n in enumerate(image_names)}
    names.update({Path(str(p)).stem: i for i, p in enumerate(image_paths)})
    for k, (model, path) in enumerate(zip(models, paths, strict=True)):
        own = _model_names(model, path)
        if own & {str(image_names[k]), Path(str(image_paths[k])).stem}:
            continue
        other = sorted({names[n] for n in own if n in names and names[n] != k})
        if other:
            j = other[0]
            raise InputError(f"{path}: is the model of image {image_names[j]} ({image_paths[j]})"
                             f", but it is given for image {image_names[k]} "
                             f"({image_paths[k]}); give the models in the images' order")


def check_camera_distances(models: Sequence[Any], paths: Sequence[Any]) -> None:
    """Refuse a camera more than :data:`MAX_DISTANCE_RADII` body radii from the centre."""
    for model, path in zip(models, paths, strict=True):
        if model.radii is None:
            continue
        try:
            centre = np.asarray(model.camera_center(np.array([0.5 * max(model.lines, 1)])),
                                dtype=np.float64).reshape(-1, 3)[0]
        except (AttributeError, ValueError):
            continue
        radius = float(model.radii[0])
        distance = float(np.linalg.norm(centre))
        if np.isfinite(distance) and distance > MAX_DISTANCE_RADII * radius:
            raise InputError(f"{path}: the camera is {distance / 1e3:.6g} km from the body's "
                             f"centre, {distance / radius:.0f} radii (radius "
                             f"{radius / 1e3:.6g} km): positions in metres labelled km?")


def check_physical_cameras(models: Sequence[Any], paths: Sequence[Any]) -> None:
    """InputError naming the first model that carries no camera position and attitude to
    adjust: an RPC is a fit of image coordinates to the ground, with neither (s2p and
    ASP correct a pair's RPCs by an image-space offset instead; demtool's map-projected
    route takes it out in ``sgm``)."""
    from demtool.errors import InputError

    for model, path in zip(models, paths, strict=True):
        if getattr(model, "kind", "") == "rpc":
            raise InputError(f"{path}: is an RPC model, which has no camera position or "
                             "attitude for bundle to adjust (the RPC route: mapproject --pair-"
                             "sensor, sgm, dem --mapprojected; docs/guides/rpc_pair.md)")


def check_block(models: Sequence[Any], paths: Sequence[Any], image_names: Sequence[str],
                image_paths: Sequence[Any]) -> None:
    """All the checks of a ``--sensors`` block (see the module docstring)."""
    check_physical_cameras(models, paths)
    check_one_body(models, paths)
    check_models_match_images(models, paths, image_names, image_paths)
    check_camera_distances(models, paths)
