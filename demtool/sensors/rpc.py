"""Rational polynomial camera (RPC00B): the model of Pléiades, WorldView, SPOT products.

An RPC maps geodetic longitude, latitude and height to image line and sample through
ratios of cubic polynomials of the normalised coordinates (NIMA STDI-0002 RPC00B;
GDAL's ``GDALRPCTransformer``):

``P = (lat − LAT_OFF) / LAT_SCALE``, ``L = (lon − LONG_OFF) / LONG_SCALE``,
``H = (h − HEIGHT_OFF) / HEIGHT_SCALE``;
``line = LINE_OFF + LINE_SCALE · Num_L(P, L, H) / Den_L(P, L, H)``, sample likewise;

each polynomial has 20 terms in RPC00B order: ``1, L, P, H, LP, LH, PH, L², P², H², PLH,
L³, LP², LH², L²P, P³, PH², L²H, P²H, H³``.  Image coordinates are the RPC's with the
first pixel's centre at (0, 0) (GDAL's RPC convention), i.e. CSM ``line = RPC line + 0.5``.
Heights are metres above the body's ellipsoid: WGS84 for Earth (the RPC's datum), given
by ``radii`` otherwise.

Image to ground solves the two RPC equations for (lon, lat) at a given height by Newton
iterations (analytic Jacobian, from the normalised centre), as ASP's ``RPCModel``
and GDAL's RPC transformer do; the imaging ray joins the ground points at the top and
bottom of the RPC's height range.

The model is checked as it is built: 20 finite coefficients per polynomial, non-zero
scales, and denominators that neither are all zero nor vanish inside the validity domain
(the cube ``|P|, |L|, |H| ≤ 1`` of the offsets and scales), where the ratio would be
infinite.  :meth:`RpcSensor.domain_problem` tells a caller whose ground lies outside that
domain (an RPC is a fit valid only there).

Readers: :mod:`demtool.sensors.rpc_files` (every file GDAL reads RPCs from, and OSSIM
``.geom`` keyword lists).

References: GDAL ``alg/gdal_rpc.cpp``; ASP ``src/asp/Camera/RPCModel.cc``; OSSIM
``ossimRpcModel.cpp``.
"""

from __future__ import annotations

import numpy as np

from demtool.maps.frames import GeodeticEllipsoid, geodetic_to_xyz, xyz_to_geodetic
from demtool.sensors.base import Ray, SensorModel

__all__ = ["COEFFS", "SCALARS", "WGS84", "RpcSensor", "geodetic_to_xyz", "xyz_to_geodetic"]

#: WGS84 semi-major and semi-minor axes, metres.
WGS84 = (6378137.0, 6356752.314245179)
#: How far (in units of the RPC's own scales) outside the validity domain a ground point
#: may lie before :meth:`RpcSensor.domain_problem` objects: RPC fits are made over the
#: domain and extrapolate smoothly a little beyond (image corners, a mountain above the
#: height range), not across another place.
DOMAIN_MARGIN = 0.5
#: The 10 offsets/scales of an RPC00B, with their ``_RPC.TXT`` names and ``.RPB`` names.
SCALARS = {"line_off": ("LINE_OFF", "lineOffset"), "samp_off": ("SAMP_OFF", "sampOffset"),
           "lat_off": ("LAT_OFF", "latOffset"), "long_off": ("LONG_OFF", "longOffset"),
           "height_off": ("HEIGHT_OFF", "heightOffset"),
           "line_scale": ("LINE_SCALE", "lineScale"), "samp_scale": ("SAMP_SCALE", "sampScale"),
           "lat_scale": ("LAT_SCALE", "latScale"), "long_scale": ("LONG_SCALE", "longScale"),
           "height_scale": ("HEIGHT_SCALE", "heightScale")}
