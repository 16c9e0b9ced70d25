"""Parameters of ``demtool refine``: the SfS energy (:class:`SfsParameters`) and the
DEM preparation (:class:`RefineParams`).  Defaults are the NavCam / LRO NAC studies'
(Grumpe & Wöhler 2014); each is written once, here, and the command's options are
generated from these fields.
"""

from __future__ import annotations

from dataclasses import dataclass

from demtool.imaging.reflectance import MODELS
from demtool.parameters import (
    Parameters,
    dry_run_field,
    parameter,
    scheduler_field,
    tile_overlap_field,
    tile_size_field,
)


@dataclass(frozen=True)
class SfsParameters(Parameters):
    """Parameters of :func:`refine_heights` (defaults: the NavCam / LRO NAC studies).

    Attributes
    ----------
    delta, gamma, tau : float
        Weights of Egrad, Eint and Edepth (δ = 0.001, γ = 0.2, τ = 10).
    lowpass_sigma : float
        σ of the low-pass f in Egrad and Edepth, pixels (21).
    albedo_sigma : float
        σ_ρ of the local albedo estimate, pixels (21).
    model : str
        Reflectance model, a name of :data:`demtool.imaging.reflectance.MODELS`.
    iterations : int
        Maximum number of outer iterations.
    tolerance : float
        Stop when an iteration lowers the energy by less than this fraction.
    shadow_threshold : float
        Pixels darker than this fraction of the median image are shadow (0: off).
    cast_shadows : bool
        Also drop the cast shadows of the current DEM.
    update_every : int
        Re-estimate albedo and shadows every this many iterations.
    border_px : float
        Width of the taper of the intensity weight at the grid border, pixels.
    shadow_weight : float
        Weight ω of Eshadow, the shadow-length heights of the image's shadows
        (:mod:`demtool.refine.shadow_lengths`); 0 disables it.  0.005: about the ratio
        of the intensity residual's variance (EI ≈ 2–3·10⁻³ at convergence on the
        synthetic scenes, model error included) to that of a shadow-length height
        read with ±1 px at the shadow's ends (tan ε² px², 0.07–0.33 for ε = 15–30°);
        measured on the synthetic scenes (30°, 15°, 45°; seeds 0, 1): 0.003–0.005 best,
        0.01 slightly worse, ≥ 0.1 worse than none at 30°.
    """

    delta: float = parameter(0.001, "Weight δ of Egrad (low-passed slopes tied to the input "
                             "DEM's).", minimum=0)
    gamma: float = parameter(0.2, "Weight γ of Eint (integrability of slopes and heights).",
                             minimum=0, min_open=True)
    tau: float = parameter(10.0, "Weight τ of Edepth (low-passed heights tied to the input "
                           "DEM's).", minimum=0, min_open=True)
    lowpass_sigma: float = parameter(21.0, "σ of the low-pass f in Egrad and Edepth, pixels.",
                                     minimum=0, min_open=True)
    albedo_sigma: float = parameter(21.0, "σ_ρ of the local albedo low-pass, pixels.",
                                    minimum=0, min_open=True)
    model: str = parameter("lunar-lambert", "Reflectance model.", choices=tuple(MODELS),
                           what="reflectance model")
    iterations: int = parameter(60, "Maximum number of iterations.", minimum=1)
    tolerance: float = parameter(1e-4, "Stop when an iteration lowers the energy by less "
                                 "than this fraction.", minimum=0)
    shadow_threshold: float = parameter(
        0.05, "Pixels darker than this fraction of the median image are shadow (0 = off).",
        minimum=0.0, maximum=1.0, max_open=True)
    cast_shadows: bool = parameter(True, "Also exclude the cast shadows of the current DEM "
                                   "(ray march to the sun).")
    update_every: int = parameter(5, "Re-estimate albedo and shadows every this many "
                                  "iterations.", minimum=1, cli=False)
    border_px: float = parameter(8.0, "Width over which the intensity term fades out at the "
                                 "grid border, pixels.", option="border-taper", minimum=0)
    shadow_weight: float = parameter(
        0.005, "Weight of the shadow-length term: across each shadow of the image the height "
        "drop is the shadow's length × tan(sun elevation) (0 = off).", minimum=0)


@dataclass(frozen=True)
class RefineParams(SfsParameters):
    """Every parameter of ``demtool refine``: the SfS energy plus the DEM preparation.

    Attributes
    ----------
    median : int
        Median prefilter of the input DEM, odd window in pixels (0 = off; 15 in the
        LRO NAC study).
    spike_threshold : float
        Robust standard deviations from the median beyond which a pixel is a spike.
    start_sigma : float
        σ of the Gaussian smoothing of the anchor DEM the iterations start from, px.
    max_nan_fraction : float
        Largest fraction of NaN in the input DEM (gaps below it are filled).
    max_illumination_change : float
        Map route: above this spread (degrees) of the sun or view direction over the DEM
        the DEM is refined per tile, each under its own directions.
    illumination_tile : int
        Map route: tile size (px) when refining per tile.
    workers, tile_size, tile_overlap, scheduler, dry_run
        Large DEMs in tiles on Dask (:mod:`demtool.refine.tiled`; docs/stages/scale.md).
    """

    median: int = parameter(15, "Median prefilter of the input DEM, odd window in pixels "
                            "(0 = off).", minimum=0, odd=True)
    spike_threshold: float = parameter(
        4.0, "Pixels farther from the median than this many robust standard deviations are "
        "spikes and take the median in the anchor DEM that Edepth and Egrad hold (0: the "
        "median everywhere).", minimum=0)
    start_sigma: float = parameter(
        2.0, "The iterations start from the anchor DEM smoothed by a Gaussian of this σ, "
        "pixels (0: from the anchor itself).", minimum=0)
    max_nan_fraction: float = parameter(
        0.2, "Refuse a DEM with more NaN than this fraction (gaps below it are filled).",
        minimum=0.0, maximum=1.0)
    max_illumination_change: float = parameter(
        1.0, "Map route: refine per tile when the sun or view direction from the sensor "
        "model varies by more than this over the DEM, degrees.", minimum=0.0, min_open=True)
    illumination_tile: int = parameter(
        512, "Map route: tile size when refining per tile, px.", minimum=64)
    # Tiles (demtool.tiling; docs/stages/scale.md): tiled, --workers is the tiles at a time.
    workers: int = parameter(0, "Tiled: tiles computed at a time, on threads of this "
                             "process (0 or 1: one after the other); untiled: threads of "
                             "the compiled kernels (0 = all cores).", minimum=0)
    tile_size: int = tile_size_field()
    tile_overlap: int | None = tile_overlap_field(
        "4 × the larger of --lowpass-sigma and --albedo-sigma + --median + 3 × "
        "--start-sigma + --border-taper")
    scheduler: str | None = scheduler_field()
    dry_run: bool = dry_run_field()

    def sfs(self) -> SfsParameters:
        """The shape-from-shading part, for :func:`demtool.refine.refine_heights`."""
        from dataclasses import fields

        return SfsParameters(**{f.name: getattr(self, f.name)
                                for f in fields(SfsParameters)})
