"""Levenberg–Marquardt of the pose-prior bundle adjustment (:mod:`demtool.bundle.priors`).

Unknowns: a constant pose offset per image (``cams`` (N, 6): translation ``dC`` in
metres, rotation vector in milliradians, about the image's pivot) and the tie points
(P, 3) body-fixed metres.  The cost (Triggs et al. 2000, "Bundle adjustment — a modern
synthesis", sect. 3 and 4.4) is

    Σ_obs ρ(|x_obs − π_i(X_j)| / σ_px)  +  Σ_i cams_i² · prior_weights
    [ + Σ_j ρ((h(X_j) − h_DEM(X_j)) / σ_DEM) ]

(ρ the Huber loss; the bracket only with a reference DEM, :mod:`demtool.bundle.surface`),
minimised on the reduced camera system (Schur complement of the points, Triggs et al.
2000, sect. 6.1; :mod:`demtool.bundle.reduced_system`) with IRLS weights re-computed
each iteration.  The inverse of the reduced camera matrix at the solution (no damping)
is the covariance of the pose offsets (Triggs et al. 2000, sect. 10; Förstner & Wrobel
2016, sect. 4.2): how well the images, the priors and the DEM determine each image's
position and pointing, their errors taken as independent; :func:`jackknife_covariance`
estimates the same from how the solution moves without each spatial block of tie points.
"""

from __future__ import annotations

import numpy as np

from demtool.bundle.offsets import PoseOffset
from demtool.bundle.reduced_system import (
    NormalEquations,
    damped_step,
    reduced_camera_system,
)

#: forward-difference steps: metres (positions, points) and milliradians (pointing)
_STEP = 1e-3
#: added to the damped point blocks' diagonal (a point seen by no image stays invertible)
_POINT_RIDGE = 1e-12


def project(models, pivots, obs, cams, points) -> np.ndarray:
    """Reprojection residuals (M, 2), pixels, of ``points`` (P, 3) through the models moved
    by ``cams`` (N, 6: dC in metres, w in milliradians)."""
    out = np.empty((len(obs.image), 2))
    for i, model in enumerate(models):
        sel = obs.image == i
        if not np.any(sel):
            continue
        offset = PoseOffset(cams[i, :3], cams[i, 3:] * 1e-3, pivots[i])
        line, sample = model.ground_to_image(offset.to_original(points[obs.point[sel]]))
        out[sel, 0] = line - obs.line[sel]
        out[sel, 1] = sample - obs.sample[sel]
    return np.nan_to_num(out, nan=1e3, posinf=1e3, neginf=-1e3)


def _jacobians(models, pivots, obs, cams, points, base):
    """Forward-difference Jacobian blocks: (M, 2, 6) per camera offset, (M, 2, 3) per
    point (each observation depends on one image and one point, so one perturbation of
    every image (point) at once gives a whole column block)."""
    jc = np.empty((len(obs.image), 2, 6))
    jp = np.empty((len(obs.image), 2, 3))
    for k in range(6):
        moved = cams.copy()
        moved[:, k] += _STEP
        jc[:, :, k] = (project(models, pivots, obs, moved, points) - base) / _STEP
    for k in range(3):
        moved = points.copy()
        moved[:, k] += _STEP
        jp[:, :, k] = (project(models, pivots, obs, cams, moved) - base) / _STEP
    return jc, jp


def _cost(residuals, cams, prior_weights, huber, sigma):
    norms = np.linalg.norm(residuals, axis=1)
    rho = np.where(norms <= huber, norms ** 2, 2 * huber * norms - huber ** 2)
    return float(rho.sum() / sigma ** 2 + np.sum(cams ** 2 * prior_weights))


def _surface_cost(surface, points, threshold: float) -> float:
    if surface is None:
        return 0.0
    from demtool.bundle.surface import huber_cost

    return huber_cost(surface.normalised_residuals(points), threshold)


def _normal_equations(models, pivots, obs, cams, points, base, prior_weights, *, huber,
                      sigma, surface, surface_huber) -> NormalEquations:
    jc, jp = _jacobians(models, pivots, obs, cams, points, base)
    return _assemble(len(models), obs, cams, points, base, jc, jp, prior_weights,
                     huber=huber, sigma=sigma, surface=surface, surface_huber=surface_huber)


def _assemble(n, obs, cams, points, base, jc, jp, prior_weights, *, huber, sigma, surface,
              surface_huber) -> NormalEquations:
    """The normal equations from the Jacobian blocks of :func:`_jacobians`."""
    n_points = len(points)
    norms = np.linalg.norm(base, axis=1)
    w = np.where(norms <= huber, 1.0, huber / np.maximum(norms, 1e-12)) / sigma ** 2
    wjc = jc * w[:, None, None]
    u = np.zeros((n, 6, 6))
    np.add.at(u, obs.image, np.einsum("mki,mkj->mij", wjc, jc))
    u[:, np.arange(6), np.arange(6)] += prior_weights
    v = np.zeros((n_points, 3, 3))
    np.add.at(v, obs.point, np.einsum("mki,mkj->mij", jp * w[:, None, None], jp))
    wm = np.einsum("mki,mkj->mij", wjc, jp)  # (M, 6, 3)
    gc = np.zeros((n, 6))
    np.add.at(gc, obs.image, -np.einsum("mki,mk->mi", wjc, base))
    gc -= prior_weights * cams
    gp = np.zeros((n_points, 3))
    np.add.at(gp, obs.point, -np.einsum("mki,mk->mi", jp * w[:, None, None], base))
    if surface is not None:  # the reference DEM: one height residual per tie point
        from demtool.bundle.surface import surface_normal_equations

        v_dem, g_dem, _ = surface_normal_equations(surface, points, threshold=surface_huber)
        v += v_dem
        gp += g_dem
    # G_j (3, 6n): the W blocks of point j's observations, by image
    g = np.zeros((n_points, 3, n, 6))
    np.add.at(g, (obs.point, slice(None), obs.image), np.swapaxes(wm, 1, 2))
    return NormalEquations(u, v, g.reshape(n_points, 3, 6 * n), gc, gp)