COEFFS = {"line_num_coeff": ("LINE_NUM_COEFF", "lineNumCoef"),
          "line_den_coeff": ("LINE_DEN_COEFF", "lineDenCoef"),
          "samp_num_coeff": ("SAMP_NUM_COEFF", "sampNumCoef"),
          "samp_den_coeff": ("SAMP_DEN_COEFF", "sampDenCoef")}


def _terms(L, P, H):
    """The 20 RPC00B monomials, stacked on a new last axis."""
    one = np.ones_like(L)
    return np.stack([one, L, P, H, L * P, L * H, P * H, L * L, P * P, H * H, P * L * H,
                     L ** 3, L * P * P, L * H * H, L * L * P, P ** 3, P * H * H, L * L * H,
                     P * P * H, H ** 3], axis=-1)


def _terms_dL(L, P, H):
    z, one = np.zeros_like(L), np.ones_like(L)
    return np.stack([z, one, z, z, P, H, z, 2 * L, z, z, P * H, 3 * L * L, P * P, H * H,
                     2 * L * P, z, z, 2 * L * H, z, z], axis=-1)


def _terms_dP(L, P, H):
    z, one = np.zeros_like(L), np.ones_like(L)
    return np.stack([z, z, one, z, L, z, H, z, 2 * P, z, L * H, z, 2 * L * P, z, L * L,
                     3 * P * P, H * H, z, 2 * P * H, z], axis=-1)


