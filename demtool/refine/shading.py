"""Surface slopes, illumination geometry and modelled reflectance on a DEM grid.

Frame (CONTRIBUTING.md, "grid frame"): x = image right (columns), y = image up
(−rows), z = toward the camera (heights, metres).  Slopes ``p = ∂z/∂x`` and
``q = ∂z/∂y`` are dimensionless (metres per metre); the unnormalised surface normal
is ``(−p, −q, 1)``, so the cosine of the angle between the normal and a unit
direction ``d`` is ``(d_z − p d_x − q d_y) / sqrt(1 + p² + q²)`` (Horn 1990,
*Height and gradient from shading*, IJCV 5(1), 37–75, eq. 1–2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from demtool.errors import ParameterError
from demtool.imaging.reflectance import get_model, get_partials


@dataclass(frozen=True)
class Illumination:
    """Sun and viewer directions in the grid frame, as unit vectors.

    Attributes
    ----------
    sun : (3,) float64
        Unit vector toward the sun (z > 0: above the horizon).
    view : (3,) float64
        Unit vector toward the camera (z > 0).
    """

    sun: np.ndarray
    view: np.ndarray

    @property
    def phase_deg(self) -> float:
        """Phase angle sun–surface–camera in degrees (constant: directional light)."""
        return float(np.degrees(np.arccos(np.clip(self.sun @ self.view, -1.0, 1.0))))

    @property
    def sun_elevation_deg(self) -> float:
        """Elevation of the sun above the grid's horizontal plane, degrees."""
        return float(np.degrees(np.arcsin(np.clip(self.sun[2], -1.0, 1.0))))

    @property
    def sun_azimuth_deg(self) -> float:
        """Sun azimuth clockwise from grid +y (image up) toward +x (image right), degrees."""
        return float(np.degrees(np.arctan2(self.sun[0], self.sun[1])) % 360.0)


def make_illumination(sun: np.ndarray, view: np.ndarray = (0.0, 0.0, 1.0)) -> Illumination:
    """Check and normalise sun and view vectors (grid frame).

    Raises
    ------
    ParameterError
        A vector that is not 3 finite numbers or has zero length, a sun at or below
        the horizon (z ≤ 0: no shading to invert), or a view from below the surface.
    """
    vectors = {}
    for name, value in (("sun", sun), ("view", view)):
        vector = np.asarray(value, dtype=np.float64).reshape(-1)
        if vector.shape != (3,) or not np.all(np.isfinite(vector)):
            raise ParameterError(f"{name} vector must be 3 finite numbers, got {value!r}")
        norm = float(np.linalg.norm(vector))
        if norm == 0.0:
            raise ParameterError(f"{name} vector has zero length")
        vectors[name] = vector / norm
    if vectors["sun"][2] <= 0.0:
        elevation = np.degrees(np.arcsin(vectors["sun"][2]))
        raise ParameterError(f"the sun is below the horizon (elevation {elevation:.1f}°, "
                             f"sun vector {np.round(vectors['sun'], 4).tolist()} in the grid "
                             "frame): shape from shading needs a lit surface")
    if vectors["view"][2] <= 0.0:
        raise ParameterError(f"the view vector {np.round(vectors['view'], 4).tolist()} points "
                             "below the horizon; it must point from the surface to the camera")
    return Illumination(sun=vectors["sun"], view=vectors["view"])


