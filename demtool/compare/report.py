"""What both compare routes (whole grid, :mod:`demtool.compare.run`, and windowed,
:mod:`demtool.compare.run_windowed`) write: the report, its table and the figures."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

REPORT = "report.json"
DIFFERENCE = "difference.tif"
HTML = "report.html"  # compare --html (demtool.compare.html)


# The shift in metres and in each input's own pixels (demtool.compare.shift_units).
UNIT_KEYS = ("shift_m", "shift_uncertainty_m", "shift_input_px")

FIGURES = ("difference.png", "dems.png", "profiles.png", "histogram.png", "completeness.png",
           "coherence.png")


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
    units = {k: report[k] for k in UNIT_KEYS if k in report}
    return {**{k: report[k] for k in keys}, "shift": report["shift"],
            "shift_uncertainty": report["shift_uncertainty"], **units,
            "wavelength_m": resolution.get("wavelength_m")}


def format_table(rows: Sequence[tuple[str, dict[str, Any]]]) -> str:
    """Short plain-text table: one row per compared DEM.

    The shift is given three ways: comparison-grid pixels (``dx px``, ``dy px``), metres
    east and north (``dE m``, ``dN m``; ``dX m``, ``dY m`` along the map axes of a
    raster without CRS) with ``dz m`` up, and the DEM's own pixels (``dx DEM``,
    ``dy DEM``) when known."""
    def fmt(value: Any, spec: str) -> str:
        return "—" if value is None else format(value, spec)

    first = rows[0][1].get("shift_m") or {}
    east, north = ("dE m", "dN m") if "east" in first else ("dX m", "dY m")
    header = (f"{'DEM':<20} {'n':>9} {'compl %':>8} {'mean':>8} {'RMSE':>8} {'NMAD':>8} "
              f"{'LE90':>8} {'dx px':>7} {'dy px':>7} {east:>8} {north:>8} {'dz m':>8} "
              f"{'dx DEM':>7} {'dy DEM':>7} {'λ coh m':>8}")
    lines = [header]
    for label, r in rows:
        resolution = r.get("effective_resolution") or {}
        metres = r.get("shift_m") or {}
        horizontal = [metres.get(k) for k in (("east", "north") if "east" in metres
                                              else ("x", "y"))]
        own = (r.get("shift_input_px") or {}).get("dem") or {}
        lines.append(
            f"{label[:20]:<20} {r['count']:>9d} {fmt(r['completeness'], '8.2f')} "
            f"{fmt(r['mean'], '8.3f')} {fmt(r['rmse'], '8.3f')} {fmt(r['nmad'], '8.3f')} "
            f"{fmt(r['le90'], '8.3f')} {r['shift']['dx_px']:7.3f} {r['shift']['dy_px']:7.3f} "
            f"{fmt(horizontal[0], '8.3f')} {fmt(horizontal[1], '8.3f')} "
            f"{r['shift']['dz']:8.3f} {fmt(own.get('dx_px'), '7.3f')} "
            f"{fmt(own.get('dy_px'), '7.3f')} {fmt(resolution.get('wavelength_m'), '8.2f')}")
    return "\n".join(lines)


def add_shift_units(report: dict[str, Any], target: Any, dem_grid: Any,
                    reference_grid: Any) -> None:
    """Add ``shift_m``, ``shift_uncertainty_m`` and ``shift_input_px`` (``dem``,
    ``reference``) to one DEM's report (:func:`demtool.compare.shift_units.shift_in_units`
    on the comparison grid ``target``)."""
    from demtool.compare.shift_units import shift_in_units

    report.update(shift_in_units(report["shift"], report["shift_uncertainty"], target,
                                 [("dem", dem_grid), ("reference", reference_grid)]))


def assemble_report(reports: Sequence[tuple[str, dict[str, Any]]], *, dem_path, reference_path,
                    also: Sequence[str], grid: str, target: Any, frame: str | None,
                    degrees: Any, body_warnings: Sequence[str], lines, log,
                    dem_grids: Sequence[Any] = (), reference_grid: Any = None
                    ) -> dict[str, Any]:
    """The report of one comparison run from each DEM's own report (main DEM first, then
    the ``also`` DEMs), logged as the table and the warnings; in memory and in windows.

    ``dem_grids`` (one :class:`demtool.compare.grids.Grid` per compared DEM, in order)
    and ``reference_grid``, when given, add the shift in metres and in the inputs' own
    pixels to each DEM's report (:func:`add_shift_units`)."""
    if reference_grid is not None:
        for (_, r), dem_grid in zip(reports, dem_grids, strict=True):
            add_shift_units(r, target, dem_grid, reference_grid)
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
                 figures: dict[str, bytes], *, html: bool = False,
                 timings: dict[str, float] | None = None) -> None:
    """``report.json`` (with its figures and provenance), the PNG figures, with ``html``
    the page ``report.html`` (:func:`demtool.compare.html.html_report`) and the sidecar,
    inside the caller's output transaction (``difference.tif`` is the caller's).
    ``timings`` (seconds per phase, :meth:`demtool.stagerun.StageRun.phase`) go into the
    provenance record's summary as ``timings_s``."""
    from demtool import io as dio

    report["figures"] = sorted(figures)
    report_path = out / REPORT
    outputs = [report_path, out / DIFFERENCE, *[out / name for name in figures]]
    if html:
        outputs.append(out / HTML)
    headline = _headline(report)
    if timings:
        headline["timings_s"] = timings
    report["provenance"] = provenance.record(headline, outputs)
    for name, content in figures.items():
        with dio.atomic_path(out / name, suffix=".png") as temporary:
            temporary.write_bytes(content)
    dio.write_json(report_path, report)
    if html:
        from demtool.compare.html import html_report

        with dio.atomic_path(out / HTML, suffix=".html") as temporary:
            temporary.write_text(html_report(report, figures), encoding="utf-8")
    provenance.write_sidecar(report_path, headline, outputs=outputs)


