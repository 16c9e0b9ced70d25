"""``demtool compare`` on DEMs larger than memory: statistics window by window.

Used by :func:`demtool.compare.run.run_compare` when ``--tile-size`` is given, or when
the in-memory comparison would need more than ``--max-memory-mb``
(:func:`windowed_tile_size`).  The comparison grid is cut into windows
(:func:`demtool.tiling.plan_tiles`); each window of the DEM, the reference and the mask
is read alone (:func:`demtool.io.read_window`) and resampled onto the grid by the same
bilinear sampler and the same cell coordinates as the in-memory path
(:func:`demtool.compare.grids.source_pixels`, :func:`~demtool.compare.grids.sample_bilinear`;
a raster already on the grid is read as is), so every cell gets the in-memory value.

1. **Read pass**: each window's core of the DEM, the reference and the mask, checked
   and decimated by ``f`` (every f-th cell in both directions, ``f`` the smallest integer
   keeping it under :data:`ALIGN_CELLS` cells, or the memory budget); the whole grid is
   kept too when it fits (:mod:`demtool.compare.window_passes`).
2. **Alignment** on the decimated grid: :func:`demtool.compare.align.coregister`; the
   shift is scaled back by ``f``.  With ``f = 1`` (a grid of at most 2 M cells) the
   alignment is the in-memory one.  ``icp`` and ``nuth-kaab+icp`` are refused (their
   rotation and scale are applied through the whole grid); the effective resolution and
   the figures come from the decimated grid too.
3. **Statistics**, exact (:class:`demtool.compare.streaming.StreamStatistics`): pass 1
   accumulates the moments and the completeness counts and writes ``difference.tif``
   window by window (the windows with their margins from the kept grid, or read again);
   further passes (typically 4–6) find the median, LE90 and NMAD exactly by bucket
   narrowing, on the differences pass 1 kept (windows that did not fit are read and
   computed again).  Count, mean, RMSE and std equal the in-memory figures to rounding
   (~1e-15 relative); median, NMAD and LE90 are the same order statistics.

Peak memory: within ``--max-memory-mb``: the alignment on the decimated grid, then what
it leaves for the kept grid (17 bytes a cell) and differences (at most 16 bytes a cell);
beyond that, one window with its margins (a few arrays of ``(tile + 2m)²`` float64, two
at a time on two threads) and the order statistics' buffers (≤ 2 MiB each), not the DEM.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from demtool.errors import InputError, ParameterError, ProcessingError

ALIGN_CELLS = 1 << 21  # cells of the decimated grid the alignment runs on
BYTES_PER_CELL = 160  # in-memory compare: ~ a dozen float64 arrays of the grid + temporaries
ALIGN_BYTES_PER_CELL = 400  # alignment on the decimated grid (measured: ~0.7 GiB at 1.9 M)
DEFAULT_TILE = 1024


def windowed_tile_size(shape: tuple[int, int], params: Any) -> int:
    """The window side of a windowed comparison, or 0 for the in-memory one.

    ``--tile-size N`` windows a grid larger than N cells; without it a grid whose
    in-memory comparison needs more than ``--max-memory-mb`` (about
    :data:`BYTES_PER_CELL` bytes a cell) is windowed with windows that fit the budget
    (at most :data:`DEFAULT_TILE` cells a side).

    Raises
    ------
    ParameterError
        ``--tile-size`` between 1 and 15.
    """
    rows, cols = shape
    size = int(params.tile_size)
    if 0 < size < 16:
        raise ParameterError(f"--tile-size must be 0 (in memory) or >= 16 cells, got {size}")
    if size == 0:
        budget = params.max_memory_mb * 2**20
        if rows * cols * BYTES_PER_CELL <= budget:
            return 0
        size = int(min(DEFAULT_TILE, max(16, math.isqrt(int(budget / BYTES_PER_CELL)))))
    return size if rows > size or cols > size else 0


@dataclass
class Source:
    """A raster read window by window onto the comparison grid."""

    path: Path
    what: str
    grid: Any  # its own demtool.compare.grids.Grid
    target: Any  # the comparison grid
    same: bool = False
    reads: list[int] = field(default_factory=list)  # cells of each window read
    offset: float = 0.0  # metres subtracted: the body's radius for a map of radii

    def __post_init__(self) -> None:
        from demtool import io as dio
        from demtool.compare.grids import _check_overlap, same_grid
        from demtool.compare.planetary import radius_offset

        if self.what != "mask":
            self.offset = radius_offset(self.path, self.grid.crs,
                                        dio.read_decimated(self.path, what=self.what),
                                        self.what)

        self.same = same_grid(self.grid, self.target)
        if not self.same:
            try:
                _check_overlap(self.grid, self.target)
            except ProcessingError as exc:
                raise ProcessingError(f"{self.path}: {self.what}: {exc}") from None

    def _read_window(self, window: tuple[int, int, int, int]) -> np.ndarray:
        """:func:`demtool.io.read_window`: the raster opened for the window and closed.

        Not one dataset kept open for the passes (10–15 ms of CPU an open saved): GDAL
        keeps the blocks an open dataset read in its block cache until it is closed, up
        to ``GDAL_CACHEMAX`` (5 % of the machine's memory), outside ``--max-memory-mb``:
        kept open, the 4096² windowed comparison with a 600 MiB budget peaked at
        1010 MiB instead of 658."""
        from demtool import io as dio

        return dio.read_window(self.path, window, what=self.what)

    def read(self, window: tuple[int, int, int, int]) -> np.ndarray:
        """The window's cells of the comparison grid, float64, NaN where no value."""
        from demtool.compare.grids import sample_bilinear, source_pixels

        if self.same:
            self.reads.append((window[1] - window[0]) * (window[3] - window[2]))
            return self._read_window(window).astype(np.float64) - self.offset
        rows, cols = source_pixels(self.grid, self.target, window)
        shape = (window[1] - window[0], window[3] - window[2])
        finite = np.isfinite(rows) & np.isfinite(cols)
        height, width = self.grid.shape
        if finite.any():
            r0 = max(int(np.floor(rows[finite].min())), 0)
            r1 = min(int(np.floor(rows[finite].max())) + 2, height)
            c0 = max(int(np.floor(cols[finite].min())), 0)
            c1 = min(int(np.floor(cols[finite].max())) + 2, width)
            if r1 > r0 and c1 > c0:
                self.reads.append((r1 - r0) * (c1 - c0))
                data = self._read_window((r0, r1, c0, c1))
                return sample_bilinear(data, rows - r0, cols - c0) - self.offset
        return np.full(shape, np.nan)


class _Header:
    """What the frame and grid checks read of a raster, without its pixels."""

    def __init__(self, info: Any) -> None:
        self.path, self.crs, self.transform, self.tags = (info.path, info.crs, info.transform,
                                                          info.tags)
        self.data = np.broadcast_to(np.float32(0), (info.height, info.width))


def _grid(info: Any):
    from demtool.compare.grids import Grid

    return Grid(shape=(info.height, info.width), transform=info.transform, crs=info.crs)


def _read_pass(sources, shape, tiles, factor, grid, two):
    """Pass 0: the DEM, the reference and the mask core by core (on two threads with
    ``two``), checked, decimated for the alignment and kept in ``grid`` (a
    :class:`demtool.compare.window_passes.Grid`, or None)."""
    from demtool.compare.window_passes import decimate
    from demtool.imaging.checks import check_magnitude
    from demtool.tiling.rows import ordered_map

    rows, cols = -(-shape[0] // factor), -(-shape[1] // factor)
    dem = np.full((rows, cols), np.nan)
    ref = np.full((rows, cols), np.nan)
    mask = None if sources["mask"] is None else np.zeros((rows, cols), dtype=bool)

    def read(tile):
        core = tile.core
        got = []
        for name in ("dem", "reference"):
            values = sources[name].read(core)
            check_magnitude(values, sources[name].path, what=sources[name].what)
            got.append(values)
        if mask is not None:
            got.append(_mask_values(sources["mask"].read(core)))
        return core, got

    with contextlib.closing(ordered_map(read, tiles, threads=2 if two else 1)) as results:
        for core, got in results:
            arrays = (dem, ref) if mask is None else (dem, ref, mask)
            for array, values in zip(arrays, got, strict=True):
                part, rs, cs = decimate(values, core, factor)
                array[rs, cs] = part
            if grid is not None:
                grid.put(core, *got[:2], None if mask is None else got[2])
    return dem, ref, mask


def _align(decimated, params, target, factor, log):
    """The co-registration on the decimated grid (:func:`_read_pass`)."""
    from demtool.compare.align import coregister

    dem, ref, mask = decimated
    common = np.isfinite(dem) & np.isfinite(ref)
    if mask is not None:
        common &= mask
    if not common.any():
        raise ProcessingError("the DEM and the reference have no common valid pixel"
                              + (" inside the mask" if mask is not None else ""))
    sx, sy = target.spacing
    try:
        _, alignment = coregister(dem, ref, method=params.align, spacing=(sx * factor,
                                                                          sy * factor),
                                  mask=mask, icp_scale=params.icp_scale, seed=params.seed)
    except ProcessingError as exc:
        _, alignment = coregister(dem, ref, method="none")
        alignment.warnings.append(f"alignment '{params.align}' failed, statistics are "
                                  f"unaligned: {exc}")
        log.warning("alignment '%s' failed, statistics are unaligned: %s", params.align, exc)
    if factor > 1:
        for key in ("dx_px", "dy_px"):
            alignment.shift[key] *= factor
            alignment.shift_uncertainty[key] *= factor
        alignment.warnings.append(f"co-registration fitted on one cell in {factor} x {factor} "
                                  "of the grid (the windowed comparison's decimated grid)")
    return alignment


def _mask_values(values: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return np.isfinite(values) & (np.abs(values) > 0.5)


def _kernels_run_concurrently() -> bool:
    from demtool.tiling.local_threads import kernels_run_concurrently

    return kernels_run_concurrently()


def _no_phase(name: str) -> contextlib.AbstractContextManager[None]:
    return contextlib.nullcontext()


def compare_one(sources: dict[str, Source | None], target: Any, params: Any, tile_size: int,
                log: Any, *, open_writer: Any = None,
                phase: Callable[[str], contextlib.AbstractContextManager[None]] = _no_phase
                ) -> dict[str, Any]:
    """The windowed comparison of ``sources["dem"]`` with ``sources["reference"]``.

    ``open_writer(shift)``, when given, opens the block writer of ``difference.tif``
    (its tags carry the shift), written in the first pass.  ``phase(name)`` times the
    phases (``read``, ``align``, ``statistics``, ``spectrum``;
    :meth:`demtool.stagerun.StageRun.phase`).  What is kept between passes, and the
    threads: :mod:`demtool.compare.window_passes`.

    Returns
    -------
    dict
        ``report`` (the keys of :func:`demtool.compare.compare_dems`'s report plus
        ``windowed``), ``comparison`` (a :class:`demtool.compare.Comparison` of the
        decimated grid, for the figures) and ``factor`` (the decimation).
    """
    from demtool.compare.core import Comparison, effective_resolution
    from demtool.compare.threads import threaded
    from demtool.compare.window_passes import (
        GRID_BYTES_PER_CELL,
        KEPT_BYTES_PER_CELL,
        Grid,
        Streams,
        check_slope_bins,
        window_result,
    )
    from demtool.compare.windowed import shift_margin, window_values
    from demtool.imaging.spectral import coherence_spectrum
    from demtool.tiling import plan_tiles
    from demtool.tiling.rows import ordered_map

    check_slope_bins(params.slope_bins)
    height, width = target.shape
    sx, sy = target.spacing
    budget = params.max_memory_mb * 2**20
    factor = max(1, math.ceil(math.sqrt(height * width / min(ALIGN_CELLS,
                                                              budget / ALIGN_BYTES_PER_CELL))))
    rows, cols = -(-height // factor), -(-width // factor)
    room = budget - rows * cols * ALIGN_BYTES_PER_CELL  # what the alignment leaves
    keep_grid = height * width * (GRID_BYTES_PER_CELL + KEPT_BYTES_PER_CELL) <= room
    two = threaded(height * width) and _kernels_run_concurrently()
    grid = Grid(target.shape, sources["mask"] is not None) if keep_grid else None
    with phase("read"):
        decimated = _read_pass(sources, target.shape,
                               plan_tiles(height, width, tile_size, overlap=0).tiles, factor,
                               grid, two)
    with phase("align"):
        alignment = _align(decimated, params, target, factor, log)
    del decimated
    shift = alignment.shift
    method = params.align if alignment.method == params.align else "none"
    tiles = plan_tiles(height, width, tile_size,
                       overlap=shift_margin(shift["dx_px"], shift["dy_px"])).tiles
    # the windows whose differences are kept for the later passes: in order, while the
    # room holds their cores at KEPT_BYTES_PER_CELL (all of them when the grid is kept)
    keep, used = [], 0
    for tile in tiles:
        used += tile.core_shape[0] * tile.core_shape[1] * KEPT_BYTES_PER_CELL
        keep.append(grid is not None or used <= room)
    bins = params.slope_bins
    streams = Streams(len(bins) - 1)
    figures = {k: np.full((rows, cols), np.nan) for k in ("aligned", "reference", "difference")}
    figures["coverage"] = np.full((rows, cols), np.nan, dtype=np.float32)
    figures["mask"] = np.zeros((rows, cols), dtype=bool)

    def compute(tile, *, first: bool):
        if grid is not None:
            dem, reference, mask = grid.window(tile.outer)
        else:
            mask = (None if sources["mask"] is None
                    else _mask_values(sources["mask"].read(tile.outer)))
            dem, reference = (sources["dem"].read(tile.outer),
                              sources["reference"].read(tile.outer))
        values = window_values(dem, reference, mask, tile.crop, method=method, shift=shift,
                               spacing=(sx, sy))
        return window_result(values, None if mask is None else mask[tile.crop], tile.core,
                             bins, factor, first=first, keep=first and keep[tile.index],
                             difference=first and open_writer is not None)

    considered = covered = 0
    kept = []
    with phase("statistics"):
        with contextlib.ExitStack() as stack:
            writer = stack.enter_context(open_writer(shift)) if open_writer else None
            results = stack.enter_context(contextlib.closing(
                ordered_map(lambda tile: compute(tile, first=True), tiles,
                            threads=2 if two else 1)))
            for result in results:
                streams.merge_first(result)
                considered += result.considered
                covered += result.covered
                if writer is not None:
                    writer.write(result.difference, result.core[0], result.core[2])
                for name, (part, rs, cs) in result.figures.items():
                    figures[name][rs, cs] = part
                if result.kept is not None:
                    kept.append(result.kept)
        streams.end_pass()
        grid = None  # the later passes read what was not kept
        again = [tile for tile in tiles if not keep[tile.index]]
        passes = 1
        while not streams.done:
            passes += 1
            streams.add_kept(kept, two)
            with contextlib.closing(ordered_map(lambda tile: compute(tile, first=False), again,
                                                threads=2 if two else 1)) as results:
                for result in results:
                    streams.add_pieces(result)
            streams.end_pass()
    log.info("windowed comparison: %d windows of %d cells, %d passes (%d reading the "
             "rasters again), alignment on every %d cell(s)%s", len(tiles), tile_size,
             passes, len(again), factor, "; the grid read once" if keep_grid else "")
    warnings = list(alignment.warnings)
    resolution = spectrum = None
    spacing = float(np.sqrt(sx * sy)) * factor
    with phase("spectrum"):
        try:
            spectrum = coherence_spectrum(
                figures["aligned"] if sources["mask"] is None
                else np.where(figures["mask"], figures["aligned"], np.nan),
                figures["reference"], spacing=spacing,
                threads=2 if threaded(rows * cols) else 1)
            resolution = effective_resolution(spectrum, spacing, 0.5)
        except ProcessingError as exc:
            warnings.append(f"no effective resolution: {exc}")
    edges = params.slope_bins
    result = streams.after.result()
    reads = [n for s in sources.values() if s is not None for n in s.reads]
    report: dict[str, Any] = {
        **{k: result[k] for k in ("count", "mean", "median", "std", "rmse", "nmad", "le90",
                                  "min", "max")},
        "completeness": 100.0 * covered / considered if considered else float("nan"),
        "shift": dict(alignment.shift), "shift_uncertainty": dict(alignment.shift_uncertainty),
        "alignment": alignment.as_dict(), "before_alignment": streams.before.result(),
        "slope_classes": [{"slope_min_deg": float(lo), "slope_max_deg": float(hi),
                           **s.result()} for lo, hi, s in zip(edges[:-1], edges[1:],
                                                              streams.classes,
                                                              strict=True)],
        "effective_resolution": resolution,
        "grid": {"shape": [height, width], "spacing_m": [sx, sy]},
        "warnings": warnings,
        "windowed": {"tile_size": tile_size, "windows": len(tiles), "passes": passes,
                     "margin_cells": shift_margin(shift["dx_px"], shift["dy_px"]),
                     "alignment_decimation": factor,
                     "largest_read_cells": max(reads, default=0),
                     "statistics": "exact (moments; order statistics by bucket narrowing)"},
    }
    comparison = Comparison(report=report, aligned=figures["aligned"],
                            reference=figures["reference"], difference=figures["difference"],
                            coverage=figures["coverage"], slope=np.empty((0, 0)),
                            alignment=alignment, spectrum=spectrum)
    return {"report": report, "comparison": comparison, "factor": factor}


def compare_windowed(run: Any, dem_path: str | os.PathLike, reference_path: str | os.PathLike,
                     out_dir: str | os.PathLike, params: Any, tile_size: int, *,
                     infos: dict[str, Any], target: Any, degrees: Any,
                     mask_path: str | os.PathLike | None = None,
                     also: Sequence[str] = (), body_warnings: Sequence[str] = ()
                     ) -> dict[str, Any]:
    """The windowed ``demtool compare`` (see the module docstring); writes what
    :func:`demtool.compare.run.run_compare` writes and returns the report."""
    from demtool import io as dio
    from demtool.compare.plots import default_profiles
    from demtool.compare.report import (
        DIFFERENCE,
        _check_profiles,
        assemble_report,
        make_figures,
        write_report,
    )
    from demtool.compare.windowed import WINDOWED_METHODS
    from demtool.imaging.checks import check_same_grid

    log, provenance = run.log, run.provenance
    if params.align not in WINDOWED_METHODS:
        raise ParameterError(f"--align {params.align} needs the whole grid in memory; the "
                             f"windowed comparison (--tile-size, or a grid beyond "
                             f"--max-memory-mb) takes {', '.join(WINDOWED_METHODS)}")
    mask_source = None
    if mask_path is not None:
        mask_info = dio.raster_info(mask_path, what="mask")
        try:
            check_same_grid(_Header(infos["reference"]), _Header(mask_info),
                            reference_what="reference DEM")
        except InputError:
            check_same_grid(_Header(infos["dem"]), _Header(mask_info))
        mask_source = Source(Path(mask_path), "mask", _grid(mask_info), target)
    lines = [tuple(float(v) for v in line) for line in params.profiles] or \
        default_profiles(target.shape)
    _check_profiles(lines, target.shape)
    out = Path(out_dir)
    label = params.label or Path(dem_path).stem
    frame = infos["reference" if params.grid == "reference" else "dem"].tags.get("frame")
    log.info("%s vs %s on the %s grid (%d x %d, %.4g x %.4g m), alignment %s, in windows of "
             "%d cells", dem_path, reference_path, params.grid, target.shape[1],
             target.shape[0], *target.spacing, params.align, tile_size)
    reference = Source(Path(reference_path), "reference DEM", _grid(infos["reference"]),
                       target)
    results = []
    with run.transaction():
        for index, (name, path) in enumerate(((label, dem_path),
                                              *((Path(p).stem, p) for p in also))):
            what = "DEM" if index == 0 else "DEM (--also)"
            sources = {"dem": Source(Path(path), what, _grid(infos[str(path)]), target),
                       "reference": reference, "mask": mask_source}

            def open_writer(shift):
                return dio.raster_writer(
                    out / DIFFERENCE, height=target.shape[0], width=target.shape[1],
                    transform=target.transform, crs=target.crs, tags=provenance.tags(
                        frame=frame or "unknown", label=label,
                        quantity="aligned DEM - reference (m)", shift=shift))

            results.append((name, compare_one(sources, target, params, tile_size, log,
                                              open_writer=open_writer if index == 0
                                              else None, phase=run.phase)))
        main = results[0][1]
        factor = main["factor"]
        report = assemble_report([(name, r["report"]) for name, r in results],
                                 dem_path=dem_path, reference_path=reference_path, also=also,
                                 grid=params.grid, target=target, frame=frame,
                                 degrees=degrees, body_warnings=body_warnings, lines=lines,
                                 log=log, dem_grids=[_grid(infos[str(p)])
                                                     for p in (dem_path, *also)],
                                 reference_grid=_grid(infos["reference"]))
        from demtool.compare.coarse import MIN_RATIO, resolution_ratio

        ratio, _ = resolution_ratio(_grid(infos["dem"]), _grid(infos["reference"]))
        if ratio >= MIN_RATIO:
            message = (f"the reference's posts are {ratio:.3g} x the DEM's cells, but the "
                       "comparison at the reference's resolution (the DEM averaged over "
                       "each reference cell) is made in memory only: raise --max-memory-mb "
                       "to get it")
            report["at_reference_resolution"] = {"error": message}
            report["warnings"].append(message)
            log.warning("%s: %s", label, message)
        figures = {}
        if params.plots:
            decimated = [tuple(v / factor for v in line) for line in lines]
            with run.phase("figures"):
                figures = make_figures([(n, r["comparison"]) for n, r in results],
                                       main["comparison"].reference, decimated,
                                       (target.spacing[0] * factor,
                                        target.spacing[1] * factor), label)
        write_report(provenance, out, report, figures, html=params.html,
                     timings=run.timings)
    return report
