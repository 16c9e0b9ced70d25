"""Self-calibration of a block: which intrinsics the block determines, and how well.

Free intrinsics are mapped with COLMAP's SIMPLE_RADIAL model (focal length f and one
radial term k1, principal point fixed at the image centre), which is robust on any
field of view.  :func:`self_calibrate` then frees the principal point (cx, cy) and a
second radial term k2 (COLMAP's RADIAL model) in a global bundle adjustment and keeps
each only when the block determines it, by backward elimination of the additional
parameters as in photogrammetric self-calibration (Gruen & Beyer 2001; Fraser 1997):

* **determinability**: the parameter's standard deviation, from the covariance of
  the bundle adjustment (COLMAP's ``estimate_ba_covariance``, Schur complement over
  the points, so correlations with the poses are included), scaled by the
  a-posteriori variance factor σ0² = Σ r² / (2·n_obs − n_unknowns), moves the image
  corner by at most :data:`MAX_CORNER_SIGMA_PX` pixels (3 px: a principal point
  known to that beats the image centre, which real cameras miss by 10-20 px, e.g.
  the 17 px of issue 14's ring; COLMAP's σ of the principal point is conservative:
  2.3 px on the synthetic 12-view ring of the tests, whose actual error is about 0.1
  px). The corner displacement per unit of the parameter is 1 for cx and cy, f·ρ³
  for k1 and f·ρ⁵ for k2, with ρ the normalised radius of the farthest image corner
  (the tangent of the half diagonal field of view). A principal point shift differs
  from a rotation of the camera only by perspective terms of order ρ² (Fraser 1997,
  on the projective coupling of the principal point with the exterior orientation),
  so on a narrow field of view its σ is large and it stays at the image centre; for
  the same reason a k2 on a 1° field of view (ρ⁵ ≈ 5e-11) is never estimated;
* **significance** (distortion terms only): |k| ≥ :data:`SIGNIFICANCE` σ_k, else the
  term is fixed at zero (a t-test of the additional parameter, Gruen & Beyer 2001);
* **enough images**: the camera is seen by at least :data:`MIN_IMAGES` registered
  images (two views cannot separate intrinsics from relative pose).

The parameter that fails its test worst is fixed (principal point back to the image
centre, distortion term to zero) and the adjustment repeated, until every free
parameter passes.

References
----------
A. Gruen, H. A. Beyer, "System calibration through self-calibration", in A. Gruen,
T. S. Huang (eds.), Calibration and Orientation of Cameras in Computer Vision,
Springer, 2001, pp. 163-193.
C. S. Fraser, "Digital camera self-calibration", ISPRS Journal of Photogrammetry and
Remote Sensing 52(4), 149-159, 1997.
B. Triggs, P. F. McLauchlan, R. I. Hartley, A. W. Fitzgibbon, "Bundle adjustment — a
modern synthesis", in Vision Algorithms: Theory and Practice, LNCS 1883, Springer,
2000, pp. 298-372 (robust cost functions, sec. 3.3).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from demtool.bundle.runtime import (
    bundle_adjustment_options,
    call_interruptibly,
    load_pycolmap,
)
from demtool.logs import get_logger

log = get_logger(__name__)

#: Largest corner-displacement standard deviation (pixels) of a refined parameter.
MAX_CORNER_SIGMA_PX = 3.0
#: A principal point known to more than MAX_CORNER_SIGMA_PX is still kept when its offset
#: from the image centre is significant (≥ SIGNIFICANCE σ) and σ is at most this (pixels):
#: it then beats the image centre, which real cameras miss by 10-20 px.
MAX_PP_SIGMA_PX = 10.0
#: A distortion term is kept when |value| ≥ SIGNIFICANCE · σ.
SIGNIFICANCE = 3.0
#: Fewest registered images seeing a camera before its intrinsics are self-calibrated.
MIN_IMAGES = 3
#: Most bundle-adjustment solves per self-calibration step.
MAX_SOLVES = 10
#: A focal length is estimated only where its σ scales the relief by at most this.
MAX_FOCAL_RELATIVE_SIGMA = 0.01
#: Largest multiple correlation with the poses of an estimated focal length or radial term.
MAX_POSE_CORRELATION = 0.99
#: COLMAP's default focal length without EXIF data, in units of the larger image side.
DEFAULT_FOCAL_FACTOR = 1.2
#: Scale (pixels) of the Cauchy loss of the self-calibration's adjustments of blocks of
#: rich features (Triggs et al. 2000, robust bundle adjustment; COLMAP's
#: ``loss_function_type``).
ROBUST_LOSS_SCALE_PX = 1.0
#: RADIAL parameter order in COLMAP: f, cx, cy, k1, k2.
RADIAL_NAMES = ("f", "cx", "cy", "k1", "k2")


def corner_radius(width: int, height: int, focal_px: float) -> float:
    """Normalised radius ρ of the image corner farthest from the centre (tan of the
    half diagonal field of view)."""
    return float(np.hypot(0.5 * width, 0.5 * height) / focal_px)


def corner_sensitivity(focal_px: float, rho: float) -> dict[str, float]:
    """Corner displacement (pixels) per unit of each RADIAL parameter besides f.

    COLMAP's RADIAL model maps normalised radius r to f·r·(1 + k1 r² + k2 r⁴) from the
    principal point, so at the corner (r = ρ) ∂u/∂k1 = f ρ³, ∂u/∂k2 = f ρ⁵, and the
    principal point moves every pixel one for one.
    """
    return {"cx": 1.0, "cy": 1.0, "k1": focal_px * rho**3, "k2": focal_px * rho**5}


def observation_residuals(reconstruction) -> dict[int, np.ndarray]:
    """Reprojection residuals of every observation, by image id.

    Returns
    -------
    dict of int to (n, 2) float64
        Observed minus projected pixel position of each observation with a 3-D point.
    """
    residuals = {}
    points = reconstruction.points3D
    for image_id in reconstruction.reg_image_ids():
        image = reconstruction.image(image_id)
        camera = reconstruction.camera(image.camera_id)
        observed, xyz = [], []
        for point2D in image.points2D:
            if point2D.has_point3D():
                observed.append(point2D.xy)
                xyz.append(points[point2D.point3D_id].xyz)
        if not observed:
            residuals[image_id] = np.zeros((0, 2))
            continue
        pose = image.cam_from_world()
        cam = np.asarray(xyz) @ pose.rotation.matrix().T + pose.translation
        projected = np.asarray(camera.img_from_cam(cam), dtype=np.float64)
        residuals[image_id] = np.asarray(observed, dtype=np.float64) - projected
    return residuals


def variance_factor(reconstruction, n_intrinsics: int) -> float:
    """A-posteriori variance factor σ0² (pixels²) of a reconstruction's residuals."""
    residuals = np.vstack(list(observation_residuals(reconstruction).values()) or
                          [np.zeros((0, 2))])
    unknowns = 3 * reconstruction.num_points3D() + 6 * reconstruction.num_reg_images() \
        + n_intrinsics - 7
    redundancy = max(2 * len(residuals) - unknowns, 1)
    return float(np.sum(residuals**2) / redundancy)


