"""Ground truth derived from a synthetic scene, for benchmarks of the later stages.

* :func:`truth_disparity` — the exact disparity of a rectified target/partner pair
  (``rectify``'s homographies), with an occlusion mask: what ``sgm`` and ``match``
  should find.
* :func:`rectified_correspondence` — the same, keeping the right rectified
  coordinates (x and y, so a rectification's vertical residual can be measured).
* :func:`target_points` — the world points seen by given target pixels.

All use exact ray casting of the scene's truth DEM (bilinear height field, the one the
images were rendered from), so they hold at any sub-pixel position, not only at
pixel centres.  The functions need only ``scene.dem``, ``scene.dem_transform`` and
``scene.cameras``.  The left view is ``scene.target`` and the right ``scene.partner``
unless ``left=`` / ``right=`` name other views: a pair rectified from other images (say
``view_00`` / ``view_03``) must name them, since the truth of another pair's
homographies through the partner's camera is meaningless (it gave 2.9 px RMS rows for
view_00 / view_03 of the small scene, whose true rows agree to 0.11 px).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from demtool.synth import render

VISIBILITY_TOLERANCE_M = 0.01  # a hit this much nearer than the point means occlusion


class TruthDisparity(NamedTuple):
    """Truth disparity on the left rectified grid.

    Attributes
    ----------
    disparity : (h, w) float32
        ``d = x_left − x_right`` in rectified pixels (CONTRIBUTING.md convention);
        NaN where the rectified pixel maps outside the target image or its surface
        point projects outside the partner image.
    visible : (h, w) bool
        True where ``disparity`` is finite and the point is not occluded in the
        partner (so a matcher can find it).
    """

    disparity: np.ndarray
    visible: np.ndarray


class Correspondence(NamedTuple):
    """Where the surface seen by each left rectified pixel falls in the right one.

    Attributes
    ----------
    x_right, y_right : (h, w) float64
        Right rectified coordinates, pixels; NaN as for ``TruthDisparity.disparity``.
    points : (h, w, 3) float64
        World coordinates of the surface points, metres; NaN outside the target image.
    visible : (h, w) bool
        Not occluded in the partner and inside the partner image.
    """

    x_right: np.ndarray
    y_right: np.ndarray
    points: np.ndarray
    visible: np.ndarray


def _apply_homography(H: np.ndarray, xy: np.ndarray) -> np.ndarray:
    homogeneous = np.column_stack([xy, np.ones(len(xy))]) @ np.asarray(H, dtype=np.float64).T
    with np.errstate(divide="ignore", invalid="ignore"):
        return homogeneous[:, :2] / homogeneous[:, 2:3]


def _camera(scene, name: str, option: str):
    """The local pinhole of view ``name``; ParameterError naming ``option`` for a view
    the scene does not have as a pinhole."""
    from demtool.errors import ParameterError

    if name not in scene.cameras:
        have = ", ".join(sorted(scene.cameras)) or "none (a sensor scene: no local pinholes)"
        raise ParameterError(f"{option}: the scene has no pinhole view {name!r} (views: "
                             f"{have})")
    return scene.cameras[name]


def _field(scene) -> render.HeightField:
    return render.height_field(np.asarray(scene.dem, dtype=np.float64), scene.dem_transform)


def target_points(scene, pixels: np.ndarray, *, view: str | None = None) -> np.ndarray:
    """World points seen by target pixels.

    Parameters
    ----------
    scene : Scene
        The synthetic scene.
    pixels : (N, 2) float
        Target-image coordinates (u, v) = (column, row), any sub-pixel position.
    view : str, optional
        The view the pixels belong to (default ``scene.target``).

    Returns
    -------
    (N, 3) float64
        World coordinates (X east, Y north, Z up), metres; NaN outside the image.
    """
    camera = _camera(scene, scene.target if view is None else view, "view")
    uv = np.atleast_2d(np.asarray(pixels, dtype=np.float64))
    inside = ((uv[:, 0] >= -0.5) & (uv[:, 0] <= camera.width - 0.5)
              & (uv[:, 1] >= -0.5) & (uv[:, 1] <= camera.height - 0.5))
    points = np.full((len(uv), 3), np.nan)
    if inside.any():
        points[inside] = render.pixel_hits(_field(scene), camera, uv[inside])
    return points


def rectified_correspondence(scene, H_left: np.ndarray, H_right: np.ndarray,
                             rect_shape: tuple[int, int], *, left: str | None = None,
                             right: str | None = None) -> Correspondence:
    """Map every left rectified pixel to its true match in the right rectified image.

    For each pixel (x, y) of the left rectified grid: ``H_left⁻¹`` takes it to the
    target image; its ray is cast onto the truth DEM; the hit is projected into the
    partner camera and through ``H_right`` to right rectified coordinates.  The point
    is visible when the partner's own ray through that projection hits the same point
    (not something nearer: occlusion), within ``VISIBILITY_TOLERANCE_M``.

    Parameters
    ----------
    scene : Scene
        The synthetic scene.
    H_left, H_right : (3, 3) float
        Homographies from original to rectified pixel coordinates (``rectify.npz``).
    rect_shape : (int, int)
        (height, width) of the left rectified grid.
    left, right : str, optional
        The views the homographies rectify (default ``scene.target`` and
        ``scene.partner``).

    Raises
    ------
    ParameterError
        ``left`` or ``right`` is not a pinhole view of the scene.

    Returns
    -------
    Correspondence
    """
    left = scene.target if left is None else left
    _camera(scene, left, "left")
    partner = _camera(scene, scene.partner if right is None else right, "right")
    height, width = (int(v) for v in rect_shape)
    rows, cols = np.mgrid[0:height, 0:width]
    left_rect = np.column_stack([cols.ravel(), rows.ravel()]).astype(np.float64)
    target_uv = _apply_homography(np.linalg.inv(H_left), left_rect)
    points = target_points(scene, np.nan_to_num(target_uv, nan=-1e9),
                           view=left)
    valid = np.isfinite(points[:, 0])
    partner_uv = np.full((len(points), 2), np.nan)
    partner_uv[valid] = partner.project(points[valid])
    inside = (valid & (partner_uv[:, 0] >= -0.5) & (partner_uv[:, 0] <= partner.width - 0.5)
              & (partner_uv[:, 1] >= -0.5) & (partner_uv[:, 1] <= partner.height - 0.5))
    visible = np.zeros(len(points), dtype=bool)
    if inside.any():
        seen = render.pixel_hits(_field(scene), partner, partner_uv[inside])
        nearer = partner.depth(points[inside]) - partner.depth(seen)
        visible[inside] = np.isfinite(nearer) & (nearer < VISIBILITY_TOLERANCE_M)
    right_rect = np.full((len(points), 2), np.nan)
    right_rect[inside] = _apply_homography(H_right, partner_uv[inside])
    shape2 = (height, width)
    return Correspondence(x_right=right_rect[:, 0].reshape(shape2),
                          y_right=right_rect[:, 1].reshape(shape2),
                          points=points.reshape(height, width, 3),
                          visible=visible.reshape(shape2))


def truth_disparity(scene, H_left: np.ndarray, H_right: np.ndarray,
                    rect_shape: tuple[int, int], *, left: str | None = None,
                    right: str | None = None) -> TruthDisparity:
    """Truth disparity ``d = x_left − x_right`` of the rectified target/partner pair.

    See :func:`rectified_correspondence` for the method.  Typical use in a benchmark::

        rect = io.read_npz("work/rectify.npz", "rectification")
        w, h = rect["size_rect"]
        truth = truth_disparity(scene, rect["H_left"], rect["H_right"], (h, w))
        error = disparity - truth.disparity  # compare on truth.visible only

    Parameters
    ----------
    scene : Scene
        The synthetic scene (``make_scene`` or ``demtool.synth.folder.load_scene``).
    H_left, H_right : (3, 3) float
        Homographies from original to rectified pixel coordinates.
    rect_shape : (int, int)
        (height, width) of the left rectified grid (the disparity map's shape).
    left, right : str, optional
        The views the homographies rectify (default ``scene.target`` and
        ``scene.partner``); name them for any other pair.

    Returns
    -------
    TruthDisparity
        ``disparity`` (h, w) float32 pixels (NaN invalid) and ``visible`` (h, w) bool.
    """
    match = rectified_correspondence(scene, H_left, H_right, rect_shape, left=left,
                                     right=right)
    x_left = np.arange(match.x_right.shape[1], dtype=np.float64)[None, :]
    disparity = (x_left - match.x_right).astype(np.float32)
    return TruthDisparity(disparity=disparity, visible=match.visible & np.isfinite(disparity))
