"""``demtool refine`` in tiles: shape from shading of each tile on its window, core kept.

Shape from shading is a global solve (the heights step is one DCT over the grid), but
what holds a pixel's height is local: Edepth and Egrad tie the Gaussian low-pass
(σ_f = 21 px) of the heights and slopes to the input DEM's, the local albedo is a
Gaussian of σ_ρ = 21 px, the DEM preparation a 15 px median and a Gaussian of
``start_sigma``, and the intensity weight fades over ``border_px`` at a grid's edge.
The influence of a window's edge on the solution decays within a few of these widths,
so each tile is refined on its core plus a margin of
``4 max(σ_f, σ_ρ) + median + 3 start_sigma + border_px`` (113 px with the defaults) and
only the core is kept (no blending: every output pixel comes from one tile, as for
``sgm``).  The window a tile is refined on is its outer window grown to a length the DCTs
are fast at, a multiple of 4 (:func:`solve_window`: 2161 → 2200 px for a 2048-px core):
the margins' few pixels otherwise make prime lengths, which cost a tile 5× the DCT time
per pixel and full-resolution Egrad filters (issue 47: tiled refine cost 2.0× the untiled
CPU on one worker).  This is the "equivalent that gives the untiled answer" of issue 15 rather
than a coarse global solve: the only quantity a coarse solve would give the tiles, the
low-passed heights, is already the input DEM's (τ = 10 holds it).

What the tiles share is computed once, in a first pass over the files that holds a strip
of rows at a time (:func:`global_pass`): the DEM's NaN fraction and magnitude checks,
the image's median (the scale of ``--shadow-threshold``: exact up to
:data:`MEDIAN_SAMPLE` pixels, of a regular sample beyond) and texture check, and the sun
and view directions (one pair for the whole DEM, as untiled).  On the body's map the
directions come from the sensor model over a decimated DEM; where they vary by more than
``--max-illumination-change`` each tile is refined per geometry window inside its own
window (:func:`demtool.refine.tiles.refine_tiles`, the untiled map route's tiles).

Agreement with the untiled run, the tolerance (issue 15: RMSE of the difference
< 0.02 GSD): 0.0034 GSD on a 384² hills scene in 4 tiles of 192 px
(tests/refine/test_tiled_refine.py), 0.0019 GSD on a 1024² relief in tiles of 512 px
(bench/scale.py), 0.011 GSD on the lunar map scene with margins of 48 px; the RMSE
against the truth is the untiled run's within 1 %.  What differs: the per-tile stopping
rule (each tile converges on its own energy), the despike threshold's grid-wide spread
(each tile's window), cast shadows longer than the margin, and gaps wider than the
margin (filled from the tile's window only).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from demtool.refine.tile_window import solve_window
from demtool.tiling import Tile, plan_tiles, read_window, wants_tiles

PROCESS_BYTES = 200 * 2**20  # a worker process with numpy, numba, scipy and rasterio (measured)
BYTES_PER_PIXEL = 250  # SfS arrays (measured ~210: 395 MB at 1024², 288 MB at 738²)
STRIP_ROWS = 256  # rows read at a time by the global pass
MEDIAN_SAMPLE = 4_000_000  # image pixels the median is computed from, at most
DECIMATED_CELLS = 1_000_000  # cells of the decimated DEM the sensor geometry is read on


def default_overlap(params: Any) -> int:
    """The margin of a refine tile, px (see the module docstring)."""
    return int(math.ceil(4 * max(params.lowpass_sigma, params.albedo_sigma) + params.median
                         + 3 * params.start_sigma + params.border_px))


@dataclass(frozen=True)
class GlobalPass:
    """What every tile shares, from one pass over the files (:func:`global_pass`)."""

    nan_fraction: float
    image_median: float
    image_sample: np.ndarray  # (h, w) the image on a regular lattice (texture check)
    image_valid: int  # finite pixels in the sample


def global_pass(image_path: str | os.PathLike, dem_path: str | os.PathLike,
                shape: tuple[int, int]) -> GlobalPass:
    """Read DEM and image strip by strip: NaN fraction, magnitude check, image median.

    Memory: one strip of :data:`STRIP_ROWS` rows of each file plus the median's sample.

    Raises
    ------
    InputError
        Heights beyond ±1e8 m (unmarked fill values) in the DEM.
    """
    from demtool.imaging.checks import check_magnitude

    height, width = shape
    step = max(1, math.ceil(math.sqrt(height * width / MEDIAN_SAMPLE)))
    missing = 0
    samples = []
    for r0 in range(0, height, STRIP_ROWS):
        window = (r0, min(r0 + STRIP_ROWS, height), 0, width)
        dem = read_window(dem_path, window, what="DEM")
        check_magnitude(dem, dem_path, what="DEM")
        missing += int(np.count_nonzero(~np.isfinite(dem)))
        image = read_window(image_path, window, what="image")
        first = (-r0) % step  # rows r0 + first, … on the global lattice of step
        samples.append(image[first::step, ::step])
    sample = np.vstack(samples)
    finite = sample[np.isfinite(sample)]
    median = float(np.median(finite)) if finite.size else 0.0
    return GlobalPass(missing / (height * width), median, sample, int(finite.size))


@dataclass(frozen=True)
class RefineTileJob:
    """Refine one tile of a DEM (picklable: paths and plain values only).

    ``sensor_path`` set: the map route whose directions vary over the DEM; the tile
    takes them from the sensor model over its own window, per geometry window.
    """

    image_path: str
    dem_path: str
    spacing: tuple[float, float]
    sun: tuple[float, float, float]
    view: tuple[float, float, float]
    image_median: float
    options: tuple[tuple[str, Any], ...]  # RefineParams fields (execution ones excluded)
    sensor_path: str | None = None
    transform: tuple[float, ...] | None = None  # the DEM's (map route per geometry)
    crs_wkt: str | None = None
    grid: tuple[int, int] | None = None  # the DEM's (rows, columns): windows grow inside it
    stage: str = "refine"
    # local --workers: tiles on threads (demtool.tiling.local_threads; audited: nogil
    # kernels, scipy.fft on the thread's numba thread count, read-only cached transfers)
    thread_safe: ClassVar[bool] = True
    bands: tuple[str, ...] = ("dem", "albedo")
    preload: tuple[str, ...] = ("demtool.refine",)  # imported once by the workers' forkserver

    def params(self):
        from demtool.refine.params import RefineParams

        return RefineParams(**dict(self.options))

    def compute(self, tile: Tile, threads: int) -> tuple[np.ndarray, dict[str, Any]]:
        """The tile's core of refined heights and albedo, on the calling thread's numba
        thread count (a worker's share: :func:`demtool.tiling.tasks.compute_tile` sets it
        for the tile and restores it after)."""
        from demtool.errors import ProcessingError
        from demtool.refine import make_illumination, refine_heights
        from demtool.refine.prepare import prepare_dem

        params = self.params()
        window = tile.outer if self.grid is None else solve_window(tile.outer, self.grid)
        dem = read_window(self.dem_path, window, what="DEM")
        image = read_window(self.image_path, window, what="image")
        rows = slice(tile.core[0] - window[0], tile.core[1] - window[0])
        cols = slice(tile.core[2] - window[2], tile.core[3] - window[2])
        out = np.full((2, *tile.core_shape), np.nan, dtype=np.float32)
        if not np.isfinite(dem).any():
            return out, {"skipped": "no height in the tile's window", "pixels": 0}
        prepared = prepare_dem(dem, median_size=params.median,
                               spike_threshold=params.spike_threshold,
                               start_sigma=params.start_sigma, max_nan_fraction=1.0)
        info: dict[str, Any] = {}
        try:
            windows = self._geometry_windows(window, prepared.dem, params)
            if windows is None:
                result = refine_heights(
                    image, prepared.dem, spacing=self.spacing,
                    illumination=make_illumination(self.sun, self.view),
                    parameters=params.sfs(), initial=prepared.initial,
                    image_median=self.image_median)
                refined, albedo, results = result.dem, result.albedo, [result]
            else:
                from demtool.refine.tiles import refine_tiles

                refined, results = refine_tiles(
                    image, prepared.dem, spacing=self.spacing, windows=windows[0],
                    illuminations=windows[1], parameters=params.sfs(),
                    initial=prepared.initial, image_median=self.image_median)
                albedo = np.full(refined.shape, np.nan, np.float32)
                info["geometry_windows"] = len(windows[0])
        except ProcessingError as exc:  # a window SfS cannot use (under 5 % of it lit)
            out[0] = prepared.initial[rows, cols]
            return out, {"skipped": str(exc).splitlines()[0][:200], **_changes(
                out[0], prepared.dem[rows, cols])}
        out[0] = refined[rows, cols]
        out[1] = albedo[rows, cols]
        return out, {**info, "iterations": max(r.iterations for r in results),
                     "converged": all(r.converged for r in results),
                     "energy_final": float(np.mean([r.energies.total for r in results])),
                     "energy_initial": float(np.mean([r.initial_energies.total
                                                      for r in results])),
                     "intensity_rms": float(np.mean([r.intensity_rms for r in results])),
                     "shadow_pixels": int(sum(r.shadow[rows, cols].sum() for r in results
                                              if r.shadow.shape == refined.shape)),
                     **_changes(out[0], prepared.dem[rows, cols])}

    def _geometry_windows(self, window: tuple[int, int, int, int], dem: np.ndarray,
                          params: Any):
        """Map route, directions varying: (windows, illuminations) inside the tile's window
        (``window``: its bounds in the DEM, ``dem``: its heights)."""
        if self.sensor_path is None:
            return None
        from affine import Affine
        from rasterio.crs import CRS

        from demtool import io as dio
        from demtool.logs import get_logger
        from demtool.refine.inputs import map_illumination
        from demtool.sensors import read_sensor

        r0, _, c0, _ = window
        transform = Affine(*self.transform[:6]) @ Affine.translation(c0, r0)
        window = dio.Raster(data=dem, transform=transform, crs=CRS.from_wkt(self.crs_wkt),
                            tags={}, path=Path(self.dem_path))
        windows, pairs, _ = map_illumination(read_sensor(self.sensor_path), window, params,
                                             get_logger(__name__))
        return None if windows is None else (windows, pairs)

    def memory_bytes(self, tile: Tile) -> int:
        """The process, and the solver's arrays over the tile's window."""
        r0, r1, c0, c1 = tile.outer if self.grid is None else solve_window(tile.outer,
                                                                            self.grid)
        height, width = r1 - r0, c1 - c0
        return PROCESS_BYTES + height * width * BYTES_PER_PIXEL


def _changes(refined: np.ndarray, anchor: np.ndarray) -> dict[str, Any]:
    change = refined.astype(np.float64) - anchor
    return {"pixels": int(change.size), "change_sum": float(change.sum()),
            "change_sum_sq": float(np.sum(change**2))}


def _summary(infos: list[dict[str, Any]]) -> dict[str, Any]:
    pixels = sum(int(i.get("pixels", 0)) for i in infos) or 1
    iterations = [i.get("iterations") for i in infos]
    skipped = [{"tile": i.get("index"), "reason": i["skipped"]} for i in infos
               if i.get("skipped")]
    return {"tile_iterations": iterations,
            "tiles_converged": sum(bool(i.get("converged")) for i in infos),
            "tiles_not_refined": skipped,
            "energy_final_tile_mean": float(np.mean([i["energy_final"] for i in infos
                                                     if "energy_final" in i] or [np.nan])),
            "shadow_fraction": sum(int(i.get("shadow_pixels", 0)) for i in infos) / pixels,
            "mean_height_shift_m": sum(float(i.get("change_sum", 0)) for i in infos) / pixels,
            "rms_height_change_m": math.sqrt(sum(float(i.get("change_sum_sq", 0))
                                                 for i in infos) / pixels)}


def read_decimated(path: str | os.PathLike, shape: tuple[int, int], cells: int, *,
                   what: str = "DEM"):
    """The raster decimated (nearest) to at most ``cells`` cells, as a demtool.io.Raster
    whose transform is scaled to match (the sensor geometry's coarse DEM)."""
    from affine import Affine
    from rasterio.errors import NotGeoreferencedWarning

    from demtool import io as dio
    from demtool.io.quiet import ignoring

    height, width = shape
    factor = max(1, math.ceil(math.sqrt(height * width / cells)))
    rows, cols = max(1, height // factor), max(1, width // factor)
    with dio._open_dataset(Path(path), what) as dataset, ignoring(NotGeoreferencedWarning):
        data = dataset.read([1], out_shape=(1, rows, cols), masked=True)
        values = dio.physical_values(data, [dataset.scales[0]], [dataset.offsets[0]])[0]
        transform = dataset.transform @ Affine.scale(width / cols, height / rows)
        return dio.Raster(data=values, transform=transform, crs=dataset.crs,
                          tags=dict(dataset.tags()), path=Path(path))


def _same_grid(image_info, dem_info) -> bool:
    from demtool.refine.inputs import _is_unit_pixel_transform

    if (image_info.height, image_info.width) != (dem_info.height, dem_info.width):
        return False
    if image_info.transform == dem_info.transform:
        return image_info.crs == dem_info.crs or image_info.crs is None
    return (_is_unit_pixel_transform(image_info.transform) and image_info.crs is None
            and dem_info.crs is None)


def _map_geometry(image_info, dem_info, shape, params, log, albedo_out):
    """Map route: the sun and view from the orthoimage's sensor model (one pair, or the
    sensor path for per-tile geometry), from a decimated DEM."""
    from demtool.errors import InputError, ParameterError
    from demtool.mapproject.core import sensor_body
    from demtool.mapproject.hashes import check_hashes
    from demtool.mapproject.surface import require_same_body
    from demtool.refine.inputs import SENSOR_TAG, _sensor_path, map_illumination
    from demtool.sensors import read_sensor

    path = _sensor_path(image_info, None)
    if path is None:
        raise InputError(f"{image_info.path}: a map image without a sensor model (no "
                         f"{SENSOR_TAG} tag; a mosaic?) has no single sun and view geometry: "
                         "map-project the raw image (demtool mapproject), or give the sun")
    if not path.is_file():
        raise InputError(f"{image_info.path}: its sensor model {path} (tag {SENSOR_TAG}) is "
                         "not found")
    check_hashes(image_info.path, image_info.tags, log=log)
    sensor = read_sensor(path)
    require_same_body(dem_info.path, dem_info.crs, sensor_body(sensor), path, "a DEM")
    coarse = read_decimated(dem_info.path, shape, DECIMATED_CELLS)
    windows, pairs, report = map_illumination(sensor, coarse, params, log)
    report["sensor"] = str(path)
    if windows is None:
        return pairs[0], None, report
    if albedo_out is not None:
        raise ParameterError("--albedo-out: not written when the DEM is refined per tile "
                             "(the sun or view varies by more than --max-illumination-change "
                             "over it)")
    mean_sun = np.mean([p.sun for p in pairs], axis=0)
    mean_view = np.mean([p.view for p in pairs], axis=0)
    from demtool.refine import make_illumination

    report.pop("tiles", None)
    return make_illumination(mean_sun, mean_view), str(path), report


def refine_tiled(run: Any, image_path: str | os.PathLike, dem_path: str | os.PathLike,
                 out: str | os.PathLike, params: Any, shape: tuple[int, int], *,
                 sun_azimuth: float | None = None, sun_elevation: float | None = None,
                 sun_vector=None, view_vector=None,
                 albedo_out: str | os.PathLike | None = None,
                 sensor_path: str | os.PathLike | None = None):
    """The tiled ``demtool refine`` (called by :func:`demtool.refine.run.run_refine`).

    The image must be on the DEM's grid (same size; an image-frame pair, or an orthoimage
    of ``demtool mapproject --grid-like DEM`` on a projected map): nothing is resampled.

    Returns
    -------
    demtool.tiling.jobs.TiledResult

    Raises
    ------
    InputError
        Image and DEM on different grids, a DEM in degrees, a NaN-only DEM, a mosaic
        without a sun, unmarked fill values.
    ParameterError
        ``--sensor`` (a raw image: map-project it first), no sun, ``--albedo-out`` with
        per-tile geometry.
    ProcessingError
        More gaps than ``--max-nan-fraction``.
    """
    from demtool import io as dio
    from demtool.errors import InputError, ParameterError, ProcessingError
    from demtool.imaging.checks import check_texture
    from demtool.refine.inputs import resolve_illumination
    from demtool.stagerun import check_same_frame
    from demtool.tiling.jobs import TiledOutput, run_tiled

    log = run.log
    height, width = shape
    dem_info = dio.raster_info(dem_path, what="DEM")
    image_info = dio.raster_info(image_path, what="image")
    sun_given = sun_vector is not None or sun_azimuth is not None
    map_report: dict[str, Any] = {}
    geometry_sensor = None
    if dem_info.crs is not None:
        from demtool.maps import to_pyproj_crs

        if to_pyproj_crs(dem_info.crs).is_geographic:
            raise InputError(f"{dem_path}: a DEM in degrees is refined in tiles only once on "
                             "a projected map: reproject it (or refine it untiled, "
                             "--tile-size 0)")
    if sensor_path is not None:
        if dem_info.crs is None:
            raise InputError(f"{dem_path}: --sensor needs a DEM on the body's map (a "
                             "planetary CRS); this DEM is in an image frame")
        raise ParameterError("--sensor: in tiles, map-project the raw image onto the DEM "
                             "first (demtool mapproject IMAGE SENSOR --grid-like DEM) and "
                             "refine the orthoimage")
    if not _same_grid(image_info, dem_info):
        raise InputError(f"{image_path}: in tiles the image must be on the DEM's grid "
                         f"({image_info.width}×{image_info.height} px, DEM {dem_path} "
                         f"{width}×{height}); resample it (demtool mapproject --grid-like "
                         "DEM) or refine untiled (--tile-size 0)")
    if dem_info.crs is None:
        check_same_frame(image_info, dem_info, "give the image the DEM was computed for",
                         "the DEM")
    if dem_info.crs is not None and not sun_given:
        illumination, geometry_sensor, map_report = _map_geometry(
            image_info, dem_info, shape, params, log, albedo_out)
        sources = {"sun": f"sensor model {map_report['sensor']}",
                   "view": f"sensor model {map_report['sensor']}"}
    else:
        illumination, sources = resolve_illumination(
            image_info, sun_azimuth=sun_azimuth, sun_elevation=sun_elevation,
            sun_vector=sun_vector, view_vector=view_vector)
    spacing = (abs(dem_info.transform.a), abs(dem_info.transform.e))
    if not all(np.isfinite(s) and s > 0 for s in spacing):
        raise InputError(f"{dem_path}: the DEM's transform has no usable pixel spacing "
                         f"({spacing})")
    shared = global_pass(image_path, dem_path, shape)
    if shared.nan_fraction >= 1.0:
        raise InputError(f"{dem_path}: DEM contains no valid (finite) pixel")
    if shared.nan_fraction > params.max_nan_fraction:
        raise ProcessingError(
            f"{dem_path}: {100 * shared.nan_fraction:.1f}% of the DEM is NaN, more than the "
            f"allowed {100 * params.max_nan_fraction:.1f}% (--max-nan-fraction); fill or "
            "crop the DEM first")
    if not shared.image_valid:
        raise InputError(f"{image_path}: image contains no valid (finite) pixel")
    check_texture(shared.image_sample, image_path, what="image")
    log.info("sun %s from %s; view %s from %s; image median %.4g",
             np.round(illumination.sun, 4).tolist(), sources["sun"],
             np.round(illumination.view, 4).tolist(), sources["view"], shared.image_median)
    tile_size = wants_tiles(height, width, params)
    overlap = default_overlap(params) if params.tile_overlap is None else params.tile_overlap
    tiling = plan_tiles(height, width, tile_size, overlap=overlap)
    options = {k: v for k, v in params.as_dict().items()
               if k not in ("workers", "tile_size", "tile_overlap", "scheduler", "dry_run")}
    job = RefineTileJob(
        str(image_path), str(dem_path), spacing, tuple(map(float, illumination.sun)),
        tuple(map(float, illumination.view)), shared.image_median,
        tuple(sorted(options.items())), sensor_path=geometry_sensor,
        transform=tuple(dem_info.transform)[:6] if geometry_sensor else None,
        crs_wkt=dem_info.crs.to_wkt() if geometry_sensor else None, grid=(height, width))
    frame = dem_info.tags.get("frame", "unknown")
    inherited = {k: v for k, v in dem_info.tags.items() if not k.startswith("demtool_")}
    tags = {**inherited, **run.provenance.tags(
        frame=frame, units="m", content="heights refined by shape from shading",
        sun_vector_grid=illumination.sun.tolist(), view_vector_grid=illumination.view.tolist(),
        reflectance_model=params.model, tile_size=tile_size,
        tile_margins=list(tiling.margins))}
    outputs = [TiledOutput(out, 0, tags, "height")]
    if albedo_out is not None:
        outputs.append(TiledOutput(albedo_out, 1, run.provenance.tags(
            frame=frame, units=f"{image_info.tags.get('units', 'image unit')} per unit "
                               "reflectance",
            content=f"local albedo (Gaussian σ = {params.albedo_sigma:g} px) of the refined "
                    "DEM"), "albedo"))
    log.info("refining %s with %s in tiles: %d×%d px", dem_path, image_path, width, height)

    def summarize(infos: list[dict[str, Any]]) -> dict[str, Any]:
        tiles = _summary(infos)
        for skipped in tiles["tiles_not_refined"]:
            log.warning("%s kept its start surface: %s",
                        tiling.tiles[skipped["tile"]].describe(), skipped["reason"])
        summary = {**tiles, "dem_nan_fraction_filled": shared.nan_fraction,
                   "image_median": shared.image_median,
                   "sun_vector_grid": illumination.sun.tolist(), "sun_source": sources["sun"],
                   "view_vector_grid": illumination.view.tolist(),
                   "view_source": sources["view"],
                   "sun_elevation_deg": illumination.sun_elevation_deg,
                   "sun_azimuth_deg": illumination.sun_azimuth_deg,
                   "phase_deg": illumination.phase_deg, "spacing_m": list(spacing),
                   "grid": [height, width]}
        if dem_info.crs is not None:
            summary["map_route"] = {**map_report, "per_tile_geometry": bool(geometry_sensor)}
        return summary

    inputs = [image_path, dem_path] + ([geometry_sensor] if geometry_sensor else [])
    return run_tiled(run, job, tiling, outputs, inputs=inputs,
                     parameters={**params.as_dict(), "sun": job.sun, "view": job.view,
                                 "image_median": shared.image_median},
                     transform=dem_info.transform, crs=dem_info.crs,
                     workers=params.workers, scheduler=params.scheduler,
                     dry_run=params.dry_run, summarize=summarize)