#: COLMAP model for each set of free distortion terms.
_DISTORTION_MODELS = {("k1", "k2"): "RADIAL", ("k1",): "SIMPLE_RADIAL", (): "SIMPLE_PINHOLE"}


def _set_model(camera, distortion: tuple[str, ...], centre_pp: bool,
               focal_px: float | None = None) -> None:
    """Switch a camera to the COLMAP model with the given distortion terms, keeping f
    (or setting it to ``focal_px``), the principal point (or resetting it to the image
    centre) and the kept terms."""
    pycolmap = load_pycolmap()
    f = float(np.mean(camera.params[camera.focal_length_idxs()])) if focal_px is None \
        else float(focal_px)
    cx, cy = ((0.5 * camera.width, 0.5 * camera.height) if centre_pp
              else (camera.principal_point_x, camera.principal_point_y))
    terms = dict(zip(("k1", "k2"), _radial(camera), strict=True))
    camera.model = getattr(pycolmap.CameraModelId, _DISTORTION_MODELS[distortion])
    camera.params = [f, cx, cy, *(terms[k] for k in distortion)]


def _radial(camera) -> tuple[float, float]:
    params = np.asarray(camera.params, dtype=np.float64)
    if camera.model_name == "RADIAL":
        return float(params[3]), float(params[4])
    if camera.model_name == "SIMPLE_RADIAL":
        return float(params[3]), 0.0
    return 0.0, 0.0


