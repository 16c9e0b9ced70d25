"""Runner of ``demtool fuse``: several DEMs of one area → one DEM, count, spread, error.

Files in, files out: read the DEMs' grids, refuse DEMs of different bodies, find each
DEM's error raster (``--error``, or ``<stem>_error.tif`` beside it, as ``dem
--error-out`` is named in the Makefile; logged), build the fused grid (the union of
the DEMs' extents on the first DEM's CRS and spacing, or ``--grid-like``'s grid),
co-register each DEM to the reference on a window of their overlap (compare's
alignment; each shift logged), optionally leave out DEMs far from the others'
consensus (``--max-nmad``; those windows read, and the figures computed, on threads
by :mod:`demtool.fuse.overlap`), then combine cell by cell (:mod:`demtool.fuse.core`) in
one tile or in many (:mod:`demtool.fuse.tiled`) and write the fused DEM and, beside it,
``<stem>_count.tif``, ``<stem>_spread.tif`` and ``<stem>_error.tif``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from demtool.fuse.checks import check_frames, check_size, same_content
from demtool.fuse.grids import (
    cells_of,
    centred,
    coreg_grid,
    grid_of,
    intersect,
    spacing_of,
    t_srs_grid,
    union_grid,
)
from demtool.stagerun import StageRun, sidecar_path

if TYPE_CHECKING:
    from demtool.fuse.params import FuseParams

PathLike = str | os.PathLike
SUFFIXES = ("count", "spread", "error")


def _shift_units(shift, uncertainty, target, spec, ref_spec) -> dict[str, Any]:
    """A shift on the fused grid in metres and in the DEM's and the reference's own pixels
    (:func:`demtool.compare.shift_units.shift_in_units`)."""
    from demtool.compare.shift_units import shift_in_units

    return shift_in_units(shift, uncertainty, target.grid(),
                          [("dem", spec.grid()), ("reference", ref_spec.grid())])


def output_paths(out: PathLike) -> dict[str, Path]:
    """The fused DEM and the rasters written beside it (``<stem>_count.tif`` ...)."""
    out = Path(out)
    paths = {"dem": out}
    for name in SUFFIXES:
        paths[name] = out.with_name(f"{out.stem}_{name}{out.suffix or '.tif'}")
    return paths


def _error_rasters(dems: Sequence[Path], errors: Sequence[PathLike] | None, method: str,
                   log) -> list[Path | None]:
    from demtool.errors import InputError, ParameterError

    if errors:
        if len(errors) != len(dems):
            raise ParameterError(f"--error: {len(errors)} error raster(s) for {len(dems)} "
                                 "DEMs; give one per DEM, in the DEMs' order")
        return [Path(e) for e in errors]
    found: list[Path | None] = []
    for dem in dems:
        beside = dem.with_name(f"{dem.stem}_error{dem.suffix}")
        found.append(beside if beside.is_file() else None)
        if beside.is_file():
            log.info("%s: error raster %s (found beside it)", dem, beside)
    if method == "median":
        missing = [str(d) for d, e in zip(dems, found, strict=True) if e is None]
        if missing:
            raise InputError(f"{missing[0]}: no error raster, and --method median weighs "
                             "each DEM by its error raster (give --error for every DEM, in "
                             "order, e.g. dem --error-out's file, or use --method mean)"
                             + (f"; also missing for {', '.join(missing[1:])}"
                                if len(missing) > 1 else ""))
    elif any(e is None for e in found):
        if any(e is not None for e in found):
            log.info("not every DEM has an error raster beside it: weighting by border "
                     "distance only")
        found = [None] * len(dems)
    return found


def write_outputs(outputs: Sequence[tuple[Path, int, str, dict[str, Any]]],
                  bands: np.ndarray, target: Any) -> None:
    """Write each (path, band, name, tags) of ``outputs``: ``bands[band]`` on ``target``'s
    grid (:func:`demtool.io.write_raster`), the files on threads at once (GDAL's
    compression, and its overviews through :mod:`demtool.io.overviews`, run outside the
    GIL), each as on the calling thread
    (:func:`demtool.tiling.tasks.carried`: its output transaction and layout); a failure
    is raised once the others have ended, the first in the outputs' order."""
    from concurrent.futures import ThreadPoolExecutor

    from demtool import io as dio
    from demtool.tiling.tasks import carried, usable_threads

    def write(output: tuple[Path, int, str, dict[str, Any]]) -> None:
        path, band, name, tags = output
        dio.write_raster(path, bands[band], transform=target.affine(), crs=target.crs(),
                         tags=tags, band_names=[name])

    threads = min(usable_threads(), len(outputs))
    if threads < 2:
        for output in outputs:
            write(output)
        return
    with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="demtool-write") as pool:
        futures = [pool.submit(carried(lambda output=output: write(output)))
                   for output in outputs]
    for future in futures:
        future.result()


