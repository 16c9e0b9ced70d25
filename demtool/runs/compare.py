"""Runner of ``demtool compare``: measure a DEM against a reference."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from demtool.runs import StageRun, check_same_frame, sidecar_path

if TYPE_CHECKING:
    from demtool.compare.params import CompareParams

REPORT = "report.json"
DIFFERENCE = "difference.tif"
FIGURES = ("difference.png", "dems.png", "profiles.png", "histogram.png", "completeness.png",
           "coherence.png")


def _read_dem(path: str | os.PathLike, what: str):
    from demtool import io as dio

    return dio.read_raster(path, what=what)


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
    from demtool.checks import check_same_grid
    from demtool.errors import InputError

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


def _check_profiles(profiles: Sequence[Sequence[float]], shape: tuple[int, int]) -> None:
    from demtool.errors import ParameterError

    rows, cols = shape
    for line in profiles:
        x0, y0, x1, y1 = line
        inside = all(-0.5 <= x <= cols - 0.5 for x in (x0, x1)) and \
            all(-0.5 <= y <= rows - 0.5 for y in (y0, y1))
        if not inside:
            raise ParameterError(f"--profile {','.join(f'{v:g}' for v in line)} leaves the "
                                 f"comparison grid (x 0..{cols - 1}, y 0..{rows - 1} px)")
        if x0 == x1 and y0 == y1:
            raise ParameterError(f"--profile {','.join(f'{v:g}' for v in line)} has zero "
                                 "length")


def _headline(report: dict[str, Any]) -> dict[str, Any]:
    keys = ("count", "completeness", "mean", "median", "std", "rmse", "nmad", "le90", "min",
            "max")
    resolution = report.get("effective_resolution") or {}
    return {**{k: report[k] for k in keys}, "shift": report["shift"],
            "shift_uncertainty": report["shift_uncertainty"],
            "wavelength_m": resolution.get("wavelength_m")}


def format_table(rows: Sequence[tuple[str, dict[str, Any]]]) -> str:
    """Short plain-text table: one row per compared DEM."""
    def fmt(value: Any, spec: str) -> str:
        return "—" if value is None else format(value, spec)

    header = (f"{'DEM':<20} {'n':>9} {'compl %':>8} {'mean':>8} {'RMSE':>8} {'NMAD':>8} "
              f"{'LE90':>8} {'dx px':>7} {'dy px':>7} {'dz m':>8} {'λ coh m':>8}")
    lines = [header]
    for label, r in rows:
        resolution = r.get("effective_resolution") or {}
        lines.append(
            f"{label[:20]:<20} {r['count']:>9d} {fmt(r['completeness'], '8.2f')} "
            f"{fmt(r['mean'], '8.3f')} {fmt(r['rmse'], '8.3f')} {fmt(r['nmad'], '8.3f')} "
            f"{fmt(r['le90'], '8.3f')} {r['shift']['dx_px']:7.3f} {r['shift']['dy_px']:7.3f} "
            f"{r['shift']['dz']:8.3f} {fmt(resolution.get('wavelength_m'), '8.2f')}")
    return "\n".join(lines)


def assemble_report(reports: Sequence[tuple[str, dict[str, Any]]], *, dem_path, reference_path,
                    also: Sequence[str], grid: str, target: Any, frame: str | None,
                    degrees: Any, body_warnings: Sequence[str], lines, log) -> dict[str, Any]:
    """The report of one comparison run from each DEM's own report (main DEM first, then
    the ``also`` DEMs), logged as the table and the warnings; in memory and in windows."""
    label, main = reports[0]
    report: dict[str, Any] = {"label": label, "dem": str(dem_path),
                              "reference": str(reference_path), **main}
    report["grid"] = {**main["grid"], "on": grid,
                      "crs": target.crs.to_string() if target.crs else None,
                      "transform": list(target.transform)[:6], "frame": frame,
                      "from_geographic": degrees}
    report["warnings"] = [*body_warnings, *report["warnings"]]
    report["profiles_px"] = [list(line) for line in lines]
    report["also"] = [{"label": name, "dem": str(path), **_headline(r),
                       "alignment": r["alignment"], "warnings": r["warnings"]}
                      for (name, r), path in zip(reports[1:], also, strict=True)]
    log.info("\n%s", format_table(reports))
    for message in report["warnings"]:
        log.warning("%s: %s", label, message)
    return report


def write_report(provenance: Any, out: Path, report: dict[str, Any],
                 figures: dict[str, bytes]) -> None:
    """``report.json`` (with its figures and provenance), the PNG figures and the sidecar,
    inside the caller's output transaction (``difference.tif`` is the caller's)."""
    from demtool import io as dio

    report["figures"] = sorted(figures)
    report_path = out / REPORT
    outputs = [report_path, out / DIFFERENCE, *[out / name for name in figures]]
    report["provenance"] = provenance.record(_headline(report), outputs)
    for name, content in figures.items():
        with dio.atomic_path(out / name, suffix=".png") as temporary:
            temporary.write_bytes(content)
    dio.write_json(report_path, report)
    provenance.write_sidecar(report_path, _headline(report), outputs=outputs)


def make_figures(comparisons: Sequence[tuple[str, Any]], reference_values, lines,
                 spacing: tuple[float, float], label: str) -> dict[str, bytes]:
    """The PNG figures of a comparison: name -> bytes (``comparisons[0]`` is the main DEM's
    :class:`demtool.compare.Comparison`, the others the ``--also`` DEMs')."""
    from demtool.compare import plots as figure_maker

    main = comparisons[0][1]
    stats = main.report
    figures: dict[str, bytes] = {}
    figures["difference.png"] = figure_maker.difference_figure(
        main.difference, spacing, title=f"{label} − reference", stats=stats)
    figures["dems.png"] = figure_maker.dems_figure(
        [(label, main.aligned), *[(n, c.aligned) for n, c in comparisons[1:]],
         ("reference", reference_values)], spacing)
    figures["profiles.png"] = figure_maker.profiles_figure(
        [("reference", reference_values), (label, main.aligned),
         *[(n, c.aligned) for n, c in comparisons[1:]]], lines, spacing)
    figures["histogram.png"] = figure_maker.histogram_figure(main.difference, stats=stats,
                                                             title=f"{label} − reference")
    figures["completeness.png"] = figure_maker.completeness_figure(
        main.coverage, spacing, percent=main.report["completeness"], title=label)
    resolution = main.report["effective_resolution"]
    if main.spectrum is not None and resolution is not None:
        figures["coherence.png"] = figure_maker.coherence_figure(
            main.spectrum.frequency, main.spectrum.coherence,
            cutoff_per_m=resolution["coherent_frequency_per_m"],
            threshold=resolution["threshold"], title=f"{label} vs reference")
    return figures


def _windowed(run, dem_path, reference_path, out_dir, params, mask_path, also):
    """The windowed comparison's report when ``--tile-size`` or the memory budget asks for
    it (:func:`demtool.runs.compare_windowed.windowed_tile_size`), else None."""
    from demtool import io as dio
    from demtool.compare.planetary import check_bodies, metric_grid
    from demtool.runs.compare_windowed import (
        _grid,
        _Header,
        compare_windowed,
        windowed_tile_size,
    )

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


def run_compare(dem_path: str | os.PathLike, reference_path: str | os.PathLike,
                out_dir: str | os.PathLike, params: CompareParams | None = None, *,
                mask_path: str | os.PathLike | None = None, also: Sequence[str] = (),
                resolved: dict[str, Any] | None = None) -> dict[str, Any]:
    """Compare DEM (and ``also`` DEMs) with REFERENCE; write the report folder.

    Reads the rasters, puts them on one grid (the reference's, or the DEM's with
    ``params.grid="dem"``; reprojected when both have a different CRS), calls
    :func:`demtool.compare.compare_dems` for each DEM, and writes into ``out_dir`` —
    in one output transaction — ``report.json`` (figures, transform, the ``also`` DEMs
    and the provenance under ``provenance``), ``difference.tif`` (aligned DEM −
    reference, with provenance tags), the PNG figures and the standard provenance
    sidecar ``report.json.json``.

    Returns
    -------
    dict
        The report (as written to ``report.json``).
    """
    import numpy as np

    from demtool import io as dio
    from demtool.checks import check_magnitude
    from demtool.compare import compare_dems
    from demtool.compare import plots as figure_maker
    from demtool.compare.params import CompareParams

    params = params or CompareParams()
    run = StageRun("compare", params, resolved=resolved,
                   inputs={"DEM": dem_path, "REFERENCE": reference_path, "--also": also,
                           "--mask": mask_path}, folders={"--out": out_dir},
                   outputs={"--out": [Path(out_dir) / n for n in (REPORT, DIFFERENCE, *FIGURES)],
                            "sidecar": sidecar_path(Path(out_dir) / REPORT)})
    log, provenance = run.log, run.provenance
    grid, align, label = params.grid, params.align, params.label
    out = Path(out_dir)
    windowed = _windowed(run, dem_path, reference_path, out_dir, params, mask_path, also)
    if windowed is not None:
        return windowed
    dem = _read_dem(dem_path, "DEM")
    reference = _read_dem(reference_path, "reference DEM")
    extra = [_read_dem(path, "DEM (--also)") for path in also]
    for raster, what in ((dem, "DEM"), (reference, "reference DEM"),
                         *((r, "DEM (--also)") for r in extra)):
        check_magnitude(raster.data, raster.path, what=what)
    mask_raster = _read_mask_raster(mask_path, dem, reference) if mask_path else None
    for raster in (dem, *extra):
        check_same_frame(raster, reference, "compare rasters of one frame (e.g. a "
                         "target-frame DEM with truth_dem_target.tif)")
    from demtool.compare.planetary import check_bodies, check_map_and_frame, metric_grid

    for raster in (dem, *extra):
        check_map_and_frame(raster, reference)

    body_warnings = check_bodies([(r.path, r.crs) for r in (reference, dem, *extra)])
    if grid == "reference":
        target = _grid_of(reference)
        reference_values = reference.data.astype(np.float64)
        dem_values = _onto(dem, target, "DEM")
        frame = reference.tags.get("frame")
    else:
        target = _grid_of(dem)
        dem_values = dem.data.astype(np.float64)
        reference_values = _onto(reference, target, "reference DEM")
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
    for name, values in ((label, dem_values), *zip(labels, extra_values, strict=True)):
        comparison = compare_dems(values, reference_values, spacing=(sx, sy), align=align,
                                  mask=mask, slope_bins=params.slope_bins,
                                  icp_scale=params.icp_scale, seed=params.seed)
        comparisons.append((name, comparison))
    report = assemble_report([(name, c.report) for name, c in comparisons],
                             dem_path=dem_path, reference_path=reference_path, also=also,
                             grid=grid, target=target, frame=frame, degrees=degrees,
                             body_warnings=body_warnings, lines=lines, log=log)
    main = comparisons[0][1]

    figures = make_figures(comparisons, reference_values, lines, (sx, sy), label) \
        if params.plots else {}
    with run.transaction():
        dio.write_raster(out / DIFFERENCE, main.difference, transform=target.transform,
                         crs=target.crs,
                         tags=provenance.tags(frame=frame or "unknown", label=label,
                                              quantity="aligned DEM - reference (m)",
                                              shift=report["shift"]))
        write_report(provenance, out, report, figures)
    return report