def _adjust(reconstruction, cameras: list[int], free_pp: bool, workers: int,
            free_f: bool = True, robust: bool = False):
    """Global BA with the intrinsics of ``cameras`` free (f when ``free_f``, the
    distortion terms of their model, the principal point when ``free_pp``), the other
    cameras' constant.

    Returns
    -------
    dict of int to (n, n) float64, or None
        Unit-weight covariance of each free camera's refined parameters (COLMAP order,
        fixed ones omitted); None when COLMAP could not estimate it.
    """
    pycolmap = load_pycolmap()
    options = bundle_adjustment_options(focal_length=free_f, principal_point=free_pp,
                                        extra_params=True, workers=workers)
    if robust:
        # Cauchy loss at ROBUST_LOSS_SCALE_PX (rich, affine-shaped features): the
        # pixel-sized residuals of a few poorly localised features stop pulling the
        # weak directions, the principal point and with it the rotations
        # (templeSparseRing: median rotation error 0.63° → 0.30°).  Standard features
        # keep least squares: there it was not shown to matter (Apollo 15's four
        # frames: mean reprojection error 0.187 px with it, 0.190 px without).
        options.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
        options.ceres.loss_function_scale = ROBUST_LOSS_SCALE_PX
    # The principal point is a weak direction: COLMAP's default gradient tolerance
    # (1e-4) stops the solver pixels short of the minimum along it.
    options.ceres.solver_options.gradient_tolerance = 1e-10
    options.ceres.solver_options.max_num_iterations = 500
    config = pycolmap.BundleAdjustmentConfig()
    for image_id in reconstruction.reg_image_ids():
        config.add_image(image_id)
    config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
    for camera_id in reconstruction.cameras:
        if camera_id not in cameras:
            config.set_constant_cam_intrinsics(camera_id)
    # A solve stops short along the weak principal-point direction: solve again until
    # the intrinsics settle (change below 0.01 px, at most MAX_SOLVES times).
    for _ in range(MAX_SOLVES):
        before = np.concatenate([reconstruction.camera(c).params for c in cameras])
        adjuster = pycolmap.create_default_ceres_bundle_adjuster(options, config,
                                                                 reconstruction)
        call_interruptibly(adjuster.solve, cancellable=False)
        after = np.concatenate([reconstruction.camera(c).params for c in cameras])
        if np.max(np.abs(after - before), initial=0.0) < 0.01:
            break
    reconstruction.update_point_3d_errors()
    covariance = pycolmap.estimate_ba_covariance(pycolmap.BACovarianceOptions(),
                                                 reconstruction, adjuster)
    if covariance is None:
        return None
    result = {}
    for camera_id in cameras:
        block = covariance.get_other_params_cov(reconstruction.camera(camera_id).params)
        if block is None:
            return None
        result[camera_id] = np.asarray(block, dtype=np.float64)
    return result


def _free_names(distortion: tuple[str, ...], free_pp: bool, free_f: bool = True) -> list[str]:
    return [*(("f",) if free_f else ()), *(("cx", "cy") if free_pp else ()), *distortion]


