"""Runner of ``demtool compare``: measure a DEM against a reference."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from demtool.compare.report import (
    DIFFERENCE,
    FIGURES,
    HTML,
    REPORT,
    _check_profiles,
    assemble_report,
    make_figures,
    write_report,
)
from demtool.stagerun import StageRun, check_same_frame, sidecar_path

if TYPE_CHECKING:
    from demtool.compare.params import CompareParams


def _read_dem(path: str | os.PathLike, what: str):
    import dataclasses

    import numpy as np

    from demtool import io as dio
    from demtool.sensors.isis_map import refuse_image_as_dem

    refuse_image_as_dem(path, what)  # an ISIS image cube holds I/F, not metres
    raster = dio.read_raster(path, what=what)
    from demtool.compare.planetary import radius_offset

    offset = radius_offset(path, raster.crs, raster.data, what)
    if offset:
        raster = dataclasses.replace(raster, data=(raster.data - offset).astype(np.float32))
    return raster


def _read_dems(dem_path: str | os.PathLike, reference_path: str | os.PathLike):
    """The DEM and the reference (:func:`_read_dem`), read at once on two threads when
    this work may use two (GDAL decodes with the GIL released); an error names the first
    file that fails, as two reads in turn would."""
    import warnings

    from rasterio.errors import NotGeoreferencedWarning

    import demtool.compare.planetary
    import demtool.io
    import demtool.maps
    import demtool.sensors.isis_map  # noqa: F401 - imported here, not by two threads at once
    from demtool.compare.threads import both
    from demtool.tiling.tasks import usable_threads

    # each read sets and restores its warning filters; with two at once they could
    # restore each other's, so the filter they set also holds around both
    # (demtool.io.read_raster_pair)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        return both(lambda: _read_dem(dem_path, "DEM"),
                    lambda: _read_dem(reference_path, "reference DEM"),
                    on=usable_threads() >= 2)


def _grid_of(raster):
    from demtool.compare.grids import Grid

    return Grid(shape=raster.data.shape, transform=raster.transform, crs=raster.crs)


def _onto(raster, grid, what: str):
    from demtool.compare.grids import resample_to_grid
    from demtool.errors import ProcessingError

    try:
        return resample_to_grid(raster.data, _grid_of(raster), grid)
    except ProcessingError as exc:
        raise ProcessingError(f"{raster.path}: {what}: {exc}") from None


def _read_mask_raster(path: str | os.PathLike, dem, reference):
    """The --mask raster, which must lie on the DEM's or the reference's grid and frame."""
    from demtool import io as dio
    from demtool.errors import InputError
    from demtool.imaging.checks import check_same_grid

    raster = dio.read_raster(path, what="mask", allow_all_nan=False)
    try:
        check_same_grid(reference, raster, reference_what="reference DEM")
    except InputError:
        check_same_grid(dem, raster)  # neither grid: say how it differs from the DEM's
    return raster


def _read_mask(raster, grid):
    """Mask raster (non-zero = use) resampled onto the comparison grid."""
    import numpy as np

    from demtool.errors import InputError

    values = _onto(raster, grid, "mask")
    with np.errstate(invalid="ignore"):
        mask = np.isfinite(values) & (np.abs(values) > 0.5)
    if not mask.any():
        raise InputError(f"{raster.path}: mask selects no pixel of the comparison grid")
    return mask


def _windowed(run, dem_path, reference_path, out_dir, params, mask_path, also):
    """The windowed comparison's report when ``--tile-size`` or the memory budget asks for
    it (:func:`demtool.compare.run_windowed.windowed_tile_size`), else None."""
    from demtool import io as dio
    from demtool.compare.planetary import check_bodies, metric_grid
    from demtool.compare.run_windowed import (
        _grid,
        _Header,
        compare_windowed,
        windowed_tile_size,
    )
    from demtool.sensors.isis_map import refuse_image_as_dem

    for path, what in [(dem_path, "DEM"), (reference_path, "reference DEM")] + [
            (path, "DEM (--also)") for path in also]:
        refuse_image_as_dem(path, what)  # an ISIS image cube holds I/F, not metres
    infos = {"dem": dio.raster_info(dem_path, what="DEM"),
             "reference": dio.raster_info(reference_path, what="reference DEM")}
    target, degrees = metric_grid(_grid(infos[params.grid]))
    tile_size = windowed_tile_size(target.shape, params)
    if not tile_size:
        return None
    infos[str(dem_path)] = infos["dem"]
    for path in also:
        infos[str(path)] = dio.raster_info(path, what="DEM (--also)")
    for path in (dem_path, *also):
        check_same_frame(_Header(infos[str(path)]), _Header(infos["reference"]),
                         "compare rasters of one frame (e.g. a target-frame DEM with "
                         "truth_dem_target.tif)")
    body_warnings = check_bodies([(i.path, i.crs) for i in (infos["reference"], infos["dem"],
                                                            *(infos[str(p)] for p in also))])
    return compare_windowed(run, dem_path, reference_path, out_dir, params, tile_size,
                            infos=infos, target=target, degrees=degrees, mask_path=mask_path,
                            also=also, body_warnings=body_warnings)


def _import_matplotlib_ahead() -> None:
    """Import matplotlib's figure and Agg canvas (its font list, the axes, the mathtext
    parser: ~0.3 s on one core) on a side thread, while the rasters are read and
    compared, instead of at the first figure.

    The package itself is imported here first: its ``__init__`` reads rcParams inside
    ``warnings.catch_warnings``, which is not thread-safe (Python < 3.14) — beside this
    thread's own ``catch_warnings`` (the rasters' reads) one of the two would put back a
    filter list the other changed."""
    import importlib

    import matplotlib  # noqa: F401 - see above

    from demtool.tiling.side_threads import start_side_thread

    def load() -> None:
        for module in ("matplotlib.figure", "matplotlib.backends.backend_agg"):
            importlib.import_module(module)

    start_side_thread(load, "demtool-matplotlib-ahead")


def run_compare(dem_path: str | os.PathLike, reference_path: str | os.PathLike,
                out_dir: str | os.PathLike, params: CompareParams | None = None, *,
                mask_path: str | os.PathLike | None = None, also: Sequence[str] = (),
                resolved: dict[str, Any] | None = None) -> dict[str, Any]:
    """Compare DEM (and ``also`` DEMs) with REFERENCE; write the report folder.

    Reads the rasters, puts them on one grid (the reference's, or the DEM's with
    ``params.grid="dem"``; reprojected when both have a different CRS), calls
    :func:`demtool.compare.compare_dems` for each DEM, and writes into ``out_dir`` —
    in one output transaction — ``report.json`` (figures, transform, the ``also`` DEMs,
    ``at_reference_resolution`` when the reference's posts are at least twice the DEM's
    cells: the DEM block-averaged over them, beside the comparison grid's figures, see
    :func:`demtool.compare.coarse.compare_at_reference_resolution`, and the provenance
    under ``provenance``), ``difference.tif`` (aligned DEM −
    reference, with provenance tags), the PNG figures and the standard provenance
    sidecar ``report.json.json``.

    Returns
    -------
    dict
        The report (as written to ``report.json``).
    """
    import numpy as np

    from demtool import io as dio
    from demtool.compare import compare_dems
    from demtool.compare import plots as figure_maker
    from demtool.compare.params import CompareParams
    from demtool.compare.threads import Side, both, threaded
    from demtool.imaging.checks import check_magnitude
    from demtool.tiling.tasks import usable_threads

    params = params or CompareParams()
    from demtool.compare.run_altimetry import is_shot_table, run_compare_shots

    if is_shot_table(reference_path):  # laser altimetry shots (LOLA, MOLA): points
        return run_compare_shots(dem_path, reference_path, out_dir, params,
                                 resolved=resolved)
    run = StageRun("compare", params, resolved=resolved,
                   inputs={"DEM": dem_path, "REFERENCE": reference_path, "--also": also,
                           "--mask": mask_path}, folders={"--out": out_dir},
                   outputs={"--out": [Path(out_dir) / n for n in
                                      (REPORT, DIFFERENCE, *FIGURES, HTML)],
                            "sidecar": sidecar_path(Path(out_dir) / REPORT)})
    log, provenance = run.log, run.provenance
    grid, align, label = params.grid, params.align, params.label
    out = Path(out_dir)
    for path in run.input_paths():
        dio.require_file(path, "input file")
    from demtool.compare.frames import check_inputs

    check_inputs(dem_path, reference_path, also)  # heights, one frame (one line if not)
    if params.plots:
        _import_matplotlib_ahead()
    windowed = _windowed(run, dem_path, reference_path, out_dir, params, mask_path, also)
    if windowed is not None:
        return windowed
    with run.phase("read"):  # reading, and the rasters put on the comparison grid
        dem, reference = _read_dems(dem_path, reference_path)
        extra = [_read_dem(path, "DEM (--also)") for path in also]
        two = usable_threads() >= 2
        both(lambda: check_magnitude(dem.data, dem.path, what="DEM"),
             lambda: check_magnitude(reference.data, reference.path, what="reference DEM"),
             on=two)
        for raster in extra:
            check_magnitude(raster.data, raster.path, what="DEM (--also)")
        mask_raster = _read_mask_raster(mask_path, dem, reference) if mask_path else None
        for raster in (dem, *extra):
            check_same_frame(raster, reference, "compare rasters of one frame (e.g. a "
                             "target-frame DEM with truth_dem_target.tif)")
        from demtool.compare.planetary import check_bodies, metric_grid

        body_warnings = check_bodies([(r.path, r.crs) for r in (reference, dem, *extra)])
        if grid == "reference":
            target = _grid_of(reference)
            reference_values, dem_values = both(
                lambda: reference.data.astype(np.float64),
                lambda: _onto(dem, target, "DEM"), on=two)
            frame = reference.tags.get("frame")
        else:
            target = _grid_of(dem)
            dem_values, reference_values = both(
                lambda: dem.data.astype(np.float64),
                lambda: _onto(reference, target, "reference DEM"), on=two)
            frame = dem.tags.get("frame")
        target, degrees = metric_grid(target)  # a degree grid is measured in metres
        if degrees is not None:
            reference_values = _onto(reference, target, "reference DEM")
            dem_values = _onto(dem, target, "DEM")
        extra_values = [_onto(raster, target, "DEM (--also)") for raster in extra]
        mask = _read_mask(mask_raster, target) if mask_raster is not None else None
    sx, sy = target.spacing
    lines = [tuple(float(v) for v in line) for line in params.profiles] or \
        figure_maker.default_profiles(target.shape)
    _check_profiles(lines, target.shape)

    label = label or Path(dem_path).stem
    labels = [Path(p).stem for p in also]
    log.info("%s vs %s on the %s grid (%d x %d, %.4g x %.4g m), alignment %s", dem_path,
             reference_path, grid, target.shape[1], target.shape[0], sx, sy, align)
    comparisons = []
    with run.phase("compare"):  # alignment, statistics, spectrum
        for name, values in ((label, dem_values), *zip(labels, extra_values, strict=True)):
            comparison = compare_dems(values, reference_values, spacing=(sx, sy),
                                      align=align, mask=mask, slope_bins=params.slope_bins,
                                      icp_scale=params.icp_scale, seed=params.seed)
            comparisons.append((name, comparison))
    report = assemble_report([(name, c.report) for name, c in comparisons],
                             dem_path=dem_path, reference_path=reference_path, also=also,
                             grid=grid, target=target, frame=frame, degrees=degrees,
                             body_warnings=body_warnings, lines=lines, log=log,
                             dem_grids=[_grid_of(r) for r in (dem, *extra)],
                             reference_grid=_grid_of(reference))
    from demtool.compare.coarse import compare_at_reference_resolution

    dem_cells = dem.data.astype(np.float64)
    if mask_raster is not None:
        dem_cells = np.where(_read_mask(mask_raster, _grid_of(dem)), dem_cells, np.nan)
    with run.phase("coarse"):
        coarse = compare_at_reference_resolution(
            dem_cells, _grid_of(dem), reference.data, _grid_of(reference), align=align,
            slope_bins=params.slope_bins, seed=params.seed)
    if coarse is not None:
        report["at_reference_resolution"] = coarse
        log.info("at the reference's resolution (%s): %s", coarse["what"],
                 coarse.get("error") or f"median {coarse['median']:.3f} m, NMAD "
                 f"{coarse['nmad']:.3f} m, RMSE {coarse['rmse']:.3f} m over "
                 f"{coarse['count']} posts")
    main = comparisons[0][1]

    def write_difference() -> None:
        dio.write_raster(out / DIFFERENCE, main.difference, transform=target.transform,
                         crs=target.crs,
                         tags=provenance.tags(frame=frame or "unknown", label=label,
                                              quantity="aligned DEM - reference (m)",
                                              shift=report["shift"]))

    with run.transaction():
        # the difference raster is compressed and written (GDAL, outside the GIL) on a
        # side thread while this one draws the figures (matplotlib, mostly under it);
        # "write_difference" is what is left of the write once the figures are drawn
        with Side(params.plots and threaded(main.difference.size)) as side:
            written = side.later(write_difference)
            with run.phase("figures"):
                figures = make_figures(comparisons, reference_values, lines, (sx, sy),
                                       label) if params.plots else {}
            with run.phase("write_difference"):
                written.result()
        write_report(provenance, out, report, figures, html=params.html,
                     timings=run.timings)
    return report
