"""What a block of images determines of its camera's intrinsics, and how it trades them
against the poses.

A self-calibrating bundle adjustment estimates intrinsics together with the poses and
the points; an intrinsic is only worth estimating where the images separate it from
the exterior orientation.  On a near-flat strip of nadir frames a change of the focal
length is matched by a change of the flying height (and of the relief: the model
stretches along the view), on a narrow field of view a shift of the principal point by
a turn of the camera (Fraser 1997; Gruen & Beyer 2001).  Two figures per parameter say
so, both from the normal equations at the solution with the points eliminated (Schur
complement, Triggs et al. 2000, sect. 6.1):

* its **marginal variance** ``σ²`` (poses and points free): the diagonal element of
  the inverse reduced matrix over intrinsics and poses (the gauge, a similarity of the
  block, fixed by holding one image's pose and one coordinate of a second image's
  centre: every intrinsic is gauge-invariant, so its variance does not depend on that
  choice);
* its **correlation with the poses** ``R``, the multiple correlation coefficient from
  the variance with the poses held at their values, ``σ²_poses fixed``:
  ``R² = 1 − σ²_poses fixed / σ²`` (the variance inflation factor 1 / (1 − R²) of
  regression diagnostics; Förstner & Wrobel 2016, sect. 4.6).  R near 1 means the
  poses absorb the parameter: what the adjustment reports for it is the poses'
  choice.

Jacobians are those of COLMAP's RADIAL model (``u = f·d(r)·x/z + cx``, ``d = 1 + k1 r²
+ k2 r⁴``) with the distortion's own derivative left out of the pose and point
columns (it is a small factor there); observation weights are one (scale the
variances by the a-posteriori variance factor σ0²).

References
----------
C. S. Fraser, "Digital camera self-calibration", ISPRS J. Photogramm. Remote Sens. 52(4),
149-159, 1997.
A. Gruen, H. A. Beyer, "System calibration through self-calibration", in Calibration and
Orientation of Cameras in Computer Vision, Springer, 2001, pp. 163-193.
B. Triggs et al., "Bundle adjustment — a modern synthesis", Vision Algorithms: Theory
and Practice, Springer, 2000.
W. Förstner, B. P. Wrobel, Photogrammetric Computer Vision, Springer, 2016.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: intrinsic parameter names, COLMAP RADIAL order
INTRINSIC_NAMES = ("f", "cx", "cy", "k1", "k2")
#: most images for which the dense reduced matrix (6 per image) is formed
MAX_IMAGES = 400
#: most tie points used (an even subsample of more; the information is scaled back up)
MAX_POINTS = 20000


@dataclass(frozen=True)
class Determinability:
    """Marginal standard deviations and pose correlations of free intrinsics.

    Attributes
    ----------
    names : tuple of str
        The free intrinsics, among :data:`INTRINSIC_NAMES` (one shared camera).
    sigma : (K,) float64
        Marginal standard deviation of each for unit observation weight (pixels for f,
        cx, cy; dimensionless for k1, k2); inf where the block does not determine it.
    sigma_poses_fixed : (K,) float64
        The same with every pose held at its value.
    pose_correlation : (K,) float64
        Multiple correlation R of each with the poses, 0 … 1 (1 where undetermined).
    """

    names: tuple[str, ...]
    sigma: np.ndarray
    sigma_poses_fixed: np.ndarray
    pose_correlation: np.ndarray

    def row(self, name: str, sigma0: float = 1.0) -> dict[str, float]:
        """``sigma``, ``sigma_poses_fixed`` (scaled by ``sigma0``) and
        ``pose_correlation`` of one parameter."""
        k = self.names.index(name)
        return {"sigma": float(self.sigma[k] * sigma0),
                "sigma_poses_fixed": float(self.sigma_poses_fixed[k] * sigma0),
                "pose_correlation": float(self.pose_correlation[k])}


def _skew(p: np.ndarray) -> np.ndarray:
    out = np.zeros(p.shape + (3,))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -p[..., 2], p[..., 1], -p[..., 0]
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = p[..., 2], -p[..., 1], p[..., 0]
    return out


def intrinsic_determinability(points_cam: np.ndarray, image: np.ndarray, point: np.ndarray,
                              rotations: np.ndarray, centres: np.ndarray, *,
                              focal_px: float, k1: float = 0.0, k2: float = 0.0,
                              free: Sequence[str] = ("f",),
                              calibrated: np.ndarray | None = None) -> Determinability:
    """Marginal σ and pose correlation of the free intrinsics of one shared camera.

    Parameters
    ----------
    points_cam : (M, 3) float64
        Each observation's tie point in its image's camera frame (``R X + t``).
    image, point : (M,) int
        Image index (0 … N−1) and tie-point index (0 … P−1) of each observation.
    rotations : (N, 3, 3) float64
        World-to-camera rotations.
    centres : (N, 3) float64
        Camera centres, world frame (for the gauge: the second fixed image is the one
        farthest from the first).
    focal_px, k1, k2 : float
        The camera's focal length (pixels) and radial terms at the solution.
    free : sequence of str
        The free intrinsics (a subset of :data:`INTRINSIC_NAMES`).
    calibrated : (N,) bool, optional
        Images whose camera is the one examined (default: all); the others' intrinsics
        are held fixed.

    Returns
    -------
    Determinability
    """
    free = tuple(n for n in INTRINSIC_NAMES if n in free)
    n_img = len(rotations)
    k_free = len(free)
    calibrated = np.ones(n_img, bool) if calibrated is None else np.asarray(calibrated, bool)
    points_cam = np.asarray(points_cam, dtype=np.float64)
    image, point = np.asarray(image), np.asarray(point)
    scale = 1.0
    n_points = int(point.max()) + 1 if len(point) else 0
    if n_points > MAX_POINTS:
        keep_points = np.zeros(n_points, bool)
        keep_points[np.random.default_rng(0).choice(n_points, MAX_POINTS, replace=False)] = True
        keep = keep_points[point]
        scale = len(point) / max(int(keep.sum()), 1)
        points_cam, image = points_cam[keep], image[keep]
        _, point = np.unique(point[keep], return_inverse=True)
    z = points_cam[:, 2]
    x, y = points_cam[:, 0] / z, points_cam[:, 1] / z
    r2 = x * x + y * y
    d = 1.0 + k1 * r2 + k2 * r2 * r2
    # ∂(u, v)/∂p_cam (M, 2, 3), the distortion factor d kept, its derivative left out
    a = np.zeros((len(z), 2, 3))
    a[:, 0, 0] = a[:, 1, 1] = focal_px * d / z
    a[:, 0, 2], a[:, 1, 2] = -focal_px * d * x / z, -focal_px * d * y / z
    rot = rotations[image]
    b = a @ rot  # ∂(u, v)/∂X (M, 2, 3)
    # camera-side columns of each observation: intrinsics, rotation (3), centre (3)
    ji = np.zeros((len(z), 2, k_free))
    columns = {"f": np.stack([d * x, d * y], 1), "cx": np.stack([np.ones_like(x), 0 * x], 1),
               "cy": np.stack([0 * x, np.ones_like(x)], 1),
               "k1": focal_px * np.stack([r2 * x, r2 * y], 1),
               "k2": focal_px * np.stack([r2 * r2 * x, r2 * r2 * y], 1)}
    for c, name in enumerate(free):
        ji[:, :, c] = columns[name] * calibrated[image][:, None]
    jr = -a @ _skew(points_cam)  # rotation perturbation R → exp([δθ]×) R
    jc = -b  # centre: p = R (X − C)
    local = np.concatenate([ji, jr, jc], axis=2)  # (M, 2, L)
    cols = np.concatenate([np.broadcast_to(np.arange(k_free), (len(z), k_free)),
                           k_free + 6 * image[:, None] + np.arange(6)], axis=1)  # (M, L)
    size = k_free + 6 * n_img
    s = np.zeros((size, size))
    jtj = np.einsum("mki,mkj->mij", local, local)
    np.add.at(s, (cols[:, :, None], cols[:, None, :]), jtj)
    # eliminate the points: S −= Σ_j W_j V_j⁻¹ W_jᵀ
    n_points = int(point.max()) + 1 if len(point) else 0
    v = np.zeros((n_points, 3, 3))
    np.add.at(v, point, np.einsum("mki,mkj->mij", b, b))
    v[:, np.arange(3), np.arange(3)] += 1e-12 * np.trace(v, axis1=1, axis2=2)[:, None] + 1e-30
    v_inv = np.linalg.inv(v)
    f_obs = np.einsum("mki,mkj->mij", local, b)  # (M, L, 3)
    e_obs = f_obs @ v_inv[point]
    order = np.argsort(point, kind="stable")
    counts = np.bincount(point, minlength=n_points)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    # every ordered pair of observations of one point
    owner = np.repeat(np.arange(n_points), counts ** 2)
    within = np.arange(len(owner)) - np.repeat(np.cumsum(counts ** 2) - counts ** 2,
                                               counts ** 2)
    first = order[starts[owner] + within // np.repeat(counts, counts ** 2)]
    second = order[starts[owner] + within % np.repeat(counts, counts ** 2)]
    for chunk in np.array_split(np.arange(len(first)), max(1, len(first) // 200000)):
        o1, o2 = first[chunk], second[chunk]
        blocks = np.einsum("pij,pkj->pik", e_obs[o1], f_obs[o2])
        np.add.at(s, (cols[o1][:, :, None], cols[o2][:, None, :]), -blocks)
    s *= scale
    s = 0.5 * (s + s.T)
    # the gauge: image 0's pose and the largest centre coordinate of the farthest image
    farthest = int(np.argmax(np.linalg.norm(centres - centres[0], axis=1)))
    axis = int(np.argmax(np.abs(centres[farthest] - centres[0])))
    fixed = set(range(k_free, k_free + 6)) | {k_free + 6 * farthest + 3 + axis}
    keep = np.array([c for c in range(size) if c not in fixed])
    reduced = s[np.ix_(keep, keep)]
    sigma = np.full(k_free, np.inf)
    sigma_fixed = np.full(k_free, np.inf)
    diag = np.sqrt(np.maximum(np.diag(reduced), 1e-300))
    scaled = reduced / diag[:, None] / diag[None, :]
    try:
        cov = np.linalg.inv(scaled)
        if np.all(np.isfinite(cov)) and np.linalg.cond(scaled) < 1e14:
            sigma = np.sqrt(np.maximum(np.diag(cov)[:k_free], 0.0)) / diag[:k_free]
    except np.linalg.LinAlgError:
        pass
    block = scaled[:k_free, :k_free]
    try:
        if np.linalg.cond(block) < 1e14:
            sigma_fixed = np.sqrt(np.maximum(np.diag(np.linalg.inv(block)), 0.0)) \
                / diag[:k_free]
    except np.linalg.LinAlgError:
        pass
    with np.errstate(invalid="ignore", divide="ignore"):
        r2_pose = np.where(np.isfinite(sigma), 1.0 - (sigma_fixed / sigma) ** 2, 1.0)
    correlation = np.sqrt(np.clip(np.nan_to_num(r2_pose, nan=1.0), 0.0, 1.0))
    return Determinability(free, sigma, sigma_fixed, correlation)


def reconstruction_determinability(reconstruction, camera_id: int, free: Sequence[str]
                                   ) -> Determinability | None:
    """:func:`intrinsic_determinability` of one camera of a ``pycolmap.Reconstruction``
    (its current solution); None with more than :data:`MAX_IMAGES` registered images
    or fewer than three."""
    image_ids = list(reconstruction.reg_image_ids())
    if not 3 <= len(image_ids) <= MAX_IMAGES:
        return None
    rotations, centres, calibrated = [], [], []
    image, point, xyz = [], [], []
    point_index: dict[int, int] = {}
    for i, image_id in enumerate(image_ids):
        im = reconstruction.image(image_id)
        pose = im.cam_from_world()
        r = np.asarray(pose.rotation.matrix(), dtype=np.float64)
        t = np.asarray(pose.translation, dtype=np.float64)
        rotations.append(r)
        centres.append(-r.T @ t)
        calibrated.append(im.camera_id == camera_id)
        for point2D in im.points2D:
            if point2D.has_point3D():
                pid = point2D.point3D_id
                image.append(i)
                point.append(point_index.setdefault(pid, len(point_index)))
                xyz.append(reconstruction.points3D[pid].xyz)
    if not image:
        return None
    rotations = np.array(rotations)
    image = np.array(image)
    xyz = np.array(xyz, dtype=np.float64)
    translations = -np.einsum("nij,nj->ni", rotations, np.array(centres))
    points_cam = np.einsum("mij,mj->mi", rotations[image], xyz) + translations[image]
    camera = reconstruction.camera(camera_id)
    params = np.asarray(camera.params, dtype=np.float64)
    focal = float(np.mean(params[camera.focal_length_idxs()]))
    k1 = float(params[3]) if camera.model_name in ("SIMPLE_RADIAL", "RADIAL") else 0.0
    k2 = float(params[4]) if camera.model_name == "RADIAL" else 0.0
    return intrinsic_determinability(points_cam, image, np.array(point), rotations,
                                     np.array(centres), focal_px=focal, k1=k1, k2=k2,
                                     free=free, calibrated=np.array(calibrated))