def _worst_failure(reconstruction, covariances, distortion, free_pp, sigma0_sq,
                   free_f=True, determinability=None):
    """The free additional parameter (group) failing its test worst, with its reason
    (the focal length is not an additional parameter: see :func:`_focal_failure`)."""
    worst, worst_ratio, worst_reason = None, 1.0, ""
    for camera_id, cov in covariances.items():
        camera = reconstruction.camera(camera_id)
        f = float(np.mean(camera.params[camera.focal_length_idxs()]))
        rho = corner_radius(camera.width, camera.height, f)
        sensitivity = corner_sensitivity(f, rho)
        names = _free_names(distortion, free_pp, free_f)
        sigma = np.sqrt(np.maximum(np.diag(cov), 0.0) * sigma0_sq)
        values = dict(zip(("k1", "k2"), _radial(camera), strict=True))
        det = (determinability or {}).get(camera_id)
        for name, s in zip(names, sigma, strict=True):
            if name == "f":
                continue
            corner_sigma = s * sensitivity[name]
            ratio = corner_sigma / MAX_CORNER_SIGMA_PX
            reason = (f"σ moves the image corner by {corner_sigma:.3g} px "
                      f"(> {MAX_CORNER_SIGMA_PX} px)")
            if name in ("cx", "cy") and ratio > 1.0 and corner_sigma <= MAX_PP_SIGMA_PX:
                # the image centre is a guess too (real cameras miss it by 10-20 px): an
                # estimate significantly away from it, known better than that, is kept
                by_name = dict(zip(names, sigma, strict=True))
                t = max(abs(camera.principal_point_x - 0.5 * camera.width)
                        / max(by_name["cx"], 1e-300),
                        abs(camera.principal_point_y - 0.5 * camera.height)
                        / max(by_name["cy"], 1e-300))
                if t >= SIGNIFICANCE:
                    ratio = 0.0
                else:
                    reason += (f", and its offset from the image centre is not significant "
                               f"(|offset|/σ = {t:.2f} < {SIGNIFICANCE:g})")
            if name in values and ratio <= 1.0:
                t = abs(values[name]) / max(s, 1e-300)
                correlation = det.row(name)["pose_correlation"] if det is not None else 0.0
                if t < SIGNIFICANCE:
                    ratio = 1.0 + (SIGNIFICANCE - t)  # fails; rank after undetermined ones
                    reason = f"not significant (|{name}|/σ = {t:.2f} < {SIGNIFICANCE:g})"
                elif correlation > MAX_POSE_CORRELATION:
                    ratio = 1.0 + correlation
                    reason = (f"correlation with the poses {correlation:.4f} "
                              f"(> {MAX_POSE_CORRELATION:g}): the poses absorb it")
            group = "pp" if name in ("cx", "cy") else name
            if group == "k1" and "k2" in names:
                group = "k2"  # hierarchy: k2 goes before k1, which is then re-tested
                reason = f"k2 goes first as k1 fails: {reason}"
            if ratio > worst_ratio:
                worst, worst_ratio, worst_reason = group, ratio, reason
    return worst, worst_reason


def _focal_failure(reconstruction, covariances, names, sigma0_sq, determinability):
    """Why the block does not determine the focal length, or None where it does.

    The focal length's marginal σ (poses and points free) must move the image corner
    by at most :data:`MAX_CORNER_SIGMA_PX` (σ_f · ρ) and scale the relief by at most
    :data:`MAX_FOCAL_RELATIVE_SIGMA` (σ_f / f: the model's depths scale with f against
    its width), and its correlation with the poses must be at most
    :data:`MAX_POSE_CORRELATION` (a near-flat strip trades f for the flying height).
    """
    for camera_id, cov in covariances.items():
        camera = reconstruction.camera(camera_id)
        f = float(np.mean(camera.params[camera.focal_length_idxs()]))
        rho = corner_radius(camera.width, camera.height, f)
        sigma = float(np.sqrt(max(cov[names.index("f"), names.index("f")], 0.0) * sigma0_sq))
        det = determinability.get(camera_id)
        correlation = det.row("f")["pose_correlation"] if det is not None else float("nan")
        figures = (f"σ {sigma:.3g} px = {100 * sigma / f:.2g} % of f, {sigma * rho:.3g} px "
                   f"at the image corner, correlation with the poses {correlation:.4f}")
        if (sigma * rho > MAX_CORNER_SIGMA_PX or sigma / f > MAX_FOCAL_RELATIVE_SIGMA
                or not correlation <= MAX_POSE_CORRELATION):
            return figures, {"sigma": sigma, "corner_sigma_px": sigma * rho,
                             "relative_sigma": sigma / f, "pose_correlation": correlation}
    return None


