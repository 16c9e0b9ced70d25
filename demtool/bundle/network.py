"""Bundle adjustment of sensor models on a control network (ISIS ``jigsaw``, knoten).

Each image keeps its sensor model (frame or line scan, :mod:`demtool.sensors`) and gets
a correction of its pointing, polynomial in time, and optionally a constant position
bias, the parameters knoten solves through usgscsm's adjustable parameters and jigsaw
through its CK polynomial (``CKDEGREE``, ``CAMSOLVE=ANGLES``/``VELOCITIES``/
``ACCELERATIONS``, ``SPSOLVE=POSITION``):

====================  ===========================================  =================
parameter             meaning                                      unit
====================  ===========================================  =================
omega, phi, kappa     rotation about the image's sample axis, line  rad
                      axis and boresight (twist), at the centre
omega/phi/kappa rate  their first derivative in time               rad/s
omega/phi/kappa accl  their second derivative in time              rad/s²
along, cross, radial  position bias along track (image lines on     m
  position bias       the ground), across track, up
====================  ===========================================  =================

Time ``t`` is seconds from the image's centre exposure (0 for a frame camera, whose
rates and accelerations are therefore not solved).  The axes are the image's own at
its centre line (:func:`image_axes`): ``F`` (3, 3), columns sample axis, line axis,
boresight, in the body frame; ``B`` (3, 3) columns along track, across track, up.  The
rotation at ``t`` is the body-frame rotation vector ``w(t) = F (a + b t + c t²)`` and
the adjusted model sees a body-fixed point ``X`` where the prior model sees

    X' = C(t) + R(w(t))ᵀ (X − C(t) − B p),

``C(t)`` the prior sensor position at ``t``: the sensor moves by ``B p`` and its rays
turn by ``R(w(t))`` about it, as usgscsm's attitude correction turns the look vector in
the sensor frame (``calculateAttitudeCorrection``, with time in seconds here rather
than usgscsm's normalised time and the angles in radians rather than metres at the
flying height).  A line scanner's exposure line depends on the correction, so the
projection iterates: ``l₀`` → ``X'(t(l₀))`` → ``l₁`` … (three steps move less than
1e-4 px: the correction changes by microradians over the few lines it moves).

The adjustment minimises (Triggs et al. 2000, sect. 3 and 4.4; ISIS ``BundleAdjust``)

    Σ_measures |v|² / σ_px²  +  Σ_images Σ_k (θ_k / σ_k)²  +  Σ_constrained (X − X₀)ᵀ Σ₀⁻¹ (X − X₀)

over the image parameters θ and the free and constrained points (fixed points are held),
by Levenberg–Marquardt on the reduced camera system (Schur complement of the points,
:mod:`demtool.bundle.reduced_system`).
Its σ₀ is jigsaw's: ``sqrt(vᵀPv / dof)`` with ``dof`` = observations (2 per measure)
+ constrained image and point parameters − unknowns.
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from demtool.bundle.network_geometry import (  # noqa: F401  (part of this interface)
    ImageFrame,
    corrected_partials,
    image_axes,
    project_corrected,
)
from demtool.bundle.priors import Observations
from demtool.bundle.reduced_system import (
    NormalEquations,
    damped_step,
    reduced_camera_system,
)

#: parameter names per image, in order (knoten/usgscsm's names, jigsaw's groups)
PARAMETER_NAMES = ("omega", "phi", "kappa", "omega rate", "phi rate", "kappa rate",
                   "omega accl", "phi accl", "kappa accl", "along-track position bias",
                   "cross-track position bias", "radial position bias")
PARAMETER_UNITS = ("rad",) * 3 + ("rad/s",) * 3 + ("rad/s2",) * 3 + ("m",) * 3
#: internal scaling of the parameters (the solver works in µrad, µrad/s, µrad/s², m)
_SCALE = np.array([1e-6] * 9 + [1.0] * 3)
GROUPS = {"angles": range(0, 3), "rates": range(3, 6), "accelerations": range(6, 9),
          "position": range(9, 12)}


@dataclass
class NetworkProblem:
    """A control network ready to adjust.

    Attributes
    ----------
    models : list of SensorModel
        One per image (the images measured by the network, input order).
    observations : Observations
        Measures: image and point index, line and sample (demtool's pixels).
    points : (P, 3) float64
        Start positions of the points, body-fixed metres.
    point_kind : (P,) int
        0 free, 1 constrained, 2 fixed.
    point_prior : (P, 3, 3) float64
        A priori covariance (m²) of constrained points (identity elsewhere, unused).
    apriori_points : (P, 3) float64
        The constrained points' a priori positions.
    solve : (12,) bool
        Which of :data:`PARAMETER_NAMES` are solved.
    sigmas : (12,) float64
        Their a priori standard deviations (SI units).
    pixel_sigma : float
        Standard deviation of a measure's line and sample, pixels.
    """

    models: list
    observations: Observations
    points: np.ndarray
    point_kind: np.ndarray
    point_prior: np.ndarray
    apriori_points: np.ndarray
    solve: np.ndarray
    sigmas: np.ndarray
    pixel_sigma: float = 1.0
    #: ground control from altimetry (:class:`demtool.bundle.network_altimetry.
    #: ShotSurface`): the points' heights tied to the shots' surface
    reference: object | None = None


@dataclass
class NetworkSolution:
    """The result of :func:`adjust_network`.

    ``theta`` (N, 12) SI units; ``theta_sigma`` (N, 12) their a posteriori standard
    deviations (σ₀ × the inverse normal matrix; NaN where not solved); ``points``
    (P, 3) and ``point_covariance`` (P, 3, 3, m², a posteriori, NaN for fixed points);
    ``residuals`` (M, 2) computed − measured (line, sample), pixels, NaN for rejected
    measures; ``kept`` (M,) bool; ``rejected`` {measure index: reason};
    ``sigma0`` jigsaw's, ``dof``; ``initial_sigma0`` (the prior models and start points,
    same dof); ``iterations``; ``history``: σ₀ after each iteration.
    """

    theta: np.ndarray
    theta_sigma: np.ndarray
    points: np.ndarray
    point_covariance: np.ndarray
    residuals: np.ndarray
    kept: np.ndarray
    rejected: dict
    sigma0: float
    dof: int
    initial_sigma0: float
    iterations: int
    history: list


def _residuals(problem, frames, theta, points, lines=None):
    """(M, 2) computed − measured and the computed lines, for all observations."""
    obs = problem.observations
    out = np.full((len(obs.image), 2), np.nan)
    computed_lines = np.full(len(obs.image), np.nan)
    for i, model in enumerate(problem.models):
        sel = np.flatnonzero(obs.image == i)
        if not len(sel):
            continue
        line, sample = project_corrected(model, frames[i], theta[i] * _SCALE,
                                         points[obs.point[sel]],
                                         None if lines is None else lines[sel])
        out[sel, 0] = line - obs.line[sel]
        out[sel, 1] = sample - obs.sample[sel]
        computed_lines[sel] = line
    return out, computed_lines


def _cost(problem, theta, points, residuals, keep):
    v = residuals[keep]
    cost = float(np.sum(v ** 2)) / problem.pixel_sigma ** 2
    weights = _prior_weights(problem)
    cost += float(np.sum(theta ** 2 * weights))
    constrained = problem.point_kind == 1
    if np.any(constrained):
        d = points[constrained] - problem.apriori_points[constrained]
        cost += float(np.einsum("pi,pij,pj->", d, np.linalg.inv(
            problem.point_prior[constrained]), d))
    if problem.reference is not None:
        dh, sigma = problem.reference.residuals(points)
        cost += float(np.nansum((dh / sigma) ** 2))
    return cost


def _prior_weights(problem) -> np.ndarray:
    """(12,) weights of the image parameters' priors, internal units; unsolved
    parameters get an overwhelming weight (held at 0)."""
    sigma = problem.sigmas / _SCALE
    return np.where(problem.solve, 1.0 / sigma ** 2, 1e16)


def _normal(problem, frames, theta, points, base, lines, keep):
    obs = problem.observations
    n, k = len(problem.models), 12
    m = len(obs.image)
    jc = np.zeros((m, 2, k))
    jp = np.zeros((m, 2, 3))
    for i, model in enumerate(problem.models):
        sel = np.flatnonzero(obs.image == i)
        if len(sel):
            jc[sel], jp[sel] = corrected_partials(model, frames[i], theta[i] * _SCALE,
                                                  points[obs.point[sel]], lines[sel])
    jc[:, :, ~problem.solve] = 0.0
    w = keep.astype(np.float64) / problem.pixel_sigma ** 2
    base = np.where(keep[:, None], base, 0.0)
    jc = np.nan_to_num(jc) * keep[:, None, None]
    jp = np.nan_to_num(jp) * keep[:, None, None]
    jp[problem.point_kind[obs.point] == 2] = 0.0
    u = np.zeros((n, k, k))
    np.add.at(u, obs.image, np.einsum("mki,mkj->mij", jc * w[:, None, None], jc))
    prior = _prior_weights(problem)
    u[:, np.arange(k), np.arange(k)] += prior
    n_points = len(points)
    v = np.zeros((n_points, 3, 3))
    np.add.at(v, obs.point, np.einsum("mki,mkj->mij", jp * w[:, None, None], jp))
    gc = np.zeros((n, k))
    np.add.at(gc, obs.image, -np.einsum("mki,mk->mi", jc * w[:, None, None], base))
    gc -= prior * theta
    gp = np.zeros((n_points, 3))
    np.add.at(gp, obs.point, -np.einsum("mki,mk->mi", jp * w[:, None, None], base))
    constrained = np.flatnonzero(problem.point_kind == 1)
    if len(constrained):
        inv = np.linalg.inv(problem.point_prior[constrained])
        v[constrained] += inv
        gp[constrained] -= np.einsum("pij,pj->pi", inv, points[constrained]
                                     - problem.apriori_points[constrained])
    if problem.reference is not None:  # altimetry: one height observation per point
        dh, sigma = problem.reference.residuals(points)
        tied = np.flatnonzero(np.isfinite(dh))
        grad = problem.reference.gradient(points[tied])
        weight = 1.0 / sigma[tied] ** 2
        v[tied] += weight[:, None, None] * grad[:, :, None] * grad[:, None, :]
        gp[tied] -= (weight * dh[tied])[:, None] * grad
    fixed = problem.point_kind == 2
    v[fixed] = np.eye(3)
    gp[fixed] = 0.0
    g = np.zeros((n_points, 3, n, k))
    np.add.at(g, (obs.point, slice(None), obs.image),
              np.swapaxes(np.einsum("mki,mkj->mij", jc * w[:, None, None], jp), 1, 2))
    return NormalEquations(u, v, g.reshape(n_points, 3, n * k), gc, gp)


def _dof(problem, keep) -> int:
    kept_points = np.unique(problem.observations.point[keep])
    kinds = problem.point_kind[kept_points]
    unknowns = 3 * int(np.count_nonzero(kinds != 2)) + \
        len(problem.models) * int(np.count_nonzero(problem.solve))
    constrained = 3 * int(np.count_nonzero(kinds == 1)) + \
        len(problem.models) * int(np.count_nonzero(problem.solve))
    heights = 0
    if problem.reference is not None:
        dh, _ = problem.reference.residuals(problem.points[kept_points])
        heights = int(np.count_nonzero(np.isfinite(dh)))
    return 2 * int(np.count_nonzero(keep)) + constrained + heights - unknowns


def _solve(problem, frames, theta, points, keep, max_iterations, history):
    base, lines = _residuals(problem, frames, theta, points)
    keep = keep & np.all(np.isfinite(base), axis=1)
    cost = _cost(problem, theta, points, base, keep)

    def trial(dc, dp):  # the step from the current theta and points
        new_theta, new_points = theta + dc, points + dp
        new_base, new_lines = _residuals(problem, frames, new_theta, new_points, lines)
        usable = keep & np.all(np.isfinite(new_base), axis=1)
        new_cost = _cost(problem, new_theta, new_points, new_base, usable) + \
            1e6 * np.count_nonzero(keep & ~usable)
        return new_cost, (new_theta, new_points, new_base, new_lines, usable)

    lam = 1e-8  # Gauss–Newton first; damped only when a step fails
    iterations = 0
    for _ in range(max_iterations):
        iterations += 1
        normal = _normal(problem, frames, theta, points, base, lines, keep)
        step = damped_step(normal, lam, cost, trial, min_lambda=1e-12)
        if step is None:  # stalled
            return theta, points, base, keep, iterations
        lam, new_cost = step.lam, step.cost
        new_theta, new_points, new_base, new_lines, usable = step.trial
        converged = cost - new_cost <= 1e-8 * cost
        theta, points, base, lines, cost = new_theta, new_points, new_base, new_lines, new_cost
        keep = usable
        history.append(float(np.sqrt(cost / max(_dof(problem, keep), 1))))
        if converged:
            break
    return theta, points, base, keep, iterations


#: below this many measures per image the compiled projections run on one thread: a
#: network's few hundred points per call cost less than waking a thread pool (10x on a
#: busy machine)
SERIAL_BELOW = 20_000


@contextmanager
def _kernel_threads(measures_per_image: int):
    import numba

    if measures_per_image >= SERIAL_BELOW:
        yield
        return
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(before)


def adjust_network(problem: NetworkProblem, *, max_iterations: int = 20,
                   rejection_multiplier: float | None = 3.0) -> NetworkSolution:
    """:func:`adjust_network_core` with the compiled projections on one thread for
    networks of fewer than :data:`SERIAL_BELOW` measures per image."""
    counts = np.bincount(problem.observations.image, minlength=len(problem.models))
    with _kernel_threads(int(counts.max()) if len(counts) else 0):
        return adjust_network_core(problem, max_iterations=max_iterations,
                                   rejection_multiplier=rejection_multiplier)


def adjust_network_core(problem: NetworkProblem, *, max_iterations: int = 20,
                        rejection_multiplier: float | None = 3.0) -> NetworkSolution:
    """Adjust the images' parameters and the network's points (module docstring).

    ``rejection_multiplier``: after convergence, measures whose residual (either
    coordinate) exceeds this many robust standard deviations of the residuals
    (1.4826 × their median absolute value), and at least 3 σ_px, are rejected and the
    block adjusted again, until none is (jigsaw's outlier rejection, ``REJECTION_
    MULTIPLIER``); None: no rejection.  Measures whose point does not project into
    their image are rejected too, and points left with fewer than two measures (free
    points) are dropped.
    """
    obs = problem.observations
    frames = [image_axes(m) for m in problem.models]
    theta = np.zeros((len(problem.models), 12))
    points = problem.points.copy()
    keep = np.ones(len(obs.image), dtype=bool)
    rejected: dict[int, str] = {}
    base, _ = _residuals(problem, frames, theta, points)
    for index in np.flatnonzero(~np.all(np.isfinite(base), axis=1)):
        rejected[int(index)] = "the point does not project into the image (prior model)"
    keep &= np.all(np.isfinite(base), axis=1)
    keep = _enough_measures(problem, keep, rejected)
    initial = _cost(problem, theta, points, base, keep)
    initial_sigma0 = float(np.sqrt(initial / max(_dof(problem, keep), 1)))
    history: list[float] = []
    total = 0
    for _ in range(10):
        theta, points, base, new_keep, iterations = _solve(problem, frames, theta, points,
                                                           keep, max_iterations, history)
        total += iterations
        for index in np.flatnonzero(keep & ~new_keep):
            rejected[int(index)] = "the point no longer projects into the image"
        keep = new_keep
        if rejection_multiplier is None:
            break
        robust = 1.4826 * float(np.median(np.abs(base[keep])))
        limit = max(rejection_multiplier * robust, 3.0 * problem.pixel_sigma)
        worst = np.max(np.abs(np.nan_to_num(base, nan=np.inf)), axis=1)
        out = keep & (worst > limit)
        if not np.any(out):
            break
        for index in np.flatnonzero(out):
            rejected[int(index)] = (f"residual {worst[index]:.2f} px > {limit:.2f} px "
                                    f"({rejection_multiplier:g} x the robust sigma "
                                    f"{robust:.3f} px)")
        keep = _enough_measures(problem, keep & ~out, rejected)
    dof = _dof(problem, keep)
    cost = _cost(problem, theta, points, base, keep)
    sigma0 = float(np.sqrt(cost / max(dof, 1)))
    theta_sigma, point_cov = _covariances(problem, frames, theta, points, base, keep, sigma0)
    residuals = np.where(keep[:, None], base, np.nan)
    return NetworkSolution(theta=theta * _SCALE, theta_sigma=theta_sigma, points=points,
                           point_covariance=point_cov, residuals=residuals, kept=keep,
                           rejected=rejected, sigma0=sigma0, dof=dof,
                           initial_sigma0=initial_sigma0, iterations=total, history=history)


def _enough_measures(problem, keep, rejected) -> np.ndarray:
    """Drop the measures of free points left with fewer than two kept measures."""
    obs = problem.observations
    counts = np.bincount(obs.point[keep], minlength=len(problem.points))
    thin = keep & (counts[obs.point] < 2) & (problem.point_kind[obs.point] == 0)
    for index in np.flatnonzero(thin):
        rejected.setdefault(int(index), "its free point has fewer than two measures left")
    return keep & ~thin


def _covariances(problem, frames, theta, points, base, keep, sigma0):
    """A posteriori standard deviations of the image parameters (N, 12; SI units) and
    covariances of the points (P, 3, 3; m²): σ₀² × the inverse normal matrix."""
    _, lines = _residuals(problem, frames, theta, points)
    normal = _normal(problem, frames, theta, points, base, lines, keep)
    s, _, v_inv = reduced_camera_system(normal, 0.0)
    n, k = len(problem.models), 12
    try:
        q = np.linalg.inv(s)
    except np.linalg.LinAlgError:
        q = np.full_like(s, np.nan)
    diag = np.sqrt(np.abs(np.diag(q))).reshape(n, k) * sigma0 * _SCALE
    diag[:, ~problem.solve] = np.nan
    vg = v_inv @ normal.g  # (P, 3, nk)
    point_cov = (v_inv + np.einsum("pai,ij,pbj->pab", vg, q, vg)) * sigma0 ** 2
    point_cov[problem.point_kind == 2] = np.nan
    return diag, point_cov


def solve_mask(groups: Sequence[str]) -> np.ndarray:
    """(12,) bool: the parameters of the named :data:`GROUPS`."""
    mask = np.zeros(12, dtype=bool)
    for group in groups:
        mask[list(GROUPS[group])] = True
    return mask
