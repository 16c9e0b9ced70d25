"""Parameters of a synthetic scene (a light module: no numpy, so the CLI imports it fast).

The fields carry their option names, ranges and help (:mod:`demtool.parameters`);
``demtool synth``'s options are generated from them.
"""

from __future__ import annotations

from dataclasses import dataclass

from demtool.parameters import Parameters, parameter, seed_field

#: Camera layouts of :class:`SceneParams` (``layout``).
LAYOUTS = ("stereo", "ring", "strip")
#: Sensor models of :class:`SceneParams` (``sensor``).
SENSORS = ("pinhole", "frame", "linescan")


@dataclass(frozen=True)
class SceneParams(Parameters):
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
        mean surface (line-scan views and ``--sensor-model`` windows: ``image_lines``
        lines of ``image_size`` samples); target ground sampling distance ``gsd_m`` (focal length
        altitude/gsd in pixels); partner B/H ``partner_bh``; other views from
        ``bh_min`` to ``bh_max``.
    Sensor models and body
        ``sensor``: ``pinhole`` (local-frame pinholes, ``cameras.npz``), ``frame``
        (the same views as CSM frame cameras on the body, an ISD each) or ``linescan``
        (two pushbroom cameras, off-nadir roll pair of ``convergence_deg``, ground
        speed ``ground_speed_m_s``); the scene sits on ``body``'s reference sphere at
        (``center_lon_deg``, ``center_lat_deg``).
    Illumination and sensor
        Sun at incidence ``sun_incidence_deg`` (from the zenith) and azimuth
        ``sun_azimuth_deg`` (clockwise from north); ``exposure_dn`` is the expected
        signal of a flat surface of mean albedo seen at nadir; photon noise with
        ``gain_e_per_dn`` electrons per DN, Gaussian read noise ``read_noise_dn``
        (both off when ``noise`` is False); quantised to ``bit_depth`` bits.
    """

    seed: int = seed_field()
    dem_size: int = parameter(512, "DEM size in cells (square).", option="size", minimum=16)
    spacing_m: float = parameter(1.0, "DEM cell size, metres.", option="spacing", minimum=0,
                                 min_open=True)
    fractal_rms_m: float = parameter(2.0, "RMS height of the fractal relief, metres.",
                                     option="relief", minimum=0)
    spectral_exponent: float = parameter(
        3.0, "Exponent β of the relief's power spectrum P(k) ∝ k^-β (β = 2H + 2).",
        minimum=1.0, maximum=5.0)
    crater_count: int = parameter(60, "Number of craters (0 = none).", option="craters",
                                  minimum=0)
    crater_exponent: float = parameter(
        2.0, "Slope b of the cumulative size-frequency law N(>D) ∝ D^-b.", minimum=0,
        min_open=True)
    crater_min_diameter_m: float = parameter(6.0, "Smallest crater diameter, metres.",
                                             option="crater-min", minimum=0, min_open=True)
    crater_max_diameter_m: float = parameter(100.0, "Largest crater diameter, metres.",
                                             option="crater-max", minimum=0, min_open=True)
    crater_depth_ratio: float = parameter(
        0.2, "Crater depth (rim crest to floor) / diameter (Pike 1977).",
        option="crater-depth", minimum=0.0, maximum=1.0)
    rim_height_ratio: float = parameter(
        0.04, "Crater rim height above the surroundings / diameter (Pike 1977).",
        option="rim-height", minimum=0.0, maximum=1.0)
    boulder_count: int = parameter(200, "Number of boulders (0 = none).", option="boulders",
                                   minimum=0)
    boulder_height_m: float = parameter(1.0, "Mean boulder height, metres.",
                                        option="boulder-height", minimum=0)
    albedo_mean: float = parameter(0.12, "Mean normal albedo.", option="albedo", minimum=0.0,
                                   maximum=1.0, min_open=True)
    albedo_variation: float = parameter(0.10, "Relative albedo variation (±, low frequency).",
                                        minimum=0.0, maximum=1.0, max_open=True)
    albedo_correlation_m: float = parameter(40.0, "Correlation length of the albedo, metres.",
                                            minimum=0, min_open=True, cli=False)
    n_views: int = parameter(8, "Number of views (target, partner, others).", option="views",
                             minimum=2, maximum=99)
    image_size: int = parameter(512, "Image width and height, pixels.", minimum=16)
    image_lines: int = parameter(
        0, "Image height of line-scan views (--sensor linescan) and of --sensor-model "
        "windows, lines (0: --image-size).", minimum=0)
    altitude_m: float = parameter(1000.0, "Camera height above the mean surface, metres.",
                                  option="altitude", minimum=0, min_open=True)
    gsd_m: float = parameter(0.5, "Target ground sampling distance, metres/pixel.",
                             option="gsd", minimum=0, min_open=True)
    partner_bh: float = parameter(
        0.3, "Base-to-height ratio of the stereo partner (baseline along image x).",
        minimum=0.0, maximum=2.0, min_open=True)
    bh_min: float = parameter(0.1, "Smallest B/H (to the target) of the other views.",
                              minimum=0)
    bh_max: float = parameter(0.5, "Largest B/H (to the target) of the other views.",
                              minimum=0)
    layout: str = parameter("stereo", "Camera layout: the target and its stereo partner plus "
                            "views around them (stereo), a ring of views around the scene "
                            "(ring), or a strip of overlapping nadir frames (strip).",
                            choices=LAYOUTS, what="layout", cli=False)
    cx_offset_px: float = parameter(0.0, "Principal point offset from the image centre, x, px.",
                                    cli=False)
    cy_offset_px: float = parameter(0.0, "Principal point offset from the image centre, y, px.",
                                    cli=False)
    sensor: str = parameter("pinhole", "Sensor model of the views: local pinholes (pinhole), "
                            "CSM frame cameras on the body (frame) or two line-scan cameras "
                            "on orbits (linescan); frame and linescan write an ISD JSON "
                            "beside each image and truth_dem_map.tif.", choices=SENSORS,
                            what="sensor")
    body: str = parameter("Moon", "Body carrying the scene (frame, linescan): a name PROJ "
                          "knows; the scene sits on its reference sphere.")
    center_lon_deg: float = parameter(0.0, "Planetocentric east longitude of the scene "
                                      "centre, degrees (frame, linescan).", option="center-lon",
                                      minimum=-360.0, maximum=360.0)
    center_lat_deg: float = parameter(0.0, "Planetocentric latitude of the scene centre, "
                                      "degrees (frame, linescan).", option="center-lat",
                                      minimum=-90.0, maximum=90.0)
    convergence_deg: float = parameter(25.0, "Convergence of the line-scan pair (rolled "
                                       "±half off nadir), degrees.", option="convergence",
                                       minimum=0.0, maximum=60.0, min_open=True)
    ground_speed_m_s: float = parameter(1600.0, "Line-scan ground speed of the orbit, m/s "
                                        "(LRO: about 1600).", option="ground-speed",
                                        minimum=0.0, min_open=True)
    sun_incidence_deg: float = parameter(60.0, "Sun incidence angle from the zenith, degrees.",
                                         option="sun-incidence", minimum=0.0, maximum=90.0,
                                         max_open=True)
    sun_azimuth_deg: float = parameter(225.0, "Sun azimuth, degrees clockwise from north.",
                                       option="sun-azimuth")
    exposure_dn: float = parameter(
        1500.0, "Expected DN of a flat mean-albedo surface seen at nadir.", option="exposure",
        minimum=0, min_open=True)
    gain_e_per_dn: float = parameter(10.0, "Photon gain, electrons per DN.", option="gain",
                                     minimum=0, min_open=True)
    read_noise_dn: float = parameter(2.0, "Read noise, DN (standard deviation).",
                                     option="read-noise", minimum=0)
    noise: bool = parameter(True, "Add photon (Poisson) and read (Gaussian) noise.")
    bit_depth: int = parameter(12, "Bits per pixel of the quantised images.", minimum=1,
                               maximum=16, cli=False)

    @property
    def lines(self) -> int:
        """Lines of a line-scan view or a ``--sensor-model`` window."""
        return self.image_lines or self.image_size

    def check(self) -> None:
        """Raise ParameterError (naming the option) for values that cannot make a scene."""
        super().check()
        if self.crater_max_diameter_m < self.crater_min_diameter_m:
            self.fail("crater_max_diameter_m",
                      f"must not be smaller than {self.label('crater_min_diameter_m')}")
        if self.bh_max < self.bh_min:
            self.fail("bh_max", f"must not be smaller than {self.label('bh_min')}")
        if self.image_lines and self.sensor == "pinhole":
            self.fail("image_lines", "is for line-scan views (--sensor linescan) and "
                      "--sensor-model windows; pinhole views are square (--image-size)")
        if self.image_lines and 0 < self.image_lines < 16:
            self.fail("image_lines", f"must be 0 or at least 16, got {self.image_lines}")
        for name in ("cx_offset_px", "cy_offset_px"):
            if not abs(getattr(self, name)) < 0.5 * self.image_size:
                self.fail(name, f"must lie inside the image (|value| < image size / 2), got "
                          f"{getattr(self, name)}")
