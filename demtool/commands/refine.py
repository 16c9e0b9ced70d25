"""`demtool refine`: shape-from-shading refinement of a coarse DEM with one image.

Tiers: :func:`command` (click, options only) → :func:`run_refine` (the runner: read
the image and the DEM, resolve sun and view, put the image on the DEM grid, call the
core, write the refined DEM, the optional albedo and the sidecar in one transaction)
→ :mod:`demtool.refine` (the pure core).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from demtool import option_types as ot
from demtool.cli import STAGES
from demtool.options import input_file, out_file

if TYPE_CHECKING:
    import numpy as np

    from demtool.io import Raster
    from demtool.refine import Illumination, RefineResult

# the preset/option defaults (the NavCam and LRO NAC studies)
DEFAULTS: dict[str, Any] = {
    "model": "lunar-lambert", "albedo_sigma": 21.0, "lowpass_sigma": 21.0, "delta": 0.001,
    "gamma": 0.2, "tau": 10.0, "median": 15, "spike_threshold": 4.0, "start_sigma": 2.0,
    "max_nan_fraction": 0.2, "iterations": 60, "tolerance": 1e-4, "shadow_threshold": 0.05,
    "border_taper": 8.0, "shadow_weight": 0.005,
}


# --------------------------------------------------------------------------------------
# Sun, view and grid
# --------------------------------------------------------------------------------------


def resolve_illumination(image: Raster, *, sun_azimuth: float | None = None,
                         sun_elevation: float | None = None,
                         sun_vector: tuple[float, float, float] | None = None,
                         view_vector: tuple[float, float, float] | None = None
                         ) -> tuple[Illumination, dict[str, str]]:
    """Sun and view directions (grid frame) from the options, else the image's tags.

    Returns
    -------
    illumination : Illumination
    sources : dict
        Where each vector came from (``"option"``, ``"tag sun_vector_grid"``, …).

    Raises
    ------
    ParameterError
        No sun direction anywhere, or a sun at or below the horizon.
    """
    from demtool.errors import ParameterError
    from demtool.refine import make_illumination, sun_from_angles

    if sun_vector is not None:
        sun, sun_source = sun_vector, "--sun-vector"
    elif sun_azimuth is not None and sun_elevation is not None:
        if sun_elevation <= 0:
            raise ParameterError(f"--sun-elevation {sun_elevation:g}: the sun is below the "
                                 "horizon; shape from shading needs a lit surface")
        sun, sun_source = sun_from_angles(sun_azimuth, sun_elevation), \
            "--sun-azimuth/--sun-elevation"
    elif image.tag_json("sun_vector_grid") is not None:
        sun, sun_source = image.tag_json("sun_vector_grid"), f"tag sun_vector_grid of {image.path}"
    else:
        raise ParameterError(f"{image.path}: no sun direction: the image has no "
                             "'sun_vector_grid' tag; give --sun-azimuth and --sun-elevation "
                             "or --sun-vector (grid frame: x image right, y image up, z up)")
    if view_vector is not None:
        view, view_source = view_vector, "--view"
    elif image.tag_json("view_vector_grid") is not None:
        view, view_source = image.tag_json("view_vector_grid"), \
            f"tag view_vector_grid of {image.path}"
    else:
        view, view_source = (0.0, 0.0, 1.0), "default (nadir)"
    try:
        make_illumination(sun)  # checks the sun alone, against a nadir view
    except ParameterError as exc:
        raise ParameterError(f"{sun_source}: {exc}") from None
    try:
        illumination = make_illumination(sun, view)
    except ParameterError as exc:
        raise ParameterError(f"{view_source}: {exc}") from None
    return illumination, {"sun": sun_source, "view": view_source}


def _is_unit_pixel_transform(transform) -> bool:
    return (transform.a, transform.b, transform.c, transform.d, transform.e, transform.f) == \
        (1.0, 0.0, 0.0, 0.0, -1.0, 0.0)


def _frame(raster: Raster) -> str | None:
    return raster.tags.get("frame")


def image_on_dem_grid(image: Raster, dem: Raster) -> tuple[np.ndarray, str | None]:
    """The image's values on the DEM's grid, resampled if the grids differ.

    An image in its own pixel frame (unit transform, no CRS) and a DEM in an image
    frame (CONTRIBUTING.md) are the same grid when their shapes agree; with different
    shapes the image is taken to cover the DEM's extent.  Otherwise both transforms
    must be in the same map units (and CRS), and the image is resampled bilinearly.

    Returns
    -------
    values : (H, W) float32
        Image on the DEM grid, NaN outside the image.
    note : str or None
        What was done when resampling (for the log and the sidecar), None otherwise.

    Raises
    ------
    InputError
        Different CRSs, or grids that do not overlap.
    """
    from affine import Affine

    from demtool.errors import InputError, ProcessingError
    from demtool.refine.prepare import resample_to_grid

    dem_shape = dem.data.shape
    if image.data.shape == dem_shape and image.transform == dem.transform:
        return image.data, None
    pixel_frame = (_is_unit_pixel_transform(image.transform) and image.crs is None
                   and dem.crs is None)
    if pixel_frame and image.data.shape == dem_shape:
        frames = (_frame(image), _frame(dem))
        if None not in frames and frames[0] != frames[1]:
            raise InputError(f"{image.path}: the image is in frame {frames[0]!r} but the DEM "
                             f"{dem.path} is in frame {frames[1]!r}; give the image the DEM "
                             "was computed for")
        return image.data, None
    if image.crs != dem.crs and image.crs is not None and dem.crs is not None:
        raise InputError(f"{image.path}: the image's CRS ({image.crs}) differs from the DEM's "
                         f"({dem.crs}); reproject one of them")
    source_transform = image.transform
    if pixel_frame:
        # an image in pixel units over the extent of an image-frame DEM
        height, width = image.data.shape
        sx = dem.transform.a * dem_shape[1] / width
        sy = dem.transform.e * dem_shape[0] / height
        if abs(abs(sx) / abs(sy) - abs(dem.transform.a) / abs(dem.transform.e)) > 0.02 * abs(
                sx / sy):
            raise InputError(f"{image.path}: image ({height} × {width} px) and DEM "
                             f"{dem.path} ({dem_shape[0]} × {dem_shape[1]}) have different "
                             "aspect ratios and the image has no map transform: their grids "
                             "cannot be matched")
        source_transform = Affine(sx, 0.0, dem.transform.c, 0.0, sy, dem.transform.f)
    try:
        values = resample_to_grid(image.data, source_transform, dem_shape, dem.transform)
    except ProcessingError:
        raise InputError(f"{image.path}: the image does not overlap the DEM {dem.path} "
                         "(compare their transforms); nothing to refine") from None
    import numpy as np

    note = (f"image {image.data.shape[0]} × {image.data.shape[1]} resampled onto the DEM grid "
            f"{dem_shape[0]} × {dem_shape[1]} ({100 * np.isfinite(values).mean():.1f}% "
            "covered)")
    return values, note


# --------------------------------------------------------------------------------------
# Runner
# --------------------------------------------------------------------------------------


def run_refine(image_path: str | os.PathLike, dem_path: str | os.PathLike,
               out: str | os.PathLike, *, sun_azimuth: float | None = None,
               sun_elevation: float | None = None,
               sun_vector: tuple[float, float, float] | None = None,
               view_vector: tuple[float, float, float] | None = None,
               model: str = "lunar-lambert", albedo_sigma: float = 21.0,
               lowpass_sigma: float = 21.0, delta: float = 0.001, gamma: float = 0.2,
               tau: float = 10.0, median: int = 15, spike_threshold: float = 4.0,
               start_sigma: float = 2.0, max_nan_fraction: float = 0.2,
               iterations: int = 60, tolerance: float = 1e-4,
               shadow_threshold: float = 0.05, cast_shadows: bool = True,
               border_taper: float = 8.0, shadow_weight: float = 0.005,
               albedo_out: str | os.PathLike | None = None,
               resolved: dict[str, Any] | None = None) -> RefineResult:
    """Refine the DEM at ``dem_path`` with the shading of ``image_path``; write ``out``.

    Writes ``out`` (float32 GeoTIFF, the DEM's grid, transform, CRS and tags plus the
    refine parameters, final energies and iteration count), ``<out>.json`` (the
    provenance sidecar with the energies per iteration) and, if asked, the albedo map,
    all in one transaction.  Options are those of ``demtool refine``.

    Raises
    ------
    InputError
        Missing/unreadable files, a NaN-only DEM, grids that cannot be matched.
    ParameterError
        Invalid parameters, no sun direction, a sun below the horizon.
    ProcessingError
        Too many DEM gaps, too few lit pixels.
    """
    import time

    import numpy as np

    from demtool import io
    from demtool.errors import InputError, ProcessingError
    from demtool.logs import get_logger
    from demtool.provenance import Provenance
    from demtool.refine import SfsParameters, refine_heights
    from demtool.refine.prepare import prepare_dem

    log = get_logger("refine")
    params = SfsParameters(delta=delta, gamma=gamma, tau=tau, lowpass_sigma=lowpass_sigma,
                           albedo_sigma=albedo_sigma, model=model, iterations=iterations,
                           tolerance=tolerance, shadow_threshold=shadow_threshold,
                           cast_shadows=cast_shadows, border_px=border_taper,
                           shadow_weight=shadow_weight)
    params.check()
    prov = Provenance("refine", resolved or {**params.as_dict(), "median": median,
                                             "spike_threshold": spike_threshold,
                                             "start_sigma": start_sigma,
                                             "max_nan_fraction": max_nan_fraction},
                      inputs=[image_path, dem_path])
    dem = io.read_raster(dem_path, what="DEM")
    image = io.read_image(image_path, what="image")
    illumination, sources = resolve_illumination(
        image, sun_azimuth=sun_azimuth, sun_elevation=sun_elevation, sun_vector=sun_vector,
        view_vector=view_vector)
    log.info("sun %s from %s; view %s from %s", np.round(illumination.sun, 4).tolist(),
             sources["sun"], np.round(illumination.view, 4).tolist(), sources["view"])
    values, note = image_on_dem_grid(image, dem)
    if note:
        log.warning("%s and %s are on different grids: %s", image.path, dem.path, note)
    spacing = dem.spacing
    if not all(np.isfinite(s) and s > 0 for s in spacing):
        raise InputError(f"{dem.path}: the DEM's transform has no usable pixel spacing "
                         f"({spacing})")
    started = time.perf_counter()
    try:
        prepared = prepare_dem(dem.data, median_size=median, spike_threshold=spike_threshold,
                               start_sigma=start_sigma, max_nan_fraction=max_nan_fraction)
    except ProcessingError as exc:
        raise ProcessingError(f"{dem.path}: {exc}") from None
    prepared_s = time.perf_counter() - started
    result = refine_heights(values, prepared.dem, spacing=spacing, illumination=illumination,
                            parameters=params, initial=prepared.initial)
    sfs_s = time.perf_counter() - started - prepared_s
    log.info("DEM preparation (gap filling, median) %.1f s, shape from shading %.1f s",
             prepared_s, sfs_s)
    shift = float(np.mean(result.dem, dtype=np.float64) - np.mean(prepared.dem,
                                                                  dtype=np.float64))
    change = result.dem.astype(np.float64) - prepared.dem
    summary = {
        "iterations": result.iterations, "converged": result.converged,
        "stop_reason": result.stop_reason,
        "energies_final": result.energies.as_dict(),
        "energies_initial": result.initial_energies.as_dict(),
        "energy_history": [e.total for e in result.history],
        "intensity_residual_rms": result.intensity_rms,
        "shadow_fraction": float(result.shadow.mean()),
        "dem_nan_fraction_filled": prepared.nan_fraction,
        "dem_spike_fraction": float(prepared.spikes.mean()),
        "mean_height_shift_m": shift,
        "rms_height_change_m": float(np.sqrt(np.mean(change**2))),
        "sun_vector_grid": illumination.sun.tolist(), "sun_source": sources["sun"],
        "view_vector_grid": illumination.view.tolist(), "view_source": sources["view"],
        "sun_elevation_deg": illumination.sun_elevation_deg,
        "sun_azimuth_deg": illumination.sun_azimuth_deg,
        "phase_deg": illumination.phase_deg,
        "spacing_m": list(spacing), "grid": list(dem.data.shape),
        "image_resampled": note,
        "timings_s": {"prepare_dem": round(prepared_s, 3), "sfs": round(sfs_s, 3)},
    }
    inherited = {k: v for k, v in dem.tags.items() if not k.startswith("demtool_")}
    tags = {**inherited, **prov.tags(
        frame=dem.tags.get("frame", "unknown"), units="m",
        content="heights refined by shape from shading",
        refine_energies=result.energies.as_dict(), refine_iterations=result.iterations,
        refine_converged=result.converged, sun_vector_grid=illumination.sun.tolist(),
        view_vector_grid=illumination.view.tolist(), reflectance_model=model)}
    outputs = [Path(out)]
    with io.output_transaction():
        io.write_raster(out, result.dem, transform=dem.transform, crs=dem.crs, tags=tags)
        if albedo_out is not None:
            io.write_raster(albedo_out, result.albedo, transform=dem.transform, crs=dem.crs,
                            tags=prov.tags(frame=dem.tags.get("frame", "unknown"),
                                           units=f"{image.tags.get('units', 'image unit')} "
                                                 "per unit reflectance",
                                           content=f"local albedo (Gaussian σ = "
                                                   f"{albedo_sigma:g} px) of the refined DEM"))
            outputs.append(Path(albedo_out))
        prov.write_sidecar(out, summary, outputs=outputs)
    log.info("wrote %s (%d iterations, mean height shift %.3g m, RMS change %.3g m)", out,
             result.iterations, shift, summary["rms_height_change_m"])
    return result


# --------------------------------------------------------------------------------------
# Command
# --------------------------------------------------------------------------------------


def _vector(ctx: click.Context, param: click.Parameter, value: str | None):
    if value is None:
        return None
    try:
        parts = tuple(float(v) for v in value.split(","))
    except ValueError:
        parts = ()
    if len(parts) != 3 or not all(abs(v) < float("inf") for v in parts):
        raise click.BadParameter(f"expected three numbers x,y,z, got {value!r}")
    if not any(parts):
        raise click.BadParameter("the vector has zero length")
    return parts


def _model(ctx: click.Context, param: click.Parameter, value: str) -> str:
    from demtool.reflectance import MODELS

    if value not in MODELS:
        raise click.BadParameter(f"unknown reflectance model {value!r}: should be one of "
                                 + ", ".join(MODELS))
    return value


def _median(ctx: click.Context, param: click.Parameter, value: int) -> int:
    if value > 1 and value % 2 == 0:
        raise click.BadParameter(f"the median window must be odd (or 0 to disable), got {value}")
    return value


_POSITIVE = ot.FloatRange(min=0.0, min_open=True)
_NON_NEGATIVE = ot.FloatRange(min=0.0)


@click.command(name="refine", help=STAGES["refine"] + """

