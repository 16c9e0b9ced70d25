"""Tie points of a block with sensor models: footprints, image pairs, SIFT tracks.

* :func:`footprint` / :func:`overlapping_pairs`: the ground footprint of each image
  (its border through ``image_to_ground`` onto the body's ellipsoid), projected
  gnomonically onto the plane tangent at the block's centre, and the pairs whose
  footprints intersect (convex polygons, Sutherland & Hodgman 1974 clipping).  This
  is ``--matcher spatial``.
* :func:`tie_points`: SIFT (Lowe 2004) in every image, ratio-test matches of each pair
  checked by a robust fundamental matrix, joined into multi-view tracks
  (union-find; a track that meets an image twice is dropped), as
  :class:`demtool.bundle.priors.Observations`; by default every track is then
  re-measured by affine least-squares matching against its reference observation
  (:mod:`demtool.bundle.tierefine`), which removes the perspective-dependent
  localisation bias of SIFT's blob centres (issue 14).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from demtool.bundle.priors import Observations
from demtool.logs import get_logger
from demtool.sensors.base import SensorModel, ray_ellipsoid_intersection

log = get_logger(__name__)

PAIRINGS = ("exhaustive", "sequential", "spatial")

#: default SIFT density of the sensor route: one keypoint per this many pixels of image
#: (an 8 px grid), between :data:`MIN_FEATURES` and :data:`MAX_FEATURES` per image
PIXELS_PER_FEATURE = 64
MIN_FEATURES = 8192
MAX_FEATURES = 65536


def features_per_image(shape: tuple[int, ...]) -> int:
    """Default number of SIFT keypoints for an image of ``shape`` (rows, cols, ...).

    With a reference DEM the block's datum (its scale above all: altitude and ground
    extent are one unknown with a known focal length) is measured by the DEM's slopes
    at the tie points, and the DEM's errors are independent between tie points farther
    apart than its posts, so the datum's precision grows with the number of tie points
    (as ASP's ``--ip-per-tile`` densifies them): one keypoint per
    :data:`PIXELS_PER_FEATURE` pixels, at least :data:`MIN_FEATURES` (small images) and
    at most :data:`MAX_FEATURES` (matching time and memory).  On the rendered 2048 px
    orbital blocks of issue 14 (docs/stages/bundle.md), 8192 → 65536 keypoints per image took
    the largest position error over four seeds from 5.3 m to 2.5 m.
    """
    pixels = int(shape[0]) * int(shape[1])
    return int(np.clip(pixels // PIXELS_PER_FEATURE, MIN_FEATURES, MAX_FEATURES))


def footprint(model: SensorModel, *, samples_per_edge: int = 8) -> np.ndarray:
    """Body-fixed points (K, 3), metres, of the image border on the body's ellipsoid.

    Border rays that miss the body (a limb in view) are dropped.
    """
    n = samples_per_edge
    lines, samples = float(model.lines), float(model.samples)
    t = np.linspace(0.0, 1.0, n, endpoint=False)
    line = np.concatenate([np.zeros(n), t * lines, np.full(n, lines), (1 - t) * lines])
    sample = np.concatenate([t * samples, np.full(n, samples), (1 - t) * samples, np.zeros(n)])
    ray = model.image_to_ray(line, sample)
    a, b = model.radii
    xyz, hit = ray_ellipsoid_intersection(ray.origin, ray.direction, a, b, return_hit=True)
    return xyz[hit]


def _tangent_plane(points: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Gnomonic projection of body-fixed points (K, 3) onto the plane tangent at
    ``centre`` (unit vector): (K, 2) coordinates in units of the body radius."""
    up = centre / np.linalg.norm(centre)
    east = np.cross([0.0, 0.0, 1.0], up)
    if np.linalg.norm(east) < 1e-9:
        east = np.array([1.0, 0.0, 0.0])
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    dots = points @ up
    return np.stack([points @ east / dots, points @ north / dots], axis=1)


def _convex_hull(points: np.ndarray) -> np.ndarray:
    """Counter-clockwise convex hull (Andrew's monotone chain) of (K, 2) points."""
    pts = sorted(map(tuple, np.unique(points, axis=0)))
    if len(pts) < 3:
        return np.asarray(pts)

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    upper: list = []
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.asarray(lower[:-1] + upper[:-1])


def _area(polygon: np.ndarray) -> float:
    if len(polygon) < 3:
        return 0.0
    x, y = polygon[:, 0], polygon[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def _clip(subject: np.ndarray, clipper: np.ndarray) -> np.ndarray:
    """Sutherland–Hodgman: ``subject`` clipped by the convex CCW polygon ``clipper``."""
    output = list(map(tuple, subject))
    for k in range(len(clipper)):
        a, b = clipper[k], clipper[(k + 1) % len(clipper)]
        inputs, output = output, []
        if not inputs:
            break

        def inside(p, a=a, b=b):
            return (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]) >= 0

        def meet(p, q, a=a, b=b):
            d1 = np.subtract(q, p)
            d2 = np.subtract(b, a)
            den = d1[0] * d2[1] - d1[1] * d2[0]
            s = ((a[0] - p[0]) * d2[1] - (a[1] - p[1]) * d2[0]) / den
            return (p[0] + s * d1[0], p[1] + s * d1[1])

        for j, q in enumerate(inputs):
            p = inputs[j - 1]
            if inside(q):
                if not inside(p):
                    output.append(meet(p, q))
                output.append(q)
            elif inside(p):
                output.append(meet(p, q))
    return np.asarray(output)


def overlapping_pairs(models: Sequence[SensorModel], *, min_overlap: float = 0.02
                      ) -> tuple[list[tuple[int, int]], np.ndarray]:
    """Image pairs whose ground footprints overlap.

    Parameters
    ----------
    models : sequence of SensorModel
        Models with ``radii`` (body-fixed metres).
    min_overlap : float
        Least intersection area, as a fraction of the smaller footprint.

    Returns
    -------
    pairs : list of (int, int)
        Index pairs ``i < j``.
    overlap : (N, N) float64
        Intersection area over the smaller footprint's area (0 … 1; 0 where a
        footprint is empty).
    """
    borders = [footprint(m) for m in models]
    centre = np.mean(np.concatenate([b for b in borders if len(b)] or [np.ones((1, 3))]),
                     axis=0)
    hulls = [_convex_hull(_tangent_plane(b, centre)) if len(b) >= 3 else np.zeros((0, 2))
             for b in borders]
    n = len(models)
    overlap = np.zeros((n, n))
    pairs = []
    for i in range(n):
        for j in range(i + 1, n):
            smaller = min(_area(hulls[i]), _area(hulls[j]))
            if smaller <= 0:
                continue
            overlap[i, j] = overlap[j, i] = _area(_clip(hulls[i], hulls[j])) / smaller
            if overlap[i, j] >= min_overlap:
                pairs.append((i, j))
    return pairs, overlap


def image_pairs(count: int, pairing: str, models: Sequence[SensorModel] | None = None
                ) -> list[tuple[int, int]]:
    """Pairs to match: all, neighbours in input order (sequential: the next 10, as
    COLMAP's default overlap), or overlapping footprints (spatial, needs ``models``)."""
    if pairing == "spatial":
        return overlapping_pairs(models)[0]
    if pairing == "sequential":
        return [(i, j) for i in range(count) for j in range(i + 1, min(count, i + 11))]
    return [(i, j) for i in range(count) for j in range(i + 1, count)]


def _find(parent: np.ndarray, i: int) -> int:
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


def tie_points(images: Sequence[np.ndarray], pairs: Sequence[tuple[int, int]], *,
               max_features: int | None = None, ratio: float = 0.8, threshold_px: float = 1.5,
               min_matches: int = 15, seed: int = 0, refine: bool = True,
               refine_template: int = 15) -> tuple[Observations, dict]:
    """Multi-view SIFT tracks of a block.

    Parameters
    ----------
    images : sequence of (H, W) arrays
        Grey images (any dtype; NaN = no data).
    pairs : sequence of (int, int)
        Image pairs to match.
    max_features : int, optional
        SIFT keypoints per image (strongest first); default
        :func:`features_per_image` of each image.
    ratio : float
        Lowe's ratio test.
    threshold_px : float
        Inlier threshold of the fundamental-matrix check (Sampson distance, px).
    min_matches : int
        Pairs with fewer inliers contribute nothing.
    seed : int
        Seed of the robust estimator.
    refine : bool
        Re-measure each track by affine LSM against its reference observation
        (:func:`demtool.bundle.tierefine.refine_observations`).
    refine_template : int
        LSM template size of that refinement, pixels (odd).

    Returns
    -------
    observations : Observations
        CSM image coordinates (pixel centre ``(r + 0.5, c + 0.5)``).
    report : dict
        ``pairs``: inlier matches per matched pair ``"i-j"``; ``refine``: the
        refinement's :class:`~demtool.bundle.tierefine.RefineReport` as a dict (with
        ``refine`` only).
    """
    from demtool.errors import ProcessingError
    from demtool.imaging.features import detect_sift, match_descriptors, ransac_fundamental

    features = [detect_sift(np.asarray(im), max_features=max_features or
                            features_per_image(np.shape(im))) for im in images]
    starts = np.cumsum([0] + [len(f) for f in features])
    parent = np.arange(starts[-1])
    report: dict[str, int] = {}
    for i, j in pairs:
        fi, fj = features[i], features[j]
        if len(fi) < 8 or len(fj) < 8:
            report[f"{i}-{j}"] = 0
            continue
        matches = match_descriptors(fi.descriptors, fj.descriptors, ratio=ratio)
        if len(matches) < max(8, min_matches):
            report[f"{i}-{j}"] = 0
            continue
        inliers = None
        for method in ("magsac", "ransac"):  # OpenCV's MAGSAC++ fails on some inputs
            try:
                _, inliers = ransac_fundamental(fi.points[matches[:, 0]],
                                                fj.points[matches[:, 1]],
                                                threshold_px=threshold_px, seed=seed,
                                                method=method)
                break
            except ProcessingError:
                continue
        if inliers is None:
            report[f"{i}-{j}"] = 0
            continue
        matches = matches[inliers]
        report[f"{i}-{j}"] = int(len(matches))
        if len(matches) < min_matches:
            continue
        for a, b in zip(starts[i] + matches[:, 0], starts[j] + matches[:, 1], strict=True):
            ra, rb = _find(parent, int(a)), _find(parent, int(b))
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
    roots = np.array([_find(parent, k) for k in range(len(parent))], dtype=np.int64)
    image_of = np.repeat(np.arange(len(images)), np.diff(starts))
    sizes = np.bincount(roots, minlength=len(roots))
    # a track meeting one image twice is ambiguous: drop it
    pair_keys = roots * len(images) + image_of
    _, first, dup_counts = np.unique(pair_keys, return_index=True, return_counts=True)
    doubled = np.zeros(len(roots), dtype=bool)
    doubled[roots[first[dup_counts > 1]]] = True
    keep = (sizes[roots] >= 2) & ~doubled[roots]
    _, point = np.unique(roots[keep], return_inverse=True)
    xy = np.concatenate([f.points for f in features])[keep].astype(np.float64)
    obs = Observations(image=image_of[keep], point=point.astype(np.int64),
                       line=xy[:, 1] + 0.5, sample=xy[:, 0] + 0.5)
    log.info("%d tie points, %d observations from %d pairs", obs.point_count, len(obs.image),
             sum(1 for v in report.values() if v >= min_matches))
    if refine and len(obs.image):
        from demtool.bundle.tierefine import refine_observations

        obs, refined = refine_observations(images, obs, template=refine_template)
        return obs, {"pairs": report, "refine": refined.as_dict()}
    return obs, {"pairs": report}


def pair_names(pairs: Sequence[tuple[int, int]], names: Sequence[str]) -> list[tuple[str, str]]:
    """Index pairs → view-name pairs (COLMAP's ``matcher="pairs"`` hook)."""
    return [(names[i], names[j]) for i, j in pairs]


def report_by_name(report: Mapping[str, int], names: Sequence[str]) -> dict[str, int]:
    """``"i-j"`` keys of :func:`tie_points`' report → ``"name_i name_j"``."""
    out = {}
    for key, value in report.items():
        i, j = (int(v) for v in key.split("-"))
        out[f"{names[i]} {names[j]}"] = value
    return out