class RpcSensor(SensorModel):
    """An RPC00B camera (see the module docstring).

    Parameters
    ----------
    rpc : dict
        The ten offsets/scales (keys of :data:`SCALARS`) and the four 20-coefficient
        arrays (keys of :data:`COEFFS`).
    lines, samples : int
        Image size in pixels (0 when unknown: an RPC file carries none).
    radii : (float, float)
        Ellipsoid of the heights, metres (WGS84 for Earth).
    name : str
    """

    kind = "rpc"
    #: heights are geodetic, above the ellipsoid ``radii`` (WGS 84 for Earth)
    height_reference = "ellipsoid"

    def __init__(self, rpc: dict, *, lines: int = 0, samples: int = 0,
                 radii: tuple[float, float] = WGS84, name: str = ""):
        self.rpc = {}
        for key in SCALARS:
            try:
                self.rpc[key] = float(rpc[key])
            except (KeyError, TypeError, ValueError):
                raise ValueError(f"'{SCALARS[key][0]}' is missing or not a number "
                                 f"({rpc.get(key)!r})") from None
            if not np.isfinite(self.rpc[key]):
                raise ValueError(f"'{SCALARS[key][0]}' is {self.rpc[key]}")
        for key in COEFFS:
            values = np.asarray(rpc[key], dtype=np.float64).reshape(-1)
            if values.size != 20:
                raise ValueError(f"'{COEFFS[key][0]}' has {values.size} coefficients, "
                                 "expected 20")
            if not np.all(np.isfinite(values)):
                raise ValueError(f"'{COEFFS[key][0]}' has a coefficient that is not a finite "
                                 "number")
            self.rpc[key] = values
        for key in ("line_scale", "samp_scale", "lat_scale", "long_scale", "height_scale"):
            if self.rpc[key] == 0:
                raise ValueError(f"'{SCALARS[key][0]}' is 0: scales must be non-zero")
        self._check_denominators()
        self.lines, self.samples = int(lines), int(samples)
        self.radii = (float(radii[0]), float(radii[1]))
        self.name = str(name)

    def _check_denominators(self) -> None:
        """ValueError when a denominator is all zeros or changes sign / reaches zero
        inside the validity domain (sampled on a 9³ lattice of the unit cube): the
        ratio would be infinite there, which no imaging geometry is."""
        t = np.linspace(-1.0, 1.0, 9)
        L, P, H = (v.ravel() for v in np.meshgrid(t, t, t, indexing="ij"))
        terms = _terms(L, P, H)
        for key in ("line_den_coeff", "samp_den_coeff"):
            coeffs = self.rpc[key]
            name = COEFFS[key][0]
            if not np.any(coeffs):
                raise ValueError(f"'{name}' is all zeros: the "
                                 f"{key.split('_')[0]} polynomial has no denominator")
            values = terms @ coeffs
            scale = float(np.max(np.abs(values)))
            if values.min() * values.max() <= 0 or np.min(np.abs(values)) < 1e-9 * scale:
                raise ValueError(f"'{name}' vanishes inside the RPC's validity domain "
                                 f"(denominator from {values.min():.3g} to "
                                 f"{values.max():.3g}): the model is not usable")

    @property
    def ellipsoid(self) -> GeodeticEllipsoid:
        """The ellipsoid of the heights (geodetic latitude, height along the normal)."""
        return GeodeticEllipsoid(*self.radii)

    def domain(self) -> dict[str, tuple[float, float]]:
        """The validity domain: ``lon``, ``lat`` (degrees) and ``height`` (metres) as
        (min, max) = offset ∓ |scale|."""
        r = self.rpc
        return {name: (r[off] - abs(r[scale]), r[off] + abs(r[scale]))
                for name, off, scale in (("lon", "long_off", "long_scale"),
                                         ("lat", "lat_off", "lat_scale"),
                                         ("height", "height_off", "height_scale"))}

    def domain_problem(self, lon, lat, height, *, margin: float = DOMAIN_MARGIN
                       ) -> str | None:
        """Why ground points lie outside the validity domain (by more than ``margin``
        times the scales; NaN ignored), or None when they are inside.

        Parameters
        ----------
        lon, lat : float arrays, degrees (geodetic, WGS 84 for Earth)
        height : float array, metres above the ellipsoid
        """
        r = self.rpc
        for what, values, off, scale, unit in (
                ("height", height, "height_off", "height_scale", " m"),
                ("latitude", lat, "lat_off", "lat_scale", "°"),
                ("longitude", lon, "long_off", "long_scale", "°")):
            v = np.asarray(values, dtype=np.float64)
            v = v[np.isfinite(v)]
            if what == "longitude":
                v = (v - r[off] + 180.0) % 360.0 - 180.0 + r[off]
            if not v.size:
                continue
            norm = (v - r[off]) / abs(r[scale])
            if np.max(np.abs(norm)) > 1.0 + margin:
                low, high = r[off] - abs(r[scale]), r[off] + abs(r[scale])
                span = (f"{v.min():.6g}" if v.min() == v.max() else
                        f"{v.min():.6g}…{v.max():.6g}")
                return (f"{what} {span}{unit} lies outside the RPC's validity domain "
                        f"{low:.6g}…{high:.6g}{unit}")
        return None

    def __repr__(self) -> str:
        return f"RpcSensor(name={self.name!r}, size={self.lines}x{self.samples})"

    # -- forward -----------------------------------------------------------------------
    def _normalised(self, lon, lat, height):
        r = self.rpc
        return ((np.asarray(lon, dtype=np.float64) - r["long_off"]) / r["long_scale"],
                (np.asarray(lat, dtype=np.float64) - r["lat_off"]) / r["lat_scale"],
                (np.asarray(height, dtype=np.float64) - r["height_off"]) / r["height_scale"])

    def lonlat_to_image(self, lon, lat, height) -> tuple[np.ndarray, np.ndarray]:
        """CSM (line, sample) of geodetic lon/lat (degrees) and height (metres)."""
        r = self.rpc
        L, P, H = np.broadcast_arrays(*self._normalised(lon, lat, height))
        t = _terms(L, P, H)
        with np.errstate(divide="ignore", invalid="ignore"):
            line = (t @ r["line_num_coeff"]) / (t @ r["line_den_coeff"])
            sample = (t @ r["samp_num_coeff"]) / (t @ r["samp_den_coeff"])
        return (line * r["line_scale"] + r["line_off"] + 0.5,
                sample * r["samp_scale"] + r["samp_off"] + 0.5)

    def _jacobian(self, L, P, H):
        """d(line_n, samp_n) / d(L, P) of the normalised model, each S-shaped."""
        r = self.rpc
        t, tl, tp = _terms(L, P, H), _terms_dL(L, P, H), _terms_dP(L, P, H)
        out = []
        for num, den in (("line_num_coeff", "line_den_coeff"),
                         ("samp_num_coeff", "samp_den_coeff")):
            n, d = t @ r[num], t @ r[den]
            for dt in (tl, tp):
                out.append(((dt @ r[num]) * d - n * (dt @ r[den])) / (d * d))
        return out  # dline/dL, dline/dP, dsamp/dL, dsamp/dP

    # -- inverse -----------------------------------------------------------------------
    def image_to_lonlat(self, line, sample, height=0.0, *, tolerance: float = 1e-9,
                        max_iterations: int = 30):
        """Geodetic (lon, lat) in degrees seen at image (line, sample) at ``height``
        metres, by Newton iterations on the normalised RPC (NaN where they diverge)."""
        r = self.rpc
        line, sample, height = np.broadcast_arrays(np.asarray(line, dtype=np.float64),
                                                   np.asarray(sample, dtype=np.float64),
                                                   np.asarray(height, dtype=np.float64))
        want_l = (line - 0.5 - r["line_off"]) / r["line_scale"]
        want_s = (sample - 0.5 - r["samp_off"]) / r["samp_scale"]
        H = (height - r["height_off"]) / r["height_scale"]
        L = np.zeros(line.shape)
        P = np.zeros(line.shape)
        for _ in range(max_iterations):
            t = _terms(L, P, H)
            with np.errstate(divide="ignore", invalid="ignore"):
                fl = (t @ r["line_num_coeff"]) / (t @ r["line_den_coeff"]) - want_l
                fs = (t @ r["samp_num_coeff"]) / (t @ r["samp_den_coeff"]) - want_s
                a, b, c, d = self._jacobian(L, P, H)
                det = a * d - b * c
                dL = (d * fl - b * fs) / det
                dP = (a * fs - c * fl) / det
            L, P = L - dL, P - dP
            if not np.any(np.abs(dL) + np.abs(dP) > tolerance):
                break
        bad = ~(np.abs(dL) + np.abs(dP) <= 1e3 * tolerance)
        lon = np.where(bad, np.nan, L * r["long_scale"] + r["long_off"])
        lat = np.where(bad, np.nan, P * r["lat_scale"] + r["lat_off"])
        return lon, lat

    def image_to_ground(self, line, sample, height=0.0) -> np.ndarray:
        """Body-fixed XYZ (metres, S + (3,)) of image points at geodetic ``height``."""
        lon, lat = self.image_to_lonlat(line, sample, height)
        return geodetic_to_xyz(lon, lat, np.broadcast_to(height, np.shape(lon)),
                               self.ellipsoid)

    def image_to_ray(self, line, sample) -> Ray:
        """The ray through the ground points at the top and bottom of the RPC's height
        range (``HEIGHT_OFF ± HEIGHT_SCALE``), from the top, unit direction downwards."""
        r = self.rpc
        top = self.image_to_ground(line, sample, r["height_off"] + abs(r["height_scale"]))
        bottom = self.image_to_ground(line, sample, r["height_off"] - abs(r["height_scale"]))
        direction = bottom - top
        direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
        return Ray(top, direction)

    def ground_to_image(self, xyz) -> tuple[np.ndarray, np.ndarray]:
        """CSM (line, sample) of body-fixed points (metres)."""
        lon, lat, height = xyz_to_geodetic(xyz, self.ellipsoid)
        return self.lonlat_to_image(lon, lat, height)

    def camera_center(self, line) -> np.ndarray:
        """An RPC carries no sensor position: NaN (S + (3,))."""
        return np.full(np.shape(line) + (3,), np.nan)

    def sun_position(self, line) -> np.ndarray:
        """An RPC carries no sun: zeros (``demtool camera`` says so)."""
        return np.zeros(np.shape(line) + (3,))