Refines DEM with the shading of IMAGE (Grumpe & Wöhler 2014): minimises
EI + δ·Egrad + γ·Eint + τ·Edepth over slopes and heights, with a local albedo
(Gaussian σ_ρ) re-estimated as the DEM changes, shadows excluded, and the low-passed
heights tied to the input so the absolute heights stay.  Sun and view come from the
image's tags (written by `demtool synth`) unless given; directions are in the grid
frame (x image right, y image up, z toward the camera).  Defaults: the NavCam and
LRO NAC studies.""")
@input_file("image")
@input_file("dem")
@out_file("Refined DEM (GeoTIFF, same grid as DEM); a sidecar OUT.json is written beside it.")
@click.option("--sun-azimuth", type=ot.FLOAT, default=None,
              help="Sun azimuth, degrees clockwise from image up toward image right.")
@click.option("--sun-elevation", type=ot.FloatRange(min=-90.0, max=90.0), default=None,
              help="Sun elevation above the horizontal, degrees.")
@click.option("--sun-vector", callback=_vector, default=None, metavar="X,Y,Z",
              help="Direction toward the sun in the grid frame (instead of the angles).")
@click.option("--view", "view_vector", callback=_vector, default=None, metavar="X,Y,Z",
              help="Direction toward the camera in the grid frame [default: image tag "
                   "view_vector_grid, else nadir 0,0,1].")
@click.option("--model", default=DEFAULTS["model"], show_default=True, callback=_model,
              help="Reflectance model: lunar-lambert or lambert.")
@click.option("--albedo-sigma", type=_POSITIVE, default=DEFAULTS["albedo_sigma"],
              show_default=True, help="σ_ρ of the local albedo low-pass, pixels.")
@click.option("--lowpass-sigma", type=_POSITIVE, default=DEFAULTS["lowpass_sigma"],
              show_default=True, help="σ of the low-pass f in Egrad and Edepth, pixels.")
@click.option("--delta", type=_NON_NEGATIVE, default=DEFAULTS["delta"], show_default=True,
              help="Weight δ of Egrad (low-passed slopes tied to the input DEM's).")
@click.option("--gamma", type=_POSITIVE, default=DEFAULTS["gamma"], show_default=True,
              help="Weight γ of Eint (integrability of slopes and heights).")
@click.option("--tau", type=_POSITIVE, default=DEFAULTS["tau"], show_default=True,
              help="Weight τ of Edepth (low-passed heights tied to the input DEM's).")
@click.option("--median", type=ot.IntRange(min=0), default=DEFAULTS["median"],
              show_default=True, callback=_median,
              help="Median prefilter of the input DEM, odd window in pixels (0 = off).")
@click.option("--spike-threshold", type=_NON_NEGATIVE, default=DEFAULTS["spike_threshold"],
              show_default=True,
              help="Pixels farther from the median than this many robust standard "
                   "deviations are spikes and take the median in the anchor DEM that "
                   "Edepth and Egrad hold (0: the median everywhere).")
@click.option("--start-sigma", type=_NON_NEGATIVE, default=DEFAULTS["start_sigma"],
              show_default=True,
              help="The iterations start from the anchor DEM smoothed by a Gaussian of "
                   "this σ, pixels (0: from the anchor itself).")
@click.option("--max-nan-fraction", type=ot.FloatRange(min=0.0, max=1.0),
              default=DEFAULTS["max_nan_fraction"], show_default=True,
              help="Refuse a DEM with more NaN than this fraction (gaps below it are filled).")
@click.option("--iterations", type=ot.IntRange(min=1), default=DEFAULTS["iterations"],
              show_default=True, help="Maximum number of iterations.")
@click.option("--tolerance", type=_NON_NEGATIVE, default=DEFAULTS["tolerance"],
              show_default=True,
              help="Stop when an iteration lowers the energy by less than this fraction.")
@click.option("--shadow-threshold", type=ot.FloatRange(min=0.0, max=1.0, max_open=True),
              default=DEFAULTS["shadow_threshold"], show_default=True,
              help="Pixels darker than this fraction of the median image are shadow (0 = off).")
@click.option("--cast-shadows/--no-cast-shadows", default=True, show_default=True,
              help="Also exclude the cast shadows of the current DEM (ray march to the sun).")
@click.option("--border-taper", type=_NON_NEGATIVE, default=DEFAULTS["border_taper"],
              show_default=True,
              help="Width over which the intensity term fades out at the grid border, pixels.")
@click.option("--shadow-weight", type=_NON_NEGATIVE, default=DEFAULTS["shadow_weight"],
              show_default=True,
              help="Weight of the shadow-length term: across each shadow of the image the "
                   "height drop is the shadow's length × tan(sun elevation) (0 = off).")
@click.option("--albedo-out", type=click.Path(dir_okay=False), default=None,
              help="Also write the local albedo map (GeoTIFF, DEM grid).")
@click.pass_context
def command(ctx: click.Context, image: str, dem: str, out: str, sun_azimuth: float | None,
            sun_elevation: float | None, **kwargs: Any) -> None:
    """Thin wrapper: check option combinations, call :func:`run_refine`."""
    from demtool.options import resolved_params

    if (sun_azimuth is None) != (sun_elevation is None):
        raise click.BadParameter("give both --sun-azimuth and --sun-elevation",
                                 param_hint="'--sun-azimuth/--sun-elevation'")
    if kwargs["sun_vector"] is not None and sun_azimuth is not None:
        raise click.BadParameter("give either --sun-vector or --sun-azimuth/--sun-elevation",
                                 param_hint="'--sun-vector'")
    run_refine(image, dem, out, sun_azimuth=sun_azimuth, sun_elevation=sun_elevation,
               resolved=resolved_params(ctx), **kwargs)
