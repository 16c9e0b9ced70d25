"""JPL's CAHV, CAHVOR and CAHVORE camera models (rover and lander cameras of Mars missions).

The models of MSL and Mars 2020 NavCams, HazCams and Mastcams, given in the PDS3
labels' ``GEOMETRIC_CAMERA_MODEL`` group (``MODEL_COMPONENT_1`` … ``_9``) and in ASP's
``.cahvor`` / ``.cahvore`` files.  All vectors are in one frame (the rover's, a site's,
or a body-fixed one), metres for C.

**CAHV** (Yakimovsky & Cunningham 1978): a point P is imaged at
``x = (P − C)·H / (P − C)·A`` (sample) and ``y = (P − C)·V / (P − C)·A`` (line).

**CAHVOR** (Gennery 2001, "Least-squares camera calibration including lens
distortion and automatic editing of calibration points"): radial distortion about the
optical axis O.  With ``ζ = (P − C)·O``, ``λ = (P − C) − ζ O`` and ``τ = |λ|² / ζ²``,
the point is moved to ``P' = P + μ λ``, ``μ = R0 + R1 τ + R2 τ²``, and imaged by CAHV.

**CAHVORE** (Gennery 2006, "Generalized camera calibration including fish-eye
lenses", IJCV 68(3)): the entrance pupil moves along O with the ray's angle θ from it,
``s(θ) = (θ / sin θ − 1)(E0 + E1 θ² + E2 θ⁴)``, and the "linearity" L sets how θ maps
to the radial coordinate: ``χ = tan(L θ) / L`` (L > 0; L = 1 perspective, CAHVORE
type 1), ``χ = θ`` (L = 0, fish-eye, type 2), ``χ = sin(L θ) / L`` (L < 0); the
image point is CAHV of ``(λ / χ) O + (1 + μ) λ`` with ``μ = R0 + R1 χ² + R2 χ⁴``.
CAHVOR is CAHVORE with L = 1 and E = 0; CAHV has R = 0 too.

Ground → image solves θ by Newton's method on
``ζ sin θ − λ cos θ − (θ − sin θ)(E0 + E1 θ² + E2 θ⁴) = 0`` (the ray through the shifted
pupil), image → ground solves χ from ``(1 + R0) χ + R1 χ³ + R2 χ⁵ = χ'`` — the
equations of VisionWorkbench's ``CAHVOREModel::point_to_pixel`` / ``pixel_to_vector``
(after JPL's ``cmod_cahvore_3d_to_2d`` / ``2d_to_3d``) and ``CAHVORModel``.  The ray's
origin is the shifted pupil ``C + s(θ) O`` (VisionWorkbench returns C: a few mm for a
HazCam, which this keeps).

Pixel convention: CAHV's (x, y) has the centre of the first pixel at (0, 0) (JPL's and
VisionWorkbench's convention); the :class:`SensorModel` interface's CSM
``(line, sample) = (y + 0.5, x + 0.5)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from demtool.sensors.base import Ray, SensorModel, WidthHeightSensor

#: Newton's iterations stop when the update is below this (radians, or χ units)
NEWTON_TOLERANCE = 1e-12
NEWTON_ITERATIONS = 60


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@dataclass(frozen=True, eq=False)
class CahvoreCamera(WidthHeightSensor):
    """A CAHV / CAHVOR / CAHVORE camera (module docstring).

    Attributes
    ----------
    C, A, H, V, O : (3,) float64
        Centre (metres), axis (unit), horizontal and vertical vectors (pixels), optical
        axis (unit), in the model's frame.
    R : (3,) float64
        Radial distortion ``R0, R1, R2`` (zeros for CAHV).
    E : (3,) float64
        Entrance-pupil terms ``E0, E1, E2`` (metres; zeros for CAHV and CAHVOR).
    linearity : float
        CAHVORE's L (1 for CAHV and CAHVOR).
    width, height : int
        Image size, pixels (0 when the file does not say).
    body_radii : (a, b) metres or None
        The body when the frame is body-fixed (heights on its map); None for a local
        frame (a rover's or a site's).
    model_name : str
        ``"cahv"``, ``"cahvor"`` or ``"cahvore"``.
    """

    C: np.ndarray
    A: np.ndarray
    H: np.ndarray
    V: np.ndarray
    O: np.ndarray  # noqa: E741 - the model's name for it
    R: np.ndarray
    E: np.ndarray
    linearity: float = 1.0
    width: int = 0
    height: int = 0
    body_radii: tuple[float, float] | None = None
    name: str = ""
    model_name: str = "cahvore"

    kind = "cahvor"

    def __post_init__(self) -> None:
        for key in ("C", "A", "H", "V", "O", "R", "E"):
            object.__setattr__(self, key, np.asarray(getattr(self, key),
                                                     dtype=np.float64).reshape(3))
        object.__setattr__(self, "A", _unit(self.A))
        object.__setattr__(self, "O", _unit(self.O))
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        object.__setattr__(self, "linearity", float(self.linearity))

    # -- SensorModel attributes -----------------------------------------------------
    @property
    def radii(self):  # type: ignore[override]
        return self.body_radii

    @property
    def center(self) -> np.ndarray:
        """The model's C, (3,) metres."""
        return self.C.copy()

    @property
    def axis(self) -> np.ndarray:
        """The pointing axis A, (3,) unit."""
        return self.A.copy()

    def intrinsics(self) -> tuple[float, float, float, float]:
        """(hs, hc, vs, vc): CAHV's focal lengths and image centre, pixels (H = hs H' + hc A,
        V = vs V' + vc A with H', V' unit and normal to A)."""
        hc, vc = float(self.H @ self.A), float(self.V @ self.A)
        hs = float(np.linalg.norm(np.cross(self.A, self.H)))
        vs = float(np.linalg.norm(np.cross(self.A, self.V)))
        return hs, hc, vs, vc

    # -- the model's equations --------------------------------------------------------
    def _chi_of_theta(self, theta):
        L = self.linearity
        if L < -1e-15:
            return np.sin(L * theta) / L
        if L > 1e-15:
            return np.tan(L * theta) / L
        return theta

    def _theta_of_chi(self, chi):
        L = self.linearity
        if L < -1e-15:
            return np.arcsin(np.clip(L * chi, -1.0, 1.0)) / L
        if L > 1e-15:
            return np.arctan(L * chi) / L
        return chi

    def pupil_shift(self, theta) -> np.ndarray:
        """Entrance pupil's shift along O (metres) for rays θ radians off it: s(θ)."""
        theta = np.asarray(theta, dtype=np.float64)
        e = self.E
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = np.where(theta > 1e-8, theta / np.sin(theta) - 1.0, theta * theta / 6.0)
        return ratio * (e[0] + e[1] * theta ** 2 + e[2] * theta ** 4)

    def project_xy(self, points) -> tuple[np.ndarray, np.ndarray]:
        """CAHV image (x, y) (first pixel's centre at 0, 0) of points S + (3,); NaN behind.

        Gennery (2006) forward model (VisionWorkbench ``CAHVOREModel::point_to_pixel``).
        """
        p = np.asarray(points, dtype=np.float64)
        pc = p - self.C
        zeta = pc @ self.O
        lam3 = pc - zeta[..., None] * self.O
        lam = np.linalg.norm(lam3, axis=-1)
        theta = np.arctan2(lam, zeta)
        e = self.E
        if np.any(e != 0.0):
            for _ in range(NEWTON_ITERATIONS):
                c, s = np.cos(theta), np.sin(theta)
                t2 = theta * theta
                poly = e[0] + e[1] * t2 + e[2] * t2 * t2
                upsilon = (zeta * c + lam * s - (1 - c) * poly
                           - (theta - s) * (2 * e[1] * theta + 4 * e[2] * t2 * theta))
                step = (zeta * s - lam * c - (theta - s) * poly) / upsilon
                theta = theta - step
                if np.nanmax(np.abs(step), initial=0.0) < NEWTON_TOLERANCE:
                    break
        chi = self._chi_of_theta(theta)
        chi2 = chi * chi
        mu = self.R[0] + self.R[1] * chi2 + self.R[2] * chi2 * chi2
        with np.errstate(invalid="ignore", divide="ignore"):
            axial = np.where(theta > 1e-8, lam / chi, zeta)
        rp = axial[..., None] * self.O + (1.0 + mu)[..., None] * lam3
        alpha = rp @ self.A
        with np.errstate(invalid="ignore", divide="ignore"):
            x = (rp @ self.H) / alpha
            y = (rp @ self.V) / alpha
        # tan(Lθ) and sin(Lθ) invert only below π/2 (JPL's "theta out of bounds")
        bad = ~(alpha > 0) | ~(theta * abs(self.linearity) < np.pi / 2) | (theta >= np.pi)
        x = np.where(bad, np.nan, x)
        y = np.where(bad, np.nan, y)
        return x, y

    def ray_xy(self, x, y) -> Ray:
        """Rays of CAHV image points (x, y): origin (the shifted pupil) and unit direction.

        Gennery (2006) inverse (VisionWorkbench ``CAHVOREModel::pixel_to_vector``).
        """
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        x, y = np.broadcast_arrays(x, y)
        w3 = np.cross(self.V - y[..., None] * self.A, self.H - x[..., None] * self.A)
        rp = w3 / float(self.A @ np.cross(self.V, self.H))
        zetap = rp @ self.O
        lam3 = rp - zetap[..., None] * self.O
        lam = np.linalg.norm(lam3, axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            chip = lam / zetap
        r = self.R
        chi = chip.copy()
        for _ in range(NEWTON_ITERATIONS):
            chi2 = chi * chi
            derivative = (1 + r[0]) + 3 * r[1] * chi2 + 5 * r[2] * chi2 * chi2
            step = ((1 + r[0]) * chi + r[1] * chi2 * chi + r[2] * chi2 * chi2 * chi
                    - chip) / derivative
            chi = chi - step
            if np.nanmax(np.abs(step), initial=0.0) < NEWTON_TOLERANCE:
                break
        theta = self._theta_of_chi(chi)
        with np.errstate(invalid="ignore", divide="ignore"):
            radial = np.where(lam[..., None] > 0, lam3 / lam[..., None], 0.0)
        direction = (np.sin(theta)[..., None] * radial + np.cos(theta)[..., None] * self.O)
        direction = _unit(direction)
        origin = self.C + self.pupil_shift(theta)[..., None] * self.O
        bad = ~(zetap > 0) | ~np.isfinite(theta)
        direction = np.where(bad[..., None], np.nan, direction)
        return Ray(origin, direction)

    # -- SensorModel interface (CSM pixel convention) ---------------------------------
    def image_to_ray(self, line, sample) -> Ray:
        """Rays of CSM (line, sample) (first pixel's centre at 0.5, 0.5), S + (3,)."""
        line, sample = np.broadcast_arrays(np.asarray(line, dtype=np.float64),
                                           np.asarray(sample, dtype=np.float64))
        return self.ray_xy(sample - 0.5, line - 0.5)

    def ground_to_image(self, xyz) -> tuple[np.ndarray, np.ndarray]:
        """CSM (line, sample) of points S + (3,) of the model's frame; NaN behind it."""
        x, y = self.project_xy(xyz)
        return y + 0.5, x + 0.5

    def image_to_ground(self, line, sample, height=0.0) -> np.ndarray:
        """Rays met with the body's ellipsoid raised by ``height`` (body-fixed frame), or
        with the plane ``Z = height`` of a local frame (as a local pinhole)."""
        if self.body_radii is not None:
            return SensorModel.image_to_ground(self, line, sample, height)
        ray = self.image_to_ray(line, sample)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (np.asarray(height, dtype=np.float64) - ray.origin[..., 2]) \
                / ray.direction[..., 2]
        s = np.where(s > 0, s, np.nan)
        return ray.origin + s[..., None] * ray.direction

    def sun_position(self, line) -> np.ndarray:
        """A CAHVOR model carries no sun."""
        raise ValueError("a CAHVOR camera model carries no sun position")

    def camera_center(self, line) -> np.ndarray:
        """The model's C, broadcast to ``shape(line) + (3,)``."""
        return np.broadcast_to(self.C, np.shape(line) + (3,)).copy()

    # -- the pinhole helpers of the synthetic renderers ((u, v) = 0-based column, row) --
    def rays(self, pixels: np.ndarray) -> np.ndarray:
        """Unit directions (N, 3) of pixels (N, 2) given as (u, v) = (column, row)."""
        uv = np.atleast_2d(np.asarray(pixels, dtype=np.float64))
        return self.ray_xy(uv[:, 0], uv[:, 1]).direction

    def project(self, points: np.ndarray) -> np.ndarray:
        """(u, v) = (column, row) of world points (N, 3); NaN behind the camera."""
        x, y = self.project_xy(np.atleast_2d(points))
        return np.stack([x, y], axis=-1)

    def turned(self, rotation: np.ndarray, center: np.ndarray | None = None
               ) -> CahvoreCamera:
        """The same camera turned about C by ``rotation`` (every direction d → rotation d)
        and, when given, moved to ``center`` (metres)."""
        import dataclasses

        rot = np.asarray(rotation, dtype=np.float64)
        c = self.C if center is None else np.asarray(center, dtype=np.float64)
        return dataclasses.replace(self, C=c, A=rot @ self.A, H=rot @ self.H,
                                   V=rot @ self.V, O=rot @ self.O)


def cahvor_from_pinhole(K: np.ndarray, R: np.ndarray, center: np.ndarray, *, width: int,
                        height: int, radial=(0.0, 0.0, 0.0), entrance=(0.0, 0.0, 0.0),
                        linearity: float = 1.0, name: str = "") -> CahvoreCamera:
    """The CAHV(ORE) camera of a pinhole ``K [R | −R C]`` (0-based pixel centres), with
    radial terms R and pupil terms E about the optical axis O = A (Yakimovsky &
    Cunningham 1978: H = fx h' + cx A, V = fy v' + cy A with h', v', A the camera's
    x, y, z axes in the world)."""
    K = np.asarray(K, dtype=np.float64)
    R = np.asarray(R, dtype=np.float64)
    A = R[2]
    H = K[0, 0] * R[0] + K[0, 1] * R[1] + K[0, 2] * A
    V = K[1, 1] * R[1] + K[1, 2] * A
    kind = "cahv"
    if np.any(radial):
        kind = "cahvor"
    if np.any(entrance) or linearity != 1.0:
        kind = "cahvore"
    return CahvoreCamera(C=center, A=A, H=H, V=V, O=A, R=radial, E=entrance,
                         linearity=linearity, width=width, height=height, name=name,
                         model_name=kind)
