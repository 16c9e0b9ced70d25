"""The damped reduced camera system shared by demtool's bundle adjustments.

Both the pose-prior adjustment (:mod:`demtool.bundle.lm`: 6 unknowns per image) and the
control-network adjustment (:mod:`demtool.bundle.network`: 12 per image) solve their
normal equations by blocks: the point blocks are eliminated (Schur complement, Triggs
et al. 2000, "Bundle adjustment — a modern synthesis", sect. 6.1), the reduced camera
system is solved, the point steps are back-substituted, and Levenberg–Marquardt damps
both block diagonals by ``1 + λ`` (Marquardt 1963, "An algorithm for least-squares
estimation of nonlinear parameters"), raising λ tenfold on a singular system or a step
that does not lower the cost and lowering it tenfold after a step that does.  Each
caller keeps its own cost, its own starting λ and its own floor for it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np


class NormalEquations(NamedTuple):
    """Normal equations of one Gauss–Newton iteration, by blocks (K unknowns per image).

    Attributes
    ----------
    u : (N, K, K) float64
        Camera blocks (priors included).
    v : (P, 3, 3) float64
        Point blocks.
    g : (P, 3, N·K) float64
        Coupling of each point with every image's unknowns.
    gc : (N, K) float64
        Right-hand sides of the cameras (minus the gradient of half the cost).
    gp : (P, 3) float64
        Right-hand sides of the points.
    """

    u: np.ndarray
    v: np.ndarray
    g: np.ndarray
    gc: np.ndarray
    gp: np.ndarray


def reduced_camera_system(normal: NormalEquations, lam: float, *,
                          point_ridge: float = 0.0):
    """The damped reduced camera system (Triggs et al. 2000, sect. 6.1).

    Parameters
    ----------
    normal : NormalEquations
    lam : float
        Levenberg–Marquardt damping: both block diagonals are multiplied by ``1 + lam``
        (0: the undamped system, whose inverse is the cameras' covariance).
    point_ridge : float
        Added to the damped point blocks' diagonal (keeps a point seen by nothing
        invertible).

    Returns
    -------
    s : (N·K, N·K) float64
        ``U − Σ_p G_pᵀ V_p⁻¹ G_p``.
    rhs : (N·K,) float64
        ``gc − Σ_p G_pᵀ V_p⁻¹ gp_p``.
    v_inv : (P, 3, 3) float64
        The inverted damped point blocks.
    """
    n, k = normal.u.shape[:2]
    ud = normal.u.copy()
    ud[:, np.arange(k), np.arange(k)] *= 1.0 + lam
    vd = normal.v.copy()
    vd[:, np.arange(3), np.arange(3)] *= 1.0 + lam
    if point_ridge:
        vd[:, np.arange(3), np.arange(3)] += point_ridge
    v_inv = np.linalg.inv(vd)
    s = np.zeros((n * k, n * k))
    for i in range(n):
        s[k * i:k * i + k, k * i:k * i + k] = ud[i]
    vg = v_inv @ normal.g  # (P, 3, N·K)
    s -= np.einsum("pki,pkj->ij", normal.g, vg)
    rhs = normal.gc.ravel() - np.einsum("pki,pk->i", vg, normal.gp)
    return s, rhs, v_inv


class DampedStep(NamedTuple):
    """An accepted Levenberg–Marquardt step: the camera step ``cameras`` (N, K) and the
    point step ``points`` (P, 3), the ``cost`` after it, what the trial returned with
    that cost (``trial``) and the λ for the next iteration (``lam``)."""

    cameras: np.ndarray
    points: np.ndarray
    cost: float
    trial: Any
    lam: float


def damped_step(normal: NormalEquations, lam: float, cost: float,
                trial: Callable[[np.ndarray, np.ndarray], tuple[float, Any]], *,
                min_lambda: float, max_lambda: float = 1e8,
                point_ridge: float = 0.0) -> DampedStep | None:
    """One Levenberg–Marquardt step on the reduced camera system.

    Solves :func:`reduced_camera_system` at ``lam`` for the camera step, back-substitutes
    the point step ``V⁻¹ (gp − G dc)`` and hands both to ``trial``, which returns the
    cost after them and anything it wants back.  A singular reduced system, or a cost
    above ``cost``, raises λ tenfold and tries again; an accepted step lowers it
    tenfold, to no less than ``min_lambda``.

    Parameters
    ----------
    normal : NormalEquations
    lam : float
        λ to start from (the caller's starting value, then what the last step returned).
    cost : float
        The cost at the current solution.
    trial : callable ``(cameras (N, K), points (P, 3)) -> (cost, result)``
    min_lambda, max_lambda : float
        λ's floor after an accepted step; past ``max_lambda`` the adjustment has
        stalled.
    point_ridge : float
        As :func:`reduced_camera_system`.

    Returns
    -------
    DampedStep, or None when no step lowered the cost before λ passed ``max_lambda``.
    """
    while True:
        s, rhs, v_inv = reduced_camera_system(normal, lam, point_ridge=point_ridge)
        try:
            dc = np.linalg.solve(s, rhs)
        except np.linalg.LinAlgError:
            lam *= 10
            continue
        dp = np.einsum("pij,pj->pi", v_inv, normal.gp - np.einsum("pki,i->pk", normal.g, dc))
        cameras = dc.reshape(normal.gc.shape)
        new_cost, result = trial(cameras, dp)
        if new_cost <= cost:
            return DampedStep(cameras, dp, new_cost, result, max(lam / 10, min_lambda))
        lam *= 10
        if lam > max_lambda:
            return None