def _reduced(normal: NormalEquations, lam: float):
    """:func:`~demtool.bundle.reduced_system.reduced_camera_system` with a 1e-12 ridge
    on the point blocks."""
    return reduced_camera_system(normal, lam, point_ridge=_POINT_RIDGE)


def solve(models, pivots, obs, cams, points, prior_weights, *, huber: float, sigma: float,
          iterations: int, surface=None, surface_huber: float = 2.0):
    """Minimise the cost of the module docstring from ``cams`` (N, 6) and ``points``
    (P, 3); image residuals weighted by ``1 / sigma²`` (pixels), Huber thresholds
    ``huber`` (pixels) and ``surface_huber`` (DEM sigmas).

    Returns
    -------
    cams : (N, 6) float64
    points : (P, 3) float64
    residuals : (M, 2) float64, pixels
    covariance : (6N, 6N) float64
        Of ``cams`` (metres, milliradians) at the solution; NaN where singular.
    cost : float
        The cost of the module docstring at the solution.
    """
    n = len(models)
    options = {"huber": huber, "sigma": sigma, "surface": surface,
               "surface_huber": surface_huber}
    base = project(models, pivots, obs, cams, points)
    cost = _cost(base, cams, prior_weights, huber, sigma) + _surface_cost(
        surface, points, surface_huber)

    def trial(dc, dp):  # the step from the current cams and points
        new_cams, new_points = cams + dc, points + dp
        new_base = project(models, pivots, obs, new_cams, new_points)
        new_cost = _cost(new_base, new_cams, prior_weights, huber, sigma) + \
            _surface_cost(surface, new_points, surface_huber)
        return new_cost, (new_cams, new_points, new_base)

    lam = 1e-3
    for _ in range(iterations):
        normal = _normal_equations(models, pivots, obs, cams, points, base, prior_weights,
                                   **options)
        step = damped_step(normal, lam, cost, trial, min_lambda=1e-9,
                           point_ridge=_POINT_RIDGE)
        if step is None:  # stalled
            break
        lam, new_cost, dc = step.lam, step.cost, step.cameras
        new_cams, new_points, new_base = step.trial
        converged = cost - new_cost <= 1e-10 * cost
        cams, points, base, cost = new_cams, new_points, new_base, new_cost
        if converged or np.max(np.abs(dc)) < 1e-6:
            break
    normal = _normal_equations(models, pivots, obs, cams, points, base, prior_weights,
                               **options)
    try:
        covariance = np.linalg.inv(_reduced(normal, 0.0)[0])
    except np.linalg.LinAlgError:
        covariance = np.full((6 * n, 6 * n), np.nan)
    return cams, points, base, covariance, cost


def jackknife_covariance(models, pivots, obs, cams, points, prior_weights, groups, *,
                         huber: float, sigma: float, surface=None,
                         surface_huber: float = 2.0) -> np.ndarray:
    """Delete-a-group jackknife covariance of the pose offsets at a solution.

    For each group of tie points, the Gauss–Newton step from the solution ``cams``,
    ``points`` without that group's observations (and DEM residuals) gives ``δ_k`` (6N,);
    the covariance is ``(G − 1) / G · Σ_k (δ_k − δ̄)(δ_k − δ̄)ᵀ`` (Efron & Stein 1981;
    with spatial groups, the block jackknife of Künsch 1989).  Unlike the inverse of the
    normal matrix it does not assume independent errors: where the reference DEM's
    errors are spatially correlated (a gridded product's interpolation error follows
    the terrain), groups of nearby tie points pull the block in different directions
    and the jackknife says so.

    Parameters
    ----------
    groups : (P,) int
        Group of each point, 0 … G − 1 (G ≥ 2; spatial blocks of the ground).
    (others as :func:`solve`, at its solution)

    Returns
    -------
    (6N, 6N) float64
        Metres and milliradians, as :func:`solve`'s covariance.
    """
    groups = np.asarray(groups)
    count = int(groups.max()) + 1
    base = project(models, pivots, obs, cams, points)
    jc, jp = _jacobians(models, pivots, obs, cams, points, base)
    options = {"huber": huber, "sigma": sigma, "surface": surface,
               "surface_huber": surface_huber}
    steps = []
    for k in range(count):
        keep_points = groups != k
        keep = keep_points[obs.point]
        renumber = np.cumsum(keep_points) - 1
        sub = type(obs)(image=obs.image[keep], point=renumber[obs.point[keep]],
                        line=obs.line[keep], sample=obs.sample[keep])
        normal = _assemble(len(models), sub, cams, points[keep_points], base[keep],
                           jc[keep], jp[keep], prior_weights, **options)
        s, rhs, _ = _reduced(normal, 0.0)
        steps.append(np.linalg.lstsq(s, rhs, rcond=None)[0])
    steps = np.array(steps)
    centred = steps - steps.mean(axis=0)
    return (count - 1) / count * centred.T @ centred