def sun_from_angles(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit sun vector in the grid frame from azimuth and elevation.

    Parameters
    ----------
    azimuth_deg : float
        Clockwise from grid +y (image up) toward +x (image right), degrees.
    elevation_deg : float
        Above the horizontal plane, degrees.
    """
    a = np.radians(azimuth_deg)
    e = np.radians(elevation_deg)
    return np.array([np.cos(e) * np.sin(a), np.cos(e) * np.cos(a), np.sin(e)])


def slopes(dem: np.ndarray, spacing: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Slopes ``p = ∂z/∂x`` and ``q = ∂z/∂y`` by central differences, reflect boundaries.

    ``p[r, c] = (z[r, c+1] − z[r, c−1]) / (2 dx)`` and
    ``q[r, c] = −(z[r+1, c] − z[r−1, c]) / (2 dy)`` (y points up, rows down), with the
    border pixels mirrored (``z[−1] = z[0]``), which is the operator G of the
    integrability term in :mod:`demtool.refine.sfs`.

    Parameters
    ----------
    dem : (H, W) float
        Heights, metres (or any unit; the slopes come out in that unit per ``spacing``).
    spacing : (dx, dy)
        Pixel spacing along x (columns) and y (rows), positive.

    Returns
    -------
    p, q : (H, W) float32
    """
    z = np.asarray(dem, dtype=np.float32)
    padded = np.pad(z, 1, mode="symmetric")
    p = (padded[1:-1, 2:] - padded[1:-1, :-2]) * np.float32(0.5 / spacing[0])
    q = (padded[:-2, 1:-1] - padded[2:, 1:-1]) * np.float32(0.5 / spacing[1])
    return p, q


def cosine(p: np.ndarray, q: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Cosine between the surface normal ``(−p, −q, 1)/N`` and a unit ``direction``."""
    dx, dy, dz = (float(v) for v in direction)  # Python floats keep float32 arrays float32
    norm = np.sqrt(1.0 + p * p + q * q)
    return (dz - p * dx - q * dy) / norm


def reflectance_map(p: np.ndarray, q: np.ndarray, illumination: Illumination,
                    model: str = "lunar-lambert",
                    albedo: np.ndarray | float = 1.0) -> np.ndarray:
    """Modelled reflectance R(p, q) of a surface with slopes ``p``, ``q``.

    Parameters
    ----------
    p, q : (H, W) float
        Slopes (dimensionless), see :func:`slopes`.
    illumination : Illumination
        Sun and view directions, grid frame.
    model : str
        A name of :data:`demtool.imaging.reflectance.MODELS`.
    albedo : float or (H, W) array
        Normal albedo ρ.

    Returns
    -------
    (H, W) float32
        Reflectance; 0 in attached shadow (μ0 ≤ 0).  Cast shadows are not modelled
        here (see :mod:`demtool.refine.shadows`).
    """
    reflect = get_model(model)
    mu0 = cosine(p, q, illumination.sun)
    mu = cosine(p, q, illumination.view)
    return reflect(mu0, mu, illumination.phase_deg, albedo).astype(np.float32)


def reflectance_and_gradient(p: np.ndarray, q: np.ndarray, illumination: Illumination,
                             model: str = "lunar-lambert"
                             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit-albedo reflectance R(p, q) and its partial derivatives ∂R/∂p, ∂R/∂q.

    Chain rule through the cosines: with ``N = sqrt(1 + p² + q²)`` and ``μ0 = s·n``,
    ``∂μ0/∂p = −s_x / N − μ0 p / N²`` (likewise for q and for μ with the view vector);
    ``∂R/∂p = ∂R/∂μ0 ∂μ0/∂p + ∂R/∂μ ∂μ/∂p``.  At grazing or shadowed geometry the
    model's partials are evaluated at the clamped cosines, so the derivative still
    points toward the lit branch (a Gauss–Newton step can leave an attached shadow).

    Returns
    -------
    R, dR_dp, dR_dq : (H, W) float32
    """
    sx, sy, sz = (float(v) for v in illumination.sun)
    vx, vy, vz = (float(v) for v in illumination.view)
    p = np.asarray(p, dtype=np.float32)
    q = np.asarray(q, dtype=np.float32)
    inv_norm = 1.0 / np.sqrt(1.0 + p * p + q * q)
    mu0 = (sz - p * sx - q * sy) * inv_norm
    mu = (vz - p * vx - q * vy) * inv_norm
    reflectance, d_mu0, d_mu = get_partials(model)(mu0, mu, illumination.phase_deg)
    inv_norm2 = inv_norm * inv_norm
    # ∂μ/∂p = −d_x/N − μ p/N², for μ0 (sun) and μ (view)
    dR_dp = d_mu0 * (-sx * inv_norm - mu0 * p * inv_norm2) \
        + d_mu * (-vx * inv_norm - mu * p * inv_norm2)
    dR_dq = d_mu0 * (-sy * inv_norm - mu0 * q * inv_norm2) \
        + d_mu * (-vy * inv_norm - mu * q * inv_norm2)
    return (reflectance.astype(np.float32), dR_dp.astype(np.float32),
            dR_dq.astype(np.float32))


def render_dem(dem: np.ndarray, spacing: tuple[float, float], illumination: Illumination,
               model: str = "lunar-lambert", albedo: np.ndarray | float = 1.0) -> np.ndarray:
    """Reflectance of a DEM under ``illumination`` (slopes by :func:`slopes`), float32."""
    p, q = slopes(dem, spacing)
    return reflectance_map(p, q, illumination, model, albedo)