def make_figures(comparisons: Sequence[tuple[str, Any]], reference_values, lines,
                 spacing: tuple[float, float], label: str) -> dict[str, bytes]:
    """The PNG figures of a comparison: name -> bytes (``comparisons[0]`` is the main DEM's
    :class:`demtool.compare.Comparison`, the others the ``--also`` DEMs').

    On a grid of :data:`demtool.compare.threads.THREADED_CELLS` cells or more, two
    figures are drawn at a time on two threads (each its own matplotlib ``Figure`` on
    the Agg canvas, no pyplot state; matplotlib keeps its fonts per thread; numpy's
    percentiles and gradients and Agg's rasterising run outside the GIL): the same PNG
    bytes as one at a time."""
    import functools

    from demtool.compare import plots as figure_maker
    from demtool.compare.threads import threaded
    from demtool.tiling.tasks import carried

    main = comparisons[0][1]
    stats = main.report
    # the difference map's and the histogram's limit: one percentile of the finite |dh|
    # (of the same values in the same order: the same number), not one each
    limit = functools.cache(lambda: figure_maker.symmetric_limit(main.difference))
    makers: dict[str, Callable[[], bytes]] = {
        "difference.png": lambda: figure_maker.difference_figure(
            main.difference, spacing, title=f"{label} − reference", stats=stats,
            limit=limit()),
        "dems.png": lambda: figure_maker.dems_figure(
            [(label, main.aligned), *[(n, c.aligned) for n, c in comparisons[1:]],
             ("reference", reference_values)], spacing),
        "profiles.png": lambda: figure_maker.profiles_figure(
            [("reference", reference_values), (label, main.aligned),
             *[(n, c.aligned) for n, c in comparisons[1:]]], lines, spacing),
        "histogram.png": lambda: figure_maker.histogram_figure(
            main.difference, stats=stats, title=f"{label} − reference", limit=limit()),
        "completeness.png": lambda: figure_maker.completeness_figure(
            main.coverage, spacing, percent=main.report["completeness"], title=label),
    }
    resolution = main.report["effective_resolution"]
    if main.spectrum is not None and resolution is not None:
        makers["coherence.png"] = lambda: figure_maker.coherence_figure(
            main.spectrum.frequency, main.spectrum.coherence,
            cutoff_per_m=resolution["coherent_frequency_per_m"],
            threshold=resolution["threshold"], title=f"{label} vs reference")
    if not threaded(main.difference.size):
        return {name: make() for name, make in makers.items()}
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=2) as pool:  # the largest (dems.png) first
        order = sorted(makers, key=lambda name: name != "dems.png")
        drawn = {name: pool.submit(carried(makers[name])) for name in order}
        return {name: drawn[name].result() for name in makers}
