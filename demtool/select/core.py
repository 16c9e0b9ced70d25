"""Image selection for the BAM route: which images overlap a target (and how well).

The NavCam study's step: SIFT on the target (cropped to a region of interest) and on
every candidate, each candidate matched to the target descriptors with Lowe's ratio
test, and the images with at least 50 matches kept.  demtool adds what a user needs
to trust and to choose among hundreds of images:

* the number of matches that agree with one epipolar geometry (fundamental-matrix
  RANSAC inliers), which rejects repeated-texture false positives;
* the fraction of the ROI the candidate covers (its footprint, mapped into the
  target through the homography of the inliers) and the fraction the inliers span;
* when cameras and the sun are known: incidence, emission and phase angles at the
  ROI centre and the convergence angle with the target, and a ranking score
  (:func:`rank_score`).

Everything here is pure (arrays in, arrays out); ``demtool.select.run`` reads the
images, caches the features and writes ``selection.json``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from demtool.errors import ParameterError, ProcessingError
from demtool.imaging import features
from demtool.sensors.base import SensorModel

#: Stereo sweet spot of the convergence angle and its tolerance (degrees), for ranking:
#: B/H 0.3-0.6 (convergence ~17-33°) gives good height precision while keeping the
#: images similar enough to match (e.g. Kirk et al. 2008 for HiRISE, 15-25°+).
CONVERGENCE_OPTIMUM_DEG = 25.0
CONVERGENCE_TOLERANCE_DEG = 12.0

#: Weights of the ranking terms (see :func:`rank_score`).
SCORE_WEIGHTS = {"inliers": 0.35, "overlap": 0.25, "convergence": 0.25, "sun": 0.15}


@dataclass(frozen=True)
class Roi:
    """Region of interest in target pixels: columns x0 … x1-1, rows y0 … y1-1 (like slices)."""

    x0: int
    y0: int
    x1: int
    y1: int

    @property
    def area(self) -> float:
        return float((self.x1 - self.x0) * (self.y1 - self.y0))

    @property
    def centre(self) -> np.ndarray:
        """(x, y) of the ROI centre, in pixel-centre coordinates."""
        return np.array([(self.x0 + self.x1 - 1) / 2.0, (self.y0 + self.y1 - 1) / 2.0])

    def polygon(self) -> np.ndarray:
        """(4, 2) float32 corners (pixel edges), counter-clockwise in image orientation."""
        return np.array([[self.x0 - 0.5, self.y0 - 0.5], [self.x1 - 0.5, self.y0 - 0.5],
                         [self.x1 - 0.5, self.y1 - 0.5], [self.x0 - 0.5, self.y1 - 0.5]],
                        np.float32)

    def as_list(self) -> list[int]:
        return [self.x0, self.y0, self.x1, self.y1]


def check_roi(roi: Sequence[float] | None, shape: tuple[int, int], what: str = "target") -> Roi:
    """Validate a ROI ``(x0, y0, x1, y1)`` against an image of ``shape`` (rows, columns).

    None means the whole image.  Raises ParameterError, naming the image size, when the
    ROI is empty or reaches outside the image.
    """
    height, width = shape
    if roi is None:
        return Roi(0, 0, int(width), int(height))
    if len(roi) != 4:
        raise ParameterError(f"--roi needs 4 numbers x0 y0 x1 y1, got {len(roi)}")
    x0, y0, x1, y1 = (int(round(v)) for v in roi)
    if not (x0 < x1 and y0 < y1):
        raise ParameterError(f"--roi {x0} {y0} {x1} {y1} is empty: need x0 < x1 and y0 < y1")
    if x0 < 0 or y0 < 0 or x1 > width or y1 > height:
        raise ParameterError(f"--roi {x0} {y0} {x1} {y1} reaches outside the {what} image "
                             f"({width} x {height} px: 0 <= x0 < x1 <= {width}, "
                             f"0 <= y0 < y1 <= {height})")
    return Roi(x0, y0, x1, y1)


# --------------------------------------------------------------------------------------
# Matching a candidate against the target
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CandidateMatch:
    """How a candidate image relates to the target (:func:`compare_with_target`).

    Attributes
    ----------
    keypoints : int
        SIFT keypoints of the candidate.
    matches : int
        Target ROI descriptors matched by the ratio test.
    inliers : int
        Matches agreeing with one fundamental matrix (RANSAC); 0 when none was found.
    overlap : float
        Fraction (0 … 1) of the ROI inside the candidate's footprint (homography of
        the inliers); falls back to ``inlier_coverage`` when no homography fits.
    inlier_coverage : float
        Fraction of the ROI inside the convex hull of the inliers' target positions.
    accepted : bool
        Passed every threshold.
    reason : str
        Why it was rejected ("" when accepted).
    points_target, points_candidate : (K, 2) float64
        The inlier matches (x, y) in target and candidate pixels.
    """

    keypoints: int
    matches: int
    inliers: int
    overlap: float
    inlier_coverage: float
    accepted: bool
    reason: str = ""
    points_target: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    points_candidate: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


def _polygon_area_fraction(polygon: np.ndarray, roi: Roi) -> float:
    """Area of (convex polygon ∩ ROI) / ROI area."""
    import cv2

    if len(polygon) < 3 or not np.all(np.isfinite(polygon)):
        return 0.0
    hull = cv2.convexHull(np.asarray(polygon, np.float32)).reshape(-1, 2)
    if len(hull) < 3:
        return 0.0
    area, _ = cv2.intersectConvexConvex(hull, roi.polygon())
    return float(np.clip(area / roi.area, 0.0, 1.0))


def footprint_overlap(points_target: np.ndarray, points_candidate: np.ndarray,
                      candidate_size: tuple[int, int], roi: Roi) -> float | None:
    """Fraction of the ROI covered by the candidate's footprint, or None if undetermined.

    The homography of the inlier matches maps the candidate's frame (its four corners)
    into the target; the footprint is intersected with the ROI.  For distant,
    nearly planar scenes (orbital and comet images) this is a good approximation.

    Parameters
    ----------
    points_target, points_candidate : (K, 2) float
        Inlier matches (x, y), K >= 8.
    candidate_size : (width, height)
        Candidate image size in pixels.
    roi : Roi
    """
    import cv2

    if len(points_target) < 8:
        return None
    H, _ = cv2.findHomography(np.asarray(points_candidate, np.float64),
                              np.asarray(points_target, np.float64), cv2.RANSAC, 3.0)
    if H is None or not np.all(np.isfinite(H)):
        return None
    width, height = candidate_size
    corners = np.array([[-0.5, -0.5, 1.0], [width - 0.5, -0.5, 1.0],
                        [width - 0.5, height - 0.5, 1.0], [-0.5, height - 0.5, 1.0]])
    mapped = corners @ H.T
    if np.any(mapped[:, 2] * mapped[0, 2] <= 0):  # footprint crosses the horizon
        return None
    return _polygon_area_fraction(mapped[:, :2] / mapped[:, 2:3], roi)


def compare_with_target(target: features.Features, candidate: features.Features, *,
                        roi: Roi, candidate_size: tuple[int, int], ratio: float = 0.8,
                        min_matches: int = 50, min_inliers: int = 25,
                        min_overlap: float = 0.0, ransac_threshold: float = 1.0,
                        seed: int = 0) -> CandidateMatch:
    """Match a candidate's features to the target's and decide whether to keep it.

    Parameters
    ----------
    target : Features
        Target keypoints inside the ROI (positions in full target pixels).
    candidate : Features
        Candidate keypoints (positions in candidate pixels).
    roi : Roi
        The target region of interest.
    candidate_size : (width, height)
        Candidate image size, pixels.
    ratio : float
        Lowe's ratio test (Lowe 2004 sect. 7.1); the study keeps images with at least
        ``min_matches`` = 50 such matches.
    min_inliers : int
        Fewest matches that must agree with one fundamental matrix.
    min_overlap : float
        Smallest accepted ``overlap`` (0 disables the test).
    ransac_threshold : float
        Sampson-distance inlier threshold, pixels.
    seed : int
        RANSAC seed.

    Returns
    -------
    CandidateMatch
    """
    pairs = features.match_descriptors(target.descriptors, candidate.descriptors, ratio=ratio,
                                       mutual=False)
    matches = len(pairs)
    common = dict(keypoints=len(candidate), matches=matches)
    if matches < min_matches:
        return CandidateMatch(**common, inliers=0, overlap=0.0, inlier_coverage=0.0,
                              accepted=False,
                              reason=f"only {matches} matches (< {min_matches})")
    points_target = target.points[pairs[:, 0]].astype(np.float64)
    points_candidate = candidate.points[pairs[:, 1]].astype(np.float64)
    try:
        _, inlier_mask = features.ransac_fundamental(points_target, points_candidate,
                                                     threshold_px=ransac_threshold, seed=seed)
    except ProcessingError as exc:
        identical = "coincide" in str(exc)
        reason = ("identical to the target (zero parallax)" if identical else
                  f"{matches} matches but no epipolar geometry fits them "
                  "(false matches, e.g. repeated texture)")
        return CandidateMatch(**common, inliers=0, overlap=0.0, inlier_coverage=0.0,
                              accepted=False, reason=reason)
    inliers = int(inlier_mask.sum())
    points_target, points_candidate = points_target[inlier_mask], points_candidate[inlier_mask]
    coverage = _polygon_area_fraction(points_target, roi)
    overlap = footprint_overlap(points_target, points_candidate, candidate_size, roi)
    overlap = coverage if overlap is None else overlap
    reason = ""
    if inliers < min_inliers:
        reason = (f"only {inliers} of {matches} matches fit one epipolar geometry "
                  f"(< {min_inliers}): false matches, e.g. repeated texture")
    elif overlap < min_overlap:
        reason = f"covers {overlap:.0%} of the ROI (< {min_overlap:.0%})"
    return CandidateMatch(**common, inliers=inliers, overlap=overlap, inlier_coverage=coverage,
                          accepted=not reason, reason=reason, points_target=points_target,
                          points_candidate=points_candidate)


# --------------------------------------------------------------------------------------
# Viewing and illumination geometry
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ViewGeometry:
    """Angles at the surface point seen by the ROI centre (degrees; distances in metres).

    ``incidence``: sun from the surface normal; ``emission``: camera from the normal;
    ``phase``: between the sun and the camera; ``convergence``: between the rays to
    this camera and to the target's; ``sun_azimuth``: of the sun, clockwise from north
    (world +Y) toward east (+X).
    """

    incidence_deg: float | None
    emission_deg: float
    phase_deg: float | None
    convergence_deg: float
    baseline_m: float
    base_to_height: float
    sun_azimuth_deg: float | None

    def as_dict(self) -> dict[str, float | None]:
        return {k: (None if v is None else round(float(v), 3)) for k, v in self.__dict__.items()}


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    cosine = np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))


def surface_point(camera: SensorModel, pixel: np.ndarray, plane_z: float = 0.0) -> np.ndarray:
    """Ground point of ``pixel`` (x, y) on the mean surface, through the sensor interface.

    A local-frame camera (``radii`` None: the world frame has Z up with Z = 0 the mean
    surface, CONTRIBUTING.md) meets the plane Z = ``plane_z``; a body-fixed model its
    ellipsoid raised by ``plane_z`` (:meth:`SensorModel.image_to_ground`).  Raises
    ProcessingError when the ray does not reach the surface in front of the camera.
    """
    x, y = np.asarray(pixel, np.float64).reshape(2)
    point = np.asarray(camera.image_to_ground(y + 0.5, x + 0.5, plane_z), np.float64)
    if camera.radii is not None:
        ray = camera.image_to_ray(y + 0.5, x + 0.5)
        from demtool.sensors.base import ray_ellipsoid_intersection

        _, hit = ray_ellipsoid_intersection(ray.origin, ray.direction, *camera.radii, plane_z,
                                            return_hit=True)
        if not hit:
            point = np.full(3, np.nan)
    if not np.all(np.isfinite(point)):
        raise ProcessingError("the target's view ray at the ROI centre does not reach the "
                              "mean surface (Z = 0); camera frame is not a demtool world frame")
    return point


def _center_seeing(camera: SensorModel, point: np.ndarray) -> np.ndarray:
    """Camera centre at the exposure that sees ``point`` (a line scanner's moves)."""
    line, _ = camera.ground_to_image(point)
    line = float(line) if np.isfinite(line) else 0.5 * camera.lines
    return np.asarray(camera.camera_center(np.asarray(line)), np.float64).reshape(3)


def view_geometry(target_camera: SensorModel, camera: SensorModel, point: np.ndarray,
                  sun_vector: np.ndarray | None = None,
                  normal: Sequence[float] | None = None) -> ViewGeometry:
    """Viewing and illumination angles of ``camera`` at the ``point``.

    Parameters
    ----------
    target_camera, camera : SensorModel
        Both in the local world frame (X east, Y north, Z up, metres), or both
        body-fixed; camera centres come from :meth:`SensorModel.camera_center`.
    point : (3,) float
        Surface point (e.g. :func:`surface_point` of the ROI centre).
    sun_vector : (3,) float, optional
        Unit vector toward the sun (same frame) at this camera's acquisition.
    normal : (3,) float, optional
        Surface normal; default up: +Z in the local frame, the radius vector on a body.
        On a body the vectors are taken into the local east-north-up frame of the point
        first, so the sun azimuth is measured from north.
    """
    point = np.asarray(point, np.float64)
    camera_center = _center_seeing(camera, point)
    target_center = _center_seeing(target_camera, point)
    to_camera = camera_center - point
    to_target = target_center - point
    sun = None if sun_vector is None else np.asarray(sun_vector, np.float64)
    if camera.radii is not None:
        from demtool.maps import enu_frame, xyz_to_lonlat_height

        lon, lat, _ = xyz_to_lonlat_height(point, radii=float(camera.radii[0]))
        frame = enu_frame(lon, lat)
        to_camera, to_target = frame @ to_camera, frame @ to_target
        sun = None if sun is None else frame @ sun
        normal = normal if normal is None else frame @ np.asarray(normal, np.float64)
    normal = np.asarray((0.0, 0.0, 1.0) if normal is None else normal, np.float64)
    baseline = float(np.linalg.norm(camera_center - target_center))
    height = float(np.dot(to_target, normal) / np.linalg.norm(normal))
    incidence = phase = azimuth = None
    if sun is not None:
        incidence = _angle_deg(sun, normal)
        phase = _angle_deg(sun, to_camera)
        azimuth = float(np.degrees(np.arctan2(sun[0], sun[1])) % 360.0)
    return ViewGeometry(incidence_deg=incidence, emission_deg=_angle_deg(to_camera, normal),
                        phase_deg=phase, convergence_deg=_angle_deg(to_camera, to_target),
                        baseline_m=baseline,
                        base_to_height=baseline / height if height > 0 else float("nan"),
                        sun_azimuth_deg=azimuth)


# --------------------------------------------------------------------------------------
# Ranking
# --------------------------------------------------------------------------------------


def rank_score(match: CandidateMatch, geometry: ViewGeometry | None, *, min_matches: int,
               target_sun_azimuth_deg: float | None = None) -> tuple[float, dict[str, float]]:
    """Score (0 … 1) that favours what the BAM and SfS routes need from a view.

    A weighted mean (weights :data:`SCORE_WEIGHTS`) of terms in 0 … 1:

    * ``inliers``: ``min(1, inliers / (4 min_matches))`` — well-connected views;
    * ``overlap``: the fraction of the ROI covered;
    * ``convergence``: ``exp(-(γ - γ0)² / (2 σ²))`` with γ0 =
      :data:`CONVERGENCE_OPTIMUM_DEG`, σ = :data:`CONVERGENCE_TOLERANCE_DEG` — the
      stereo sweet spot (small angles give poor height precision, large ones poor
      matching);
    * ``sun``: ``(1 - cos Δφ) / 2`` of the sun-azimuth difference with the target —
      different illumination directions constrain shape from shading.

    Terms whose inputs are unknown (no cameras, no sun) are left out and the weights of
    the others renormalised.

    Returns
    -------
    score : float
    terms : dict of str to float
        The individual terms that entered the score.
    """
    terms: dict[str, float] = {
        "inliers": min(1.0, match.inliers / (4.0 * max(min_matches, 1))),
        "overlap": float(match.overlap),
    }
    if geometry is not None:
        offset = geometry.convergence_deg - CONVERGENCE_OPTIMUM_DEG
        terms["convergence"] = float(np.exp(-0.5 * (offset / CONVERGENCE_TOLERANCE_DEG) ** 2))
        if geometry.sun_azimuth_deg is not None and target_sun_azimuth_deg is not None:
            delta = np.radians(geometry.sun_azimuth_deg - target_sun_azimuth_deg)
            terms["sun"] = float((1.0 - np.cos(delta)) / 2.0)
    total_weight = sum(SCORE_WEIGHTS[k] for k in terms)
    score = sum(SCORE_WEIGHTS[k] * v for k, v in terms.items()) / total_weight
    return float(score), {k: round(v, 4) for k, v in terms.items()}


def path_relative_to(path: str | os.PathLike, folder: str | os.PathLike) -> str:
    """``path`` written relative to ``folder`` (the folder of the file that records it),
    so that the recording file can be read from any working folder; symbolic links are
    kept (no resolution), and a path on another drive stays absolute."""
    absolute = os.path.abspath(path)
    try:
        return os.path.relpath(absolute, os.path.abspath(folder))
    except ValueError:  # another drive (Windows)
        return absolute