def run_fuse(dems: Sequence[PathLike], out: PathLike, params: FuseParams | None = None, *,
             errors: Sequence[PathLike] | None = None, reference: PathLike | None = None,
             grid_like: PathLike | None = None, resolved: dict[str, Any] | None = None
             ) -> dict[str, Any]:
    """Fuse DEMs of one area into one (see the module docstring).

    Parameters
    ----------
    dems : sequence of path-like
        The DEMs (GeoTIFF heights, metres), the first one giving the CRS and spacing.
    out : path-like
        The fused DEM; ``<stem>_count.tif``, ``<stem>_spread.tif`` and
        ``<stem>_error.tif`` are written beside it, and the sidecar ``<out>.json``.
    params : FuseParams, optional
    errors : sequence of path-like, optional
        One error raster per DEM (metres), in order.
    reference : path-like, optional
        The DEM every DEM is co-registered to (default: the first DEM).
    grid_like : path-like, optional
        A raster whose grid the fused DEM is written on (default: the union of the DEMs'
        extents on the first DEM's grid).

    Returns
    -------
    dict
        The summary written to the sidecar: ``grid``, ``dems`` (each with its shift, also
        in metres and in its own and the reference's pixels — ``shift_m``,
        ``shift_uncertainty_m``, ``shift_input_px`` of
        :func:`demtool.compare.shift_units.shift_in_units` —,
        consensus NMAD and whether it was used), ``cells``, ``rejected_fraction``,
        ``strips`` (row strips the grid was computed in, on threads) and ``timings_s``
        (wall and CPU seconds per phase: ``coregister``, ``consensus``, ``combine``,
        ``write``).

    Raises
    ------
    InputError
        DEMs of different bodies, a DEM outside the fused grid or without common cells
        with the reference, a missing error raster for ``--method median``, every DEM
        left out by ``--max-nmad``.
    """
    from demtool import io as dio
    from demtool.errors import DemtoolError, InputError, ParameterError, ProcessingError
    from demtool.fuse.core import estimate_shift
    from demtool.fuse.overlap import consensus_figures, consensus_stack, coreg_samples
    from demtool.fuse.params import FuseParams
    from demtool.fuse.tiled import FuseTileJob, fuse_tiled, on_threads, single_tile
    from demtool.tiling import wants_tiles

    params = params or FuseParams()
    dem_paths = [Path(d) for d in dems]
    paths = output_paths(out)
    run = StageRun("fuse", params, resolved=resolved,
                   inputs={"DEM": dem_paths, "--error": list(errors) if errors else None,
                           "--reference": reference, "--grid-like": grid_like},
                   outputs={"--out": paths["dem"], "count": paths["count"],
                            "spread": paths["spread"], "error": paths["error"],
                            "sidecar": sidecar_path(paths["dem"])})
    log = run.log
    if not dem_paths:
        raise ParameterError("give at least one DEM")
    infos = [dio.raster_info(p, what="DEM") for p in dem_paths]
    extra = [dio.raster_info(p, what=what) for p, what in
             ((reference, "reference DEM"), (grid_like, "--grid-like raster")) if p]
    check_frames(infos + extra, [*dem_paths, *(p for p in (reference, grid_like) if p)])
    error_paths = _error_rasters(dem_paths, errors, params.method, log)
    specs = [grid_of(i) for i in infos]
    error_specs = []
    for dem, spec, path in zip(dem_paths, specs, error_paths, strict=True):
        if path is None:
            error_specs.append(None)
            continue
        if same_content(path, dem):
            raise InputError(f"{path}: is the DEM {dem} itself, given as its error raster; "
                             "give the error raster dem --error-out wrote with it")
        info = dio.raster_info(path, what="error raster")
        if (info.height, info.width) != spec.shape or \
                not info.transform.almost_equals(spec.affine()):
            raise InputError(f"{path}: the error raster is not on {dem}'s grid "
                             f"({info.height}x{info.width} vs {spec.shape[0]}x{spec.shape[1]})"
                             "; give the error raster the dem stage wrote with this DEM")
        error_specs.append(spec)
    if params.t_srs is not None:
        if grid_like:
            raise ParameterError(f"--t-srs {params.t_srs} and --grid-like {grid_like} each "
                                 "set the fused grid: give one")
        target = t_srs_grid(params.t_srs, specs, dem_paths[0])
    else:
        target = grid_of(extra[-1]) if grid_like else union_grid(specs, specs[0])
    spacing = target.grid().spacing
    log.info("fused grid: %d x %d cells of %.4g x %.4g (%s)", target.shape[1],
             target.shape[0], spacing[0], spacing[1],
             "from --grid-like" if grid_like else f"on --t-srs {params.t_srs}" if params.t_srs
             else "union of the DEMs on the first's grid")
    check_size(target, dem_paths, specs, grid_like, wants_tiles(*target.shape, params), out,
                log)
    windows = []
    for path, spec in zip(dem_paths, specs, strict=True):
        window = cells_of(spec, target)
        if window is None:
            raise InputError(f"{path}: no common overlap with the fused grid; fuse DEMs of "
                             "one area")
        windows.append(window)

    # Co-registration to the reference, on a window of their overlap.
    ref_path = Path(reference) if reference else dem_paths[0]
    ref_spec = grid_of(extra[0]) if reference else specs[0]
    ref_window = cells_of(ref_spec, target)
    if ref_window is None:
        raise InputError(f"{ref_path}: the reference has no common overlap with the fused "
                         "grid; fuse DEMs of one area")
    shifts, records = [], []
    failed: set[int] = set()  # left out: co-registration failed (with --max-nmad)

    def align(i: int) -> tuple[dict[str, Any] | Exception, int]:
        """DEM i's alignment to the reference, or the error that stops the run (a reading
        error, wrapped in RuntimeError) or leaves the DEM out (ProcessingError of the
        co-registration); and the factor of the co-registration grid."""
        factor = plans[i][2]
        dem, ref = samples[i]
        for sample in (dem, ref):
            if isinstance(sample, DemtoolError):  # raised in the DEMs' order below
                return RuntimeError(sample), factor
        try:
            return estimate_shift(dem, ref, method=params.align,
                                  spacing=tuple(v / factor for v in spacing),
                                  label=str(dem_paths[i])), factor
        except ProcessingError as exc:
            return exc, factor

    to_align = [i for i, p in enumerate(dem_paths) if not (p == ref_path and not reference)]
    overlaps = {i: intersect(windows[i], ref_window) for i in to_align}
    for i, path in ((i, dem_paths[i]) for i in to_align):
        if overlaps[i] is None:
            raise InputError(f"{path}: no common overlap with the reference "
                             f"{ref_path}; fuse DEMs of one area")
    plans = {i: coreg_grid(target, centred(overlaps[i], params.coreg_size),
                           (spacing_of(specs[i]), spacing_of(ref_spec)), params.coreg_size)
             for i in to_align}
    with run.phase("coregister"):
        samples = coreg_samples(plans, {i: (dem_paths[i], specs[i]) for i in to_align},
                                (ref_path, ref_spec))
        aligned = dict(zip(to_align, on_threads(align, to_align), strict=True))
    for i, path in enumerate(dem_paths):
        record: dict[str, Any] = {"dem": str(path), "error": None if error_paths[i] is None
                                  else str(error_paths[i])}
        if i not in aligned:
            zero = {"dx_px": 0.0, "dy_px": 0.0, "dz": 0.0}
            record["alignment"] = {"method": "reference", "shift": zero,
                                   **_shift_units(zero, zero, target, specs[i], ref_spec)}
            shifts.append((0.0, 0.0, 0.0))
            records.append(record)
            continue
        alignment, factor = aligned[i]
        if isinstance(alignment, RuntimeError):
            raise alignment.args[0]
        if isinstance(alignment, ProcessingError):
            exc = alignment
            reason = str(exc).replace("the reference", f"the reference {ref_path}")
            if not reason.startswith(f"{path}:"):
                reason = (f"{path}: co-registration to the reference {ref_path} failed: "
                          f"{reason}")
            if params.max_nmad is None:
                raise InputError(f"{reason}; check this DEM, or give --max-nmad to leave "
                                 "out DEMs that do not agree with the others") from None
            log.warning("%s: left out (%s)", path, reason)
            record["alignment"] = None
            record["left_out"] = reason
            failed.add(i)
            shifts.append((0.0, 0.0, 0.0))
            records.append(record)
            continue
        if factor > 1:
            log.info("%s: co-registered on a grid %d times finer than the fused grid",
                     path, factor)
            for key in ("shift", "shift_uncertainty"):
                if key in alignment:
                    alignment[key] = {k: (v / factor if k in ("dx_px", "dy_px") else v)
                                      for k, v in alignment[key].items()}
        s = alignment["shift"]
        alignment.update(_shift_units(s, alignment["shift_uncertainty"], target, specs[i],
                                      ref_spec))
        metres, own = alignment["shift_m"], alignment["shift_input_px"]["dem"]
        log.info("%s: shift to the reference dx %+.3f dy %+.3f cells of the fused grid "
                 "(%+.3f %+.3f of its own pixels; %s %+.3f %+.3f m), dz %+.3f m (%s, %d "
                 "common cells)", path, s["dx_px"], s["dy_px"], own["dx_px"], own["dy_px"],
                 "east, north" if "east" in metres else "map x, y",
                 *(v for k, v in metres.items() if k not in ("up", "axes")), s["dz"],
                 params.align, alignment["common_cells"])
        for warning in alignment.get("warnings", []):
            log.warning("%s: %s", path, warning)
        shifts.append((s["dx_px"], s["dy_px"], s["dz"]))
        record["alignment"] = alignment
        records.append(record)

    others = [i for i, p in enumerate(dem_paths) if not (p == ref_path and not reference)]
    if len(others) >= 2 and failed.issuperset(others):
        raise InputError(f"{ref_path}: no DEM co-registers to this reference ({len(failed)} "
                         "failed); check it, or give another DEM as --reference")
    # DEM-level outlier rejection against the consensus of the others.
    used = list(range(len(dem_paths)))
    scale_floor = 0.0
    if len(dem_paths) >= 2:
        window = centred(ref_window, params.coreg_size)
        with run.phase("consensus"):
            stack = consensus_stack([(dem_paths[i], specs[i], shifts[i])
                                     for i in range(len(dem_paths))], target, window)
            stack[sorted(failed)] = np.nan
            nmads, floor = consensus_figures(stack, scale=params.method == "huber")
            nmads[sorted(failed)] = np.inf
            if params.method == "huber":
                scale_floor = floor
        if params.method == "huber":
            log.info("Huber scale: at least %.3f m (NMAD of the heights against their "
                     "cell's median over the reference's window)", scale_floor)
        for i, value in enumerate(nmads):
            records[i]["consensus_nmad_m"] = None if not np.isfinite(value) else float(value)
            log.info("%s: NMAD against the others' median %.3f m", dem_paths[i], value)
        if params.max_nmad is not None:
            used = [i for i, v in enumerate(nmads) if not (v > params.max_nmad)]
            for i in sorted(set(range(len(dem_paths))) - set(used) - failed):
                log.warning("%s: left out (NMAD against the others' median %.3f m > "
                            "--max-nmad %g m)", dem_paths[i], nmads[i], params.max_nmad)
            if not used:
                listed = ", ".join(f"{p.name} {v:.3g} m" for p, v in
                                   zip(dem_paths, nmads, strict=True))
                raise InputError(f"every DEM was rejected as an outlier (NMAD against the "
                                 f"others' median above --max-nmad {params.max_nmad:g} m: "
                                 f"{listed}); raise --max-nmad or check the DEMs")
    for i, record in enumerate(records):
        record["used"] = i in used

    job = FuseTileJob(dems=tuple(str(dem_paths[i]) for i in used),
                      errors=tuple(None if error_paths[i] is None else str(error_paths[i])
                                   for i in used),
                      grids=tuple(specs[i] for i in used),
                      shifts=tuple(tuple(float(v) for v in shifts[i]) for i in used),
                      target=target, method=params.method, outlier_k=params.outlier_k,
                      blend=params.blend, gap=params.gap,
                      weights_exponent=params.weights_exponent,
                      min_error=params.min_error, scale_floor=scale_floor)
    summary: dict[str, Any] = {"grid": {"shape": list(target.shape),
                                        "transform": list(target.transform)},
                               "method": params.method, "dems": records}
    if params.method == "huber":
        summary["huber_scale_floor_m"] = scale_floor
    prov = run.provenance
    body_tags: dict[str, Any] = {}
    if target.crs_wkt is not None:
        from demtool.maps import body_from_crs

        body_tags = body_from_crs(target.crs()).tags()
    descriptions = {"dem": ("fused heights", "metres"),
                    "count": ("number of DEMs combined in the cell", "DEMs"),
                    "spread": ("NMAD of the combined heights (NaN: fewer than two)", "metres"),
                    "error": ("combined one-sigma error", "metres")}
    outputs = [(paths[name], band, name,
                prov.tags(meaning=descriptions[name][0], units=descriptions[name][1],
                          fuse_method=params.method, **body_tags))
               for band, name in enumerate(("dem", "count", "spread", "error"))]
    inputs = [*job.dems, *(e for e in job.errors if e)]
    tile_size = wants_tiles(*target.shape, params)
    summary["timings_s"] = run.timings
    if tile_size:
        result = fuse_tiled(run, job, tile_size, params, outputs, inputs, summary)
        return {**result.summary, "dry_run": result.dry_run}
    with run.phase("combine"):  # sampling, border weights and combination, in row strips
        bands, info = job.compute(single_tile(target.shape), 0)
    summary["strips"] = info["strips"]
    if info["cells"] == 0:
        raise ProcessingError("the fused DEM has no cell with a height")
    summary["cells"] = info["cells"]
    summary["rejected_fraction"] = float(1 - info["kept"] / info["offered"]) \
        if info["offered"] else 0.0
    log.info("fused %d DEM(s) into %d cells (%.2f %% of the values rejected as outliers)",
             len(used), info["cells"], 100 * summary["rejected_fraction"])
    with run.transaction():
        with run.phase("write"):
            write_outputs(outputs, bands, target)
        prov.write_sidecar(paths["dem"], summary, outputs=[o[0] for o in outputs])
    return summary