def prior_focal_px(width: int, height: int) -> float:
    """The focal length assumed without knowledge: COLMAP's default for an image without
    EXIF data, ``1.2 × max(width, height)`` pixels (``default_focal_length_factor``)."""
    return DEFAULT_FOCAL_FACTOR * max(width, height)


def _determinability(reconstruction, cameras, names):
    from demtool.bundle.determinability import reconstruction_determinability

    out = {}
    for camera_id in cameras:
        det = reconstruction_determinability(reconstruction, camera_id, names)
        if det is not None:
            out[camera_id] = det
    return out


def self_calibrate(reconstruction, *, workers: int = 0,
                   focal_prior_px: float | None = None,
                   focal_known: bool = False, robust: bool = False) -> dict[str, Any]:
    """Refine the focal length, principal point and radial terms where the block
    determines them.

    Changes ``reconstruction`` in place (cameras end as SIMPLE_PINHOLE,
    SIMPLE_RADIAL or RADIAL with the kept terms); see the module docstring for the
    criterion.  Backward elimination: the additional parameters (k2, k1, the principal
    point) are fixed one at a time while one fails its test; then the focal length is
    tested (:func:`_focal_failure`) and, where the block does not determine it, set
    to ``focal_prior_px`` (default :func:`prior_focal_px`) and held there, with one
    warning saying what the user can give instead.  With ``focal_known`` the focal
    length is the user's (``focal_prior_px``, or the camera's) and stays fixed; the
    principal point and radial terms are still tested.  ``robust``: adjust with a
    Cauchy loss of :data:`ROBUST_LOSS_SCALE_PX` (blocks of rich, affine-shaped
    features, whose localisation has a long tail).

    Returns
    -------
    dict
        ``refined`` (names among f, cx, cy, k1, k2), ``fixed`` (name → reason),
        ``values`` and ``sigma`` (f, cx, cy in pixels, demtool's convention with pixel
        centres at integers; k1, k2 dimensionless) of the first self-calibrated
        camera, ``decisions`` (name → ``estimated`` or ``prior``, with σ, its effect at
        the image corner and the correlation with the poses where computed),
        ``corner_radius`` ρ, ``cameras`` (how many were self-calibrated),
        ``sigma0_px`` (a-posteriori σ of an image coordinate).  With no camera seen
        by :data:`MIN_IMAGES` images, ``refined`` lists what COLMAP's mapping refined
        (f, k1), with a reason and a warning that the focal length is not tested.
    """
    counts: dict[int, int] = {}
    for image_id in reconstruction.reg_image_ids():
        camera_id = reconstruction.image(image_id).camera_id
        counts[camera_id] = counts.get(camera_id, 0) + 1
    cameras = [c for c, n in counts.items() if n >= MIN_IMAGES]
    if not cameras:
        reason = f"no camera is seen by {MIN_IMAGES} or more registered images"
        log.warning("self-calibration: %s; the focal length is COLMAP's two-view estimate, "
                    "not tested (give --focal-mm and --pixel-mm, --focal-px, --cameras or "
                    "sensor models for a known scale of the relief)", reason)
        return {"refined": ["f", "k1"], "reason": reason,
                "decisions": {"f": {"status": "estimated, not tested", "reason": reason}}}
    distortion: tuple[str, ...] = ("k1", "k2")
    free_pp, free_f = True, not focal_known
    if focal_known and focal_prior_px is None:
        camera = reconstruction.camera(cameras[0])
        focal_prior_px = float(np.mean(camera.params[camera.focal_length_idxs()]))
    fixed: dict[str, str] = {}
    focal_report: dict[str, Any] = {}
    determinability: dict = {}
    while True:
        for camera_id in cameras:
            camera = reconstruction.camera(camera_id)
            prior = None if free_f else (focal_prior_px or prior_focal_px(camera.width,
                                                                         camera.height))
            _set_model(camera, distortion, centre_pp=not free_pp, focal_px=prior)
        names = _free_names(distortion, free_pp, free_f)
        covariances = _adjust(reconstruction, cameras, free_pp, workers, free_f=free_f,
                              robust=robust)
        n_intrinsics = len(cameras) * len(names)
        sigma0_sq = variance_factor(reconstruction, n_intrinsics)
        determinability = _determinability(reconstruction, cameras, names) if names else {}
        if covariances is None and names and len(determinability) == len(cameras):
            # COLMAP's covariance is singular (an undetermined direction): the variances
            # of this module's own reduced normal equations say which parameter it is
            covariances = {c: np.diag(d.sigma ** 2) / sigma0_sq
                           for c, d in determinability.items()}
        if covariances is None:
            worst, reason = ("pp" if free_pp else distortion[-1] if distortion else
                             "f" if free_f else None, "covariance not estimable (singular)")
        else:
            worst, reason = _worst_failure(reconstruction, covariances, distortion, free_pp,
                                           sigma0_sq, free_f, determinability)
            if worst is None and free_f:
                failure = _focal_failure(reconstruction, covariances, names, sigma0_sq,
                                         determinability)
                if failure is not None:
                    worst, reason = "f", failure[0]
                    focal_report = failure[1]
        if worst is None or (covariances is None and not free_pp and not distortion
                             and not free_f):
            break
        if worst == "f":
            camera = reconstruction.camera(cameras[0])
            prior = focal_prior_px or prior_focal_px(camera.width, camera.height)
            log.warning("self-calibration: the block does not determine the focal length "
                        "(%s); kept at the prior %.1f px%s, so the relief's scale is not "
                        "measured: give --focal-mm and --pixel-mm, --focal-px, --cameras "
                        "(intrinsics) or sensor models (--sensors)", reason, prior,
                        "" if focal_prior_px else " (1.2 × the image size, COLMAP's default)")
            fixed["f"] = reason
            free_f = False
            continue
        log.info("self-calibration: %s fixed (%s)", worst, reason)
        if worst == "pp":
            free_pp = False
            fixed["cx"] = fixed["cy"] = reason
        else:
            fixed[worst] = reason
            distortion = distortion[: distortion.index(worst)]
    camera = reconstruction.camera(cameras[0])
    names = _free_names(distortion, free_pp, free_f)
    sigma = (np.full(len(names), np.nan) if covariances is None else
             np.sqrt(np.maximum(np.diag(covariances[cameras[0]]), 0.0) * sigma0_sq))
    k1, k2 = _radial(camera)
    f = float(np.mean(camera.params[camera.focal_length_idxs()]))
    values = {"f": f, "cx": camera.principal_point_x - 0.5,
              "cy": camera.principal_point_y - 0.5, "k1": k1, "k2": k2}
    rho = corner_radius(camera.width, camera.height, f)
    sensitivity = {"f": rho, **corner_sensitivity(f, rho)}
    det = determinability.get(cameras[0])
    decisions: dict[str, dict[str, Any]] = {}
    for name in RADIAL_NAMES:
        if name in names:
            s = float(sigma[names.index(name)])
            row = {"status": "estimated", "value": values[name], "sigma": s,
                   "corner_sigma_px": s * sensitivity[name]}
            if det is not None:
                row["pose_correlation"] = det.row(name)["pose_correlation"]
        elif name == "f" and focal_known:
            row = {"status": "given", "value": values[name]}
        else:
            row = {"status": "prior", "value": values[name], "reason": fixed.get(name, "")}
            if name == "f":
                row.update(focal_report)
        decisions[name] = row
    return {"refined": names, "fixed": fixed, "values": values,
            "sigma": {n: float(s) for n, s in zip(names, sigma, strict=True)},
            "decisions": decisions,
            "corner_radius": rho, "cameras": len(cameras),
            "sigma0_px": float(np.sqrt(sigma0_sq))}
