"""Parameters of a synthetic scene (a light module: no numpy, so the CLI imports it fast)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from demtool.errors import ParameterError

#: Camera layouts of :class:`SceneParams` (``layout``).
LAYOUTS = ("stereo", "ring", "strip")


@dataclass(frozen=True)
class SceneParams:
    """Every parameter of a synthetic scene (defaults: the demo scene).

    Terrain
        ``dem_size`` cells of ``spacing_m`` metres (square); fractal relief of RMS
        ``fractal_rms_m`` and spectral exponent ``spectral_exponent`` (β of
        P(k) ∝ k^-β); ``crater_count`` simple craters with diameters between
        ``crater_min_diameter_m`` and ``crater_max_diameter_m`` from N(>D) ∝ D^-b with
        b = ``crater_exponent``, depth ``crater_depth_ratio``·D, rim height
        ``rim_height_ratio``·D (Pike 1977); ``boulder_count`` boulders of mean height
        ``boulder_height_m``.
    Albedo
        ``albedo_mean`` · (1 ± ``albedo_variation``), correlation length
        ``albedo_correlation_m`` (low frequency).
    Cameras
        ``n_views`` square images of ``image_size`` pixels at ``altitude_m`` above the
        mean surface; target ground sampling distance ``gsd_m`` (focal length
        altitude/gsd in pixels); partner B/H ``partner_bh``; other views from
        ``bh_min`` to ``bh_max``.
    Illumination and sensor
        Sun at incidence ``sun_incidence_deg`` (from the zenith) and azimuth
        ``sun_azimuth_deg`` (clockwise from north); ``exposure_dn`` is the expected
        signal of a flat surface of mean albedo seen at nadir; photon noise with
        ``gain_e_per_dn`` electrons per DN, Gaussian read noise ``read_noise_dn``
        (both off when ``noise`` is False); quantised to ``bit_depth`` bits.
    """

    seed: int = 0
    dem_size: int = 512
    spacing_m: float = 1.0
    fractal_rms_m: float = 2.0
    spectral_exponent: float = 3.0
    crater_count: int = 60
    crater_exponent: float = 2.0
    crater_min_diameter_m: float = 6.0
    crater_max_diameter_m: float = 100.0
    crater_depth_ratio: float = 0.2
    rim_height_ratio: float = 0.04
    boulder_count: int = 200
    boulder_height_m: float = 1.0
    albedo_mean: float = 0.12
    albedo_variation: float = 0.10
    albedo_correlation_m: float = 40.0
    n_views: int = 8
    image_size: int = 512
    altitude_m: float = 1000.0
    gsd_m: float = 0.5
    partner_bh: float = 0.3
    bh_min: float = 0.1
    bh_max: float = 0.5
    layout: str = "stereo"
    cx_offset_px: float = 0.0
    cy_offset_px: float = 0.0
    sun_incidence_deg: float = 60.0
    sun_azimuth_deg: float = 225.0
    exposure_dn: float = 1500.0
    gain_e_per_dn: float = 10.0
    read_noise_dn: float = 2.0
    noise: bool = True
    bit_depth: int = 12

    def as_dict(self) -> dict[str, Any]:
        """All parameters as a plain dict (for JSON and tags)."""
        return asdict(self)



def check_parameters(params: SceneParams) -> None:
    """Raise ParameterError (naming the parameter) for values that cannot make a scene."""
    positive = ["dem_size", "spacing_m", "image_size", "altitude_m", "gsd_m", "exposure_dn",
                "gain_e_per_dn", "albedo_mean", "crater_min_diameter_m", "crater_exponent",
                "albedo_correlation_m", "bit_depth"]
    for name in positive:
        if not getattr(params, name) > 0:
            raise ParameterError(f"{name} must be positive, got {getattr(params, name)}")
    non_negative = ["fractal_rms_m", "crater_count", "boulder_count", "boulder_height_m",
                    "read_noise_dn", "crater_depth_ratio", "rim_height_ratio", "partner_bh",
                    "bh_min", "bh_max"]
    for name in non_negative:
        if not getattr(params, name) >= 0:
            raise ParameterError(f"{name} must not be negative, got {getattr(params, name)}")
    if params.n_views < 2:
        raise ParameterError(f"n_views must be at least 2 (target and partner), "
                             f"got {params.n_views}")
    if params.dem_size < 16:
        raise ParameterError(f"dem_size must be at least 16 cells, got {params.dem_size}")
    if params.crater_max_diameter_m < params.crater_min_diameter_m:
        raise ParameterError("crater_max_diameter_m must not be smaller than "
                             "crater_min_diameter_m")
    if params.bh_max < params.bh_min:
        raise ParameterError("bh_max must not be smaller than bh_min")
    if not 0.0 <= params.sun_incidence_deg < 90.0:
        raise ParameterError(f"sun_incidence_deg must be in [0, 90), got "
                             f"{params.sun_incidence_deg}")
    if not 0.0 <= params.albedo_variation < 1.0:
        raise ParameterError(f"albedo_variation must be in [0, 1), got "
                             f"{params.albedo_variation}")
    if params.layout not in LAYOUTS:
        raise ParameterError(f"layout must be one of {', '.join(LAYOUTS)}, got "
                             f"{params.layout!r}")
    for name in ("cx_offset_px", "cy_offset_px"):
        if not abs(getattr(params, name)) < 0.5 * params.image_size:
            raise ParameterError(f"{name} must lie inside the image (|value| < "
                                 f"image_size/2), got {getattr(params, name)}")
    if params.bit_depth > 16:
        raise ParameterError(f"bit_depth must be at most 16, got {params.bit_depth}")
