"""Parameters of ``demtool bundle`` (defaults: :class:`demtool.bundle.colmap.SfmOptions`).

The command's options are generated from these fields; each SfM default is read from
the core's :class:`SfmOptions`, so it is written once.
"""

from __future__ import annotations

from dataclasses import dataclass

from demtool.core_source import core_constant, core_defaults
from demtool.parameters import Parameters, parameter, seed_field, workers_field

# Read from the core's source (bundle.colmap and bundle.register are the SfM runners), as
# every command run with a preset naming [bundle] reads them.
CORE = core_defaults("demtool.bundle.colmap:SfmOptions")
CAMERA_MODELS = core_constant("demtool.bundle.colmap:CAMERA_MODELS")
MATCHERS = core_constant("demtool.bundle.colmap:MATCHERS")
FEATURES = core_constant("demtool.bundle.register:FEATURES")


@dataclass(frozen=True)
class BundleParams(Parameters):
    """Every option of ``demtool bundle`` except its files."""

    focal_px: float | None = parameter(None, "Known focal length, pixels (principal point at "
                                       "the image centre).", minimum=0.0, min_open=True)
    focal_mm: float | None = parameter(None, "Known focal length, millimetres (with "
                                       "--pixel-mm; a metric camera's calibration).",
                                       minimum=0.0, min_open=True)
    pixel_mm: float | None = parameter(None, "Pixel pitch of the images as given, "
                                       "millimetres (the detector's or the scan's pitch "
                                       "times any downsampling; with --focal-mm).",
                                       minimum=0.0, min_open=True)
    refine_intrinsics: bool = parameter(False, "Let bundle adjustment refine known focal "
                                        "lengths (default: fixed).",
                                        flag="--refine-intrinsics")
    shared_camera: bool = parameter(CORE["shared_camera"], "One camera for all images "
                                    "(one instrument) or one per image.",
                                    flag="--shared-camera/--per-image-camera")
    camera_model: str | None = parameter(
        None, "COLMAP camera model (pinhole, optionally with radial distortion); default "
        "SIMPLE_RADIAL (f, k), or PINHOLE with known intrinsics.", choices=CAMERA_MODELS,
        what="camera model")
    self_calibrate: bool = parameter(True, "With free intrinsics (or a focal length alone), "
                                     "refine the focal length, the principal point "
                                     "and radial terms k1, k2 where the block determines "
                                     "them.")
    matcher: str = parameter(CORE["matcher"], "Pair selection: all pairs, neighbours in "
                             "input order (strips), or overlapping footprints of the sensor "
                             "models (spatial; needs --sensors or cubes); auto: exhaustive "
                             "up to 100 images.",
                             choices=(*(m for m in MATCHERS if m != "pairs"), "spatial"),
                             what="matcher")
    max_features: int | None = parameter(
        None, f"SIFT features per image (default: {CORE['max_features']}; with sensor "
        "models one per 64 pixels of image, 8192 to 65536: dense tie points tie the "
        "block to --reference-dem more tightly).", minimum=64, metavar="N")
    features: str = parameter(
        CORE["features"], "SIFT features: COLMAP's standard ones; rich ones (affine-shaped "
        "DSP-SIFT at a third of the peak threshold, guided matching: weak texture, wide "
        "angles between views; about 7x slower to extract); auto: standard, then a second "
        "pass with rich ones when views are left unregistered.",
        choices=FEATURES, what="features")
    position_sigma: float = parameter(100.0, "With sensor models: standard deviation of the "
                                      "prior sensor positions, metres.", minimum=0.0,
                                      min_open=True)
    pointing_sigma: float = parameter(1.0, "With sensor models: standard deviation of the "
                                      "prior pointing, milliradians.", minimum=0.0,
                                      min_open=True)
    reference_dem_sigma: float = parameter(10.0, "With --reference-dem: standard deviation "
                                           "of its heights (noise), metres; where the DEM's "
                                           "interpolation error exceeds it, each tie point "
                                           "adds that error: post^2/8 x the local "
                                           "curvature (bilinear's bound) and the share of "
                                           "post x local slope it leaves, both measured on "
                                           "the DEM.", minimum=0.0, min_open=True)
    refine_ties: bool = parameter(True, "With sensor models: re-measure the SIFT tie "
                                  "points by affine least-squares matching (removes "
                                  "SIFT's perspective-dependent bias).",
                                  flag="--refine-ties/--no-refine-ties")
    register_to_dem: bool = parameter(True, "With --reference-dem: also adjust from the "
                                      "prior block registered to the DEM (a search of "
                                      "shifts within 3 sigmas of the priors) and keep the "
                                      "solution of lower cost.",
                                      flag="--register-to-dem/--no-register-to-dem")
    solve: str = parameter("angles+rates", "With --control-network: the pointing terms "
                           "solved per image (polynomial in time: knoten's omega/phi/kappa "
                           "bias, rate, acceleration; jigsaw's CKDEGREE 0-2); a frame "
                           "camera's rates are not solved.",
                           choices=("angles", "angles+rates", "angles+rates+accelerations"),
                           what="pointing terms")
    solve_position: bool = parameter(False, "With --control-network: also solve a constant "
                                     "position bias per image (along track, across track, "
                                     "radial; a priori --position-sigma).",
                                     flag="--solve-position/--no-solve-position")
    angular_rate_sigma: float = parameter(0.1, "With --control-network: a priori standard "
                                          "deviation of the angular rates, mrad/s (the "
                                          "angles': --pointing-sigma).", minimum=0.0,
                                          min_open=True)
    angular_acceleration_sigma: float = parameter(0.01, "With --control-network: a priori "
                                                  "standard deviation of the angular "
                                                  "accelerations, mrad/s^2.", minimum=0.0,
                                                  min_open=True)
    measure_sigma: float = parameter(1.0, "With --control-network: standard deviation of a "
                                     "measure's line and sample, pixels.", minimum=0.0,
                                     min_open=True)
    rejection_multiplier: float = parameter(3.0, "With --control-network: reject measures "
                                            "whose residual exceeds this many robust sigmas "
                                            "(and 3 --measure-sigma) and adjust again "
                                            "(jigsaw's outlier rejection); 0: none.",
                                            minimum=0.0)
    reference_points_sigma: float = parameter(1.0, "With --reference-points: standard "
                                              "deviation of a shot's height, metres, where "
                                              "the table states none (a sigma column).",
                                              minimum=0.0, min_open=True)
    reproducible: bool = parameter(
        CORE["reproducible"], "Map and adjust with one thread: the same inputs give the "
        "same bundle.npz bit for bit (feature extraction and matching still use "
        "--workers).  --fast-nondeterministic maps with --workers threads too: faster on "
        "large blocks, but two runs may differ in the last bits of the poses (and, "
        "through incremental mapping, in which points are triangulated).",
        flag="--reproducible/--fast-nondeterministic")
    seed: int = seed_field()
    workers: int = workers_field()

    def check(self) -> None:
        super().check()
        if (self.focal_mm is None) != (self.pixel_mm is None):
            given, missing = (("focal_mm", "--pixel-mm") if self.pixel_mm is None
                              else ("pixel_mm", "--focal-mm"))
            self.fail(given, f"needs {missing} (the focal length in pixels is their ratio)")
        if self.focal_mm is not None and self.focal_px is not None:
            self.fail("focal_px", "and --focal-mm both give the focal length; give one")

    def known_focal_px(self) -> float | None:
        """The known focal length in pixels: --focal-px, or --focal-mm / --pixel-mm."""
        if self.focal_mm is not None and self.pixel_mm is not None:
            return self.focal_mm / self.pixel_mm
        return self.focal_px
