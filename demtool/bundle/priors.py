"""Bundle adjustment of sensor models with pose priors (the mission's SPICE).

Each image keeps its sensor model (frame or line scan, :mod:`demtool.sensors`) and gets
a constant pose offset in the body-fixed frame, as ASP's ``bundle_adjust`` adjustment
files do (VisionWorkbench ``AdjustedCameraModel``): a translation ``dC`` (metres) and a
small rotation ``dR`` (rotation vector ``w``, radians) about a pivot ``P`` (the sensor
position at the image's centre line).  A body-fixed point ``X`` is seen by the adjusted
model where the original model sees

    X' = P + dRᵀ (X − P − dC),

so a frame camera's position becomes ``C + dC`` and its sensor-to-body rotation
``dR · R``; a line scanner's whole trajectory is moved and turned alike.

The adjustment minimises (Triggs et al. 2000, "Bundle adjustment — a modern synthesis",
sect. 3 and 4.4, priors as extra residuals)

    Σ_obs ρ(|x_obs − π_i(X_j)|² / 1 px²) + Σ_i |dC_i|² / σ_p² + Σ_i |w_i|² / σ_θ²

over the offsets of every image and the tie points ``X_j`` (Huber loss ρ on the
reprojection residuals, 1 px scale), starting from tie points triangulated with the
prior models, so no two-view initialisation is needed: any pair whose rays meet
registers.  ``σ_p`` is ``--position-sigma`` (m), ``σ_θ`` ``--pointing-sigma`` (mrad).
The block's common offset (a shift, turn or scale of all images together) is
determined by the priors alone, so it is only as good as their mean, unless a
reference DEM ties the tie points' heights to the ground (``surface``,
:mod:`demtool.bundle.surface`).  With one, the first adjustment also runs from the
prior block registered to the DEM (:func:`demtool.bundle.surface.register_points`) and
the solution of lower cost is kept; each of these first adjustments runs on the DEM
averaged over 2 × 2 posts before the DEM itself (:data:`SURFACE_LEVELS`), and the
reported pose uncertainty also comes from a spatial jackknife
(:func:`demtool.bundle.lm.jackknife_covariance`), since a gridded DEM's errors are
spatially correlated.  The solver is :mod:`demtool.bundle.lm`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from demtool.bundle.offsets import PoseOffset, pivot_of
from demtool.errors import ProcessingError
from demtool.logs import get_logger
from demtool.sensors.base import Ray, SensorModel

if TYPE_CHECKING:
    from demtool.bundle.surface import SurfaceShift

log = get_logger(__name__)

#: block-mean factors of the reference DEM on which the first adjustment runs in turn,
#: coarse to fine (the last, 1, is the DEM itself)
SURFACE_LEVELS = (2, 1)


def zero_offset(model: SensorModel) -> PoseOffset:
    """The offset that leaves ``model`` as it is."""
    return PoseOffset(np.zeros(3), np.zeros(3), pivot_of(model))


class AdjustedSensor(SensorModel):
    """A sensor model moved by a :class:`PoseOffset` (ASP's adjusted camera).

    Everything but the pose (image size, body, sun, timing) is the original model's.
    """

    def __init__(self, model: SensorModel, offset: PoseOffset):
        self.model = model
        self.offset = offset
        self.name = model.name
        self.kind = model.kind
        self.lines = model.lines
        self.samples = model.samples
        self.radii = model.radii

    def image_to_ray(self, line, sample) -> Ray:
        ray = self.model.image_to_ray(line, sample)
        return Ray(self.offset.from_original(ray.origin), ray.direction @ self.offset.matrix.T)

    def ground_to_image(self, xyz) -> tuple[np.ndarray, np.ndarray]:
        return self.model.ground_to_image(self.offset.to_original(xyz))

    def sun_position(self, line) -> np.ndarray:
        return self.model.sun_position(line)

    def camera_center(self, line) -> np.ndarray:
        return self.offset.from_original(self.model.camera_center(line))


@dataclass(frozen=True)
class Observations:
    """Tie-point observations of a block.

    Attributes
    ----------
    image : (M,) int
        Index of the observing image.
    point : (M,) int
        Index of the tie point (0 … P-1).
    line, sample : (M,) float64
        Measured image coordinates, CSM convention (first pixel centre at 0.5).
    """

    image: np.ndarray
    point: np.ndarray
    line: np.ndarray
    sample: np.ndarray

    @property
    def point_count(self) -> int:
        return int(self.point.max()) + 1 if len(self.point) else 0

    def subset(self, keep: np.ndarray) -> Observations:
        """The kept observations, tie points renumbered 0 … P'-1 (single views dropped)."""
        keep = np.asarray(keep, dtype=bool).copy()
        counts = np.bincount(self.point[keep], minlength=self.point_count)
        keep &= counts[self.point] >= 2
        _, point = np.unique(self.point[keep], return_inverse=True)
        return Observations(self.image[keep], point.astype(np.int64), self.line[keep],
                            self.sample[keep])


def triangulate(models: Sequence[SensorModel], obs: Observations) -> tuple[np.ndarray,
                                                                           np.ndarray]:
    """Least-squares intersection of each tie point's rays (nearest point to all rays).

    Returns
    -------
    points : (P, 3) float64
        Body-fixed metres.
    miss_m : (P,) float64
        RMS distance of the point to its rays, metres.
    """
    origins = np.empty((len(obs.image), 3))
    directions = np.empty((len(obs.image), 3))
    for i, model in enumerate(models):
        sel = obs.image == i
        if np.any(sel):
            ray = model.image_to_ray(obs.line[sel], obs.sample[sel])
            origins[sel], directions[sel] = ray.origin, ray.direction
    n_points = obs.point_count
    # Σ (I − d dᵀ) X = Σ (I − d dᵀ) o, solved relative to the first ray's origin (precision).
    reference = np.zeros((n_points, 3))
    reference[obs.point[::-1]] = origins[::-1]
    local = origins - reference[obs.point]
    projector = np.eye(3) - directions[:, :, None] * directions[:, None, :]
    a = np.zeros((n_points, 3, 3))
    b = np.zeros((n_points, 3))
    np.add.at(a, obs.point, projector)
    np.add.at(b, obs.point, np.einsum("nij,nj->ni", projector, local))
    singular = np.abs(np.linalg.det(a)) < 1e-12
    a[singular] = np.eye(3)
    points = np.linalg.solve(a, b[..., None])[..., 0]
    offsets = points[obs.point] - local
    distance = np.linalg.norm(offsets - np.sum(offsets * directions, axis=1)[:, None]
                              * directions, axis=1)
    miss = np.sqrt(np.bincount(obs.point, distance ** 2, n_points)
                   / np.maximum(np.bincount(obs.point, minlength=n_points), 1))
    miss[singular] = np.inf
    return points + reference, miss


def _finite(value) -> float | None:
    return float(value) if np.isfinite(value) else None


@dataclass(frozen=True)
class PriorAdjustment:
    """The outcome of :func:`adjust_with_priors`.

    Attributes
    ----------
    offsets : list of PoseOffset
        One per image, input order.
    points : (P, 3) float64
        Adjusted tie points, body-fixed metres.
    observations : Observations
        The observations kept (outliers removed).
    residuals : (M, 2) float64
        Reprojection residuals (line, sample) of the kept observations, pixels.
    initial_rms_px : float
        RMS reprojection residual with the prior models and triangulated points.
    pixel_sigma : float
        Sigma of the image observations in the final adjustment, pixels.
    surface_residuals : (P,) float64 or None
        With a reference DEM: the tie points' heights minus the DEM's, metres (NaN off
        the DEM).
    covariance : (6N, 6N) float64 or None
        Covariance of the pose offsets (per image: dC in metres, rotation in mrad) from
        the images, the priors and the DEM at the solution, their errors taken as
        independent (the inverse normal matrix).
    jackknife_covariance : (6N, 6N) float64 or None
        With a reference DEM: the same from a spatial delete-a-group jackknife
        (:func:`demtool.bundle.lm.jackknife_covariance`, 3 × 3 blocks of the ground),
        which sees the DEM's spatially correlated errors that ``covariance`` ignores.
    surface_shift : demtool.bundle.surface.SurfaceShift or None
        With a reference DEM: the translation that registered the prior block's tie
        points to it before the adjustment (its start).
    """

    offsets: list[PoseOffset]
    points: np.ndarray
    observations: Observations
    residuals: np.ndarray
    initial_rms_px: float
    pixel_sigma: float = 1.0
    surface_residuals: np.ndarray | None = None
    covariance: np.ndarray | None = None
    surface_shift: SurfaceShift | None = None
    jackknife_covariance: np.ndarray | None = None

    def sigmas(self, *, formal: bool = False) -> np.ndarray:
        """(N, 2): each image's position (m) and pointing (mrad) standard deviation, the
        root sum of squares over the three axes; per axis the larger of the formal
        (:attr:`covariance`) and the jackknife variance (where there is one; nine
        groups make the jackknife itself uncertain, so it only ever widens), or the
        formal one alone with ``formal``."""
        if self.covariance is None:
            return np.full((len(self.offsets), 2), np.nan)
        d = np.diag(self.covariance)
        if self.jackknife_covariance is not None and not formal:
            d = np.fmax(d, np.diag(self.jackknife_covariance))
        d = d.reshape(-1, 6)
        return np.sqrt(np.stack([d[:, :3].sum(axis=1), d[:, 3:].sum(axis=1)], axis=1))

    def image_report(self, names: Sequence[str]) -> dict[str, dict]:
        """Per image: observations, mean and RMS residual (px), position change (m) and
        pointing change (mrad) from the prior."""
        norms = np.linalg.norm(self.residuals, axis=1)
        sigmas, formal = self.sigmas(), self.sigmas(formal=True)
        report = {}
        for i, name in enumerate(names):
            sel = self.observations.image == i
            report[name] = {
                "observations": int(np.count_nonzero(sel)),
                "mean_residual_px": float(norms[sel].mean()) if np.any(sel) else None,
                "rms_residual_px": float(np.sqrt(np.mean(norms[sel] ** 2)))
                if np.any(sel) else None,
                "position_change_m": self.offsets[i].position_change_m,
                "position_change_xyz_m": [float(v) for v in self.offsets[i].translation],
                "pointing_change_mrad": self.offsets[i].pointing_change_mrad,
                "position_sigma_m": _finite(sigmas[i, 0]),
                "pointing_sigma_mrad": _finite(sigmas[i, 1]),
                "position_sigma_formal_m": _finite(formal[i, 0]),
                "pointing_sigma_formal_mrad": _finite(formal[i, 1]),
            }
        return report


def adjust_with_priors(models: Sequence[SensorModel], obs: Observations, *,
                       position_sigma: float, pointing_sigma: float,
                       outlier_px: float = 3.0, max_iterations: int = 30,
                       huber_px: float = 2.0, min_pixel_sigma: float = 0.05,
                       surface=None, register_to_dem: bool = True) -> PriorAdjustment:
    """Adjust constant pose offsets of sensor models and tie points, priors on the poses.

    Parameters
    ----------
    models : sequence of SensorModel
        The prior models (body-fixed metres), one per image.
    obs : Observations
        Tie-point observations (every point seen by ≥ 2 images).
    position_sigma : float
        Standard deviation of the prior positions, metres (per axis).
    pointing_sigma : float
        Standard deviation of the prior pointing, milliradians (per axis).
    outlier_px : float
        After a first adjustment, observations with a residual above
        ``max(outlier_px, 4 × median)`` pixels are dropped and the block re-adjusted.
    max_iterations : int
        Levenberg–Marquardt iterations per adjustment.
    huber_px : float
        Huber threshold of the reprojection residuals, in image sigmas.
    min_pixel_sigma : float
        The image observations are weighted with a sigma of 1 px in the first round,
        then with their robust RMS residual (never below this, pixels): tie points
        good to 0.05 px outweigh the pose priors accordingly.
    surface : demtool.bundle.surface.ReferenceSurface, optional
        A reference DEM: each tie point's height is tied to it with the surface's sigma
        (Huber loss, 2 sigmas), which fixes the block's datum (height, tilt, scale and,
        over relief, horizontal position) that tie points and priors leave open.
    register_to_dem : bool
        With ``surface``: the first adjustment runs twice, from the priors and from the
        prior block registered to the DEM (:func:`demtool.bundle.surface.
        register_points`, shifts within 3 σ of the priors' ground uncertainty), and the
        solution of lower cost goes on (a start beyond the reach of the DEM's slopes
        converges on a wrong fit with perfect residuals).

    Returns
    -------
    PriorAdjustment

    Raises
    ------
    ProcessingError
        No tie points, or an image with none (it cannot be adjusted).
    """
    from demtool.bundle import lm

    n_images = len(models)
    pivots = [pivot_of(m) for m in models]
    prior_weights = np.array([1 / position_sigma ** 2] * 3 + [1 / pointing_sigma ** 2] * 3)
    cams = np.zeros((n_images, 6))
    registered = None
    initial_rms = float("nan")
    pixel_sigma = 1.0
    for round_ in range(2):
        counts = np.bincount(obs.image, minlength=n_images)
        if not len(obs.image) or np.any(counts == 0):
            empty = [str(getattr(models[i], "name", i)) for i in np.flatnonzero(counts == 0)]
            raise ProcessingError(f"no tie points in image(s) {', '.join(empty) or 'all'}: "
                                  "the images may not overlap")
        # the second round starts from the first's poses and re-triangulated points
        current = [AdjustedSensor(m, PoseOffset(cams[i, :3], cams[i, 3:] * 1e-3, pivots[i]))
                   for i, m in enumerate(models)]
        points0, _ = triangulate(current, obs)
        if round_ == 0:
            start = lm.project(models, pivots, obs, cams, points0)
            initial_rms = float(np.sqrt(np.mean(np.sum(start ** 2, axis=1))))
        options = {"huber": huber_px * pixel_sigma, "sigma": pixel_sigma,
                   "iterations": max_iterations}
        # the first adjustment climbs down a block-mean pyramid of the DEM: bilinear
        # heights of a rough DEM make the fit's cost rugged at the scale of its posts,
        # with local minima a few metres apart; the coarse levels smooth them away
        levels = [surface.coarsened(f) for f in SURFACE_LEVELS] if round_ == 0 and \
            surface is not None else [surface]
        cams, points, residuals, covariance, cost = _solve_down(
            models, pivots, obs, cams, points0, prior_weights, levels, options)
        if round_ == 0 and surface is not None and register_to_dem:
            registered = _register(surface, points0, pivots, position_sigma, pointing_sigma)
            if registered is not None:
                # a second start, every sensor and point moved onto the DEM alike; the
                # lower cost of the two solutions wins (a start beyond the DEM fit's
                # reach converges on a wrong fit with perfect residuals)
                moved = np.zeros_like(cams)
                moved[:, :3] = registered.shift
                other = _solve_down(models, pivots, obs, moved, points0 + registered.shift,
                                    prior_weights, levels, options)
                log.info("adjustment from the priors: cost %.6g; from the registered "
                         "block: %.6g", cost, other[4])
                if other[4] < cost:
                    cams, points, residuals, covariance, cost = other
                else:
                    registered = replace(registered, used=False)
        norms = np.linalg.norm(residuals, axis=1)
        log.info("adjustment round %d: %d observations, %d tie points, RMS %.3f px "
                 "(image sigma %.3f px)", round_ + 1, len(obs.image), obs.point_count,
                 np.sqrt(np.mean(norms ** 2)), pixel_sigma)
        if round_ == 1:
            break
        keep = norms <= max(outlier_px, 4.0 * float(np.median(norms)))
        obs = obs.subset(keep)
        # a posteriori image sigma (variance component of the image observations, Förstner
        # 1979), robust: the normalised median absolute residual per coordinate
        robust = 1.4826 * float(np.median(np.abs(residuals[keep])))
        pixel_sigma = float(np.clip(robust, min_pixel_sigma, 1.0))
    offsets = [PoseOffset(cams[i, :3].copy(), cams[i, 3:] * 1e-3, pivots[i])
               for i in range(n_images)]
    jackknife = None
    if surface is not None:
        jackknife = lm.jackknife_covariance(models, pivots, obs, cams, points, prior_weights,
                                            spatial_groups(points), surface=surface,
                                            huber=huber_px * pixel_sigma, sigma=pixel_sigma)
    return PriorAdjustment(offsets=offsets, points=points, observations=obs,
                           residuals=residuals, initial_rms_px=initial_rms,
                           pixel_sigma=pixel_sigma, covariance=covariance,
                           jackknife_covariance=jackknife,
                           surface_residuals=None if surface is None else
                           surface.residuals(points), surface_shift=registered)


def spatial_groups(points, per_axis: int = 3) -> np.ndarray:
    """(P,) int: the block of each body-fixed point (P, 3) in a ``per_axis × per_axis``
    split of the ground at the quantiles of its east and north coordinates (about the
    points' mean), so every block holds about as many points."""
    from demtool.bundle.surface import local_axes

    points = np.asarray(points, dtype=np.float64)
    centre = points.mean(axis=0)
    east, north, _ = local_axes(centre)
    index = []
    for axis in (east, north):
        along = (points - centre) @ axis
        edges = np.quantile(along, np.linspace(0, 1, per_axis + 1)[1:-1])
        index.append(np.searchsorted(edges, along, side="right"))
    return index[0] * per_axis + index[1]


def _solve_down(models, pivots, obs, cams, points, prior_weights, surfaces, options):
    """:func:`demtool.bundle.lm.solve` on each of ``surfaces`` in turn (coarse to fine,
    ``None`` = no DEM), each from the last's solution; the last solution."""
    from demtool.bundle import lm

    for surface in surfaces:
        solution = lm.solve(models, pivots, obs, cams, points, prior_weights,
                            surface=surface, **options)
        cams, points = solution[0], solution[1]
    return solution


def _register(surface, points, pivots, position_sigma: float, pointing_sigma: float):
    """:func:`demtool.bundle.surface.register_points` of the prior block's tie points,
    searched within three times the priors' ground uncertainty (position and pointing
    at the sensors' median range), logged."""
    from demtool.bundle.surface import register_points

    ranges = [np.median(np.linalg.norm(points - p, axis=1)) for p in pivots]
    ground_sigma = np.hypot(position_sigma, float(np.median(ranges)) * pointing_sigma * 1e-3)
    found = register_points(surface, points, radius_m=3.0 * ground_sigma)
    if found is None:
        log.warning("reference DEM: fewer than half of the tie points lie on its data "
                    "within %.0f m of the priors; the adjustment starts from the priors",
                    3.0 * ground_sigma)
        return None
    log.info("reference DEM: the prior block registered by %+.1f m east, %+.1f m north, "
             "%+.1f m up (searched %.0f m around the priors; height residual spread "
             "%.2f -> %.2f m)", found.east_m, found.north_m, found.up_m, found.searched_m,
             found.spread_before_m, found.spread_m)
    return found
