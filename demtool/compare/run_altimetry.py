"""``demtool compare DEM shots.csv``: a DEM against laser altimetry shots
(:mod:`demtool.io.altimetry`, :mod:`demtool.compare.altimetry`).

Writes into ``--out``: ``report.json`` (shots read, inside the DEM, on no data, outside;
statistics of DEM − shot before and after the alignment; the translation moving the DEM
onto the shots in metres east/north/up and in DEM posts (x right, y down), with its
formal sigma), ``shots.csv`` (per shot: longitude, latitude, time, track, shot height,
DEM height, DEM − shot before and after, status) and ``profile_track_<k>.png`` (shot
heights and the DEM before and after alignment along each track).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from demtool.stagerun import StageRun, sidecar_path

#: file suffixes read as altimetry tables by ``compare``
SHOT_SUFFIXES = (".csv", ".tab", ".txt")


def is_shot_table(path) -> bool:
    return Path(path).suffix.lower() in SHOT_SUFFIXES


def _grid_positions(dem, shots):
    """Fractional (col, row) of the shots on the DEM's grid, and the DEM's sphere radius."""
    from pyproj import CRS, Transformer

    from demtool.errors import InputError

    if dem.crs is None:
        raise InputError(f"{dem.path}: the DEM has no CRS: shots (longitude, latitude) "
                         "cannot be placed on it")
    crs = CRS.from_user_input(dem.crs)
    geodetic = crs.geodetic_crs
    radius = float(geodetic.ellipsoid.semi_major_metre)
    to_map = Transformer.from_crs(geodetic, crs, always_xy=True)
    lon = ((shots.lon + 180.0) % 360.0) - 180.0
    x, y = to_map.transform(lon, shots.lat)
    inverse = ~dem.transform
    col, row = inverse @ (np.asarray(x), np.asarray(y))
    return np.asarray(col) - 0.5, np.asarray(row) - 0.5, radius, crs


def run_compare_shots(dem_path: str | os.PathLike, shots_path: str | os.PathLike,
                      out_dir: str | os.PathLike, params=None, *,
                      resolved: dict[str, Any] | None = None) -> dict[str, Any]:
    """Compare a DEM with altimetry shots; write the report folder (module docstring)."""
    from demtool import io as dio
    from demtool.compare.altimetry import (
        align_to_shots,
        difference_statistics,
        sample_bilinear,
    )
    from demtool.compare.params import CompareParams
    from demtool.errors import InputError
    from demtool.io.altimetry import BODY_TOLERANCE, read_shots
    from demtool.logs import get_logger

    params = params or CompareParams()
    params.check()
    out = Path(out_dir)
    log = get_logger("compare")
    shots = read_shots(shots_path)
    dem = _read_dem(dem_path)
    col, row, sphere, crs = _grid_positions(dem, shots)
    if shots.radius is not None:
        median = float(np.median(shots.radius))
        if abs(median - sphere) > BODY_TOLERANCE * sphere:
            raise InputError(f"{shots_path}: the shots' radii (median {median / 1e3:.1f} km) "
                             f"are far from the DEM's body ({sphere / 1e3:.1f} km, "
                             f"{Path(dem_path).name}): altimetry of another body?")
        heights = shots.radius - sphere
    else:
        heights = shots.height
    data = dem.data.astype(np.float64)
    h, w = data.shape
    inside = (col >= 0) & (row >= 0) & (col <= w - 1) & (row <= h - 1)
    before = sample_bilinear(data, col, row)
    on_data = inside & np.isfinite(before)
    diff = before - heights
    a, _, _, _, e, _ = tuple(dem.transform)[:6]
    post = (abs(a), abs(e))
    alignment = align_to_shots(data, col, row, heights, post_m=post)
    after = alignment.residuals
    shift = alignment.shift_m
    report = {
        "dem": str(dem_path), "shots": str(shots_path), "crs": crs.to_string(),
        "reference_radius_m": sphere,
        "shots_read": len(shots), "shots_on_dem": int(np.count_nonzero(on_data)),
        "shots_on_no_data": int(np.count_nonzero(inside & ~np.isfinite(before))),
        "shots_outside": int(np.count_nonzero(~inside)),
        "tracks": int(len(np.unique(shots.track))) if len(shots.track) else 0,
        "difference_before": difference_statistics(diff),
        "alignment": {
            "method": "translation (Gauss-Newton on the bilinear DEM, 3 NMAD trimming)",
            "rotation": "not solved",
            "horizontal_solved": alignment.horizontal,
            **({"note": alignment.note} if alignment.note else {}),
            "shift_m": {"east": float(shift[0]), "north": float(shift[1]),
                        "up": float(shift[2])},
            "sigma_m": {"east": float(alignment.sigma_m[0]),
                        "north": float(alignment.sigma_m[1]),
                        "up": float(alignment.sigma_m[2])},
            "shift_posts": {"x_right": float(shift[0] / post[0]),
                            "y_down": float(-shift[1] / post[1])},
            "shots_used": alignment.used, "converged": alignment.converged,
            "sigma_note": "formal (shots independent): a lower bound"},
        "difference_after": difference_statistics(after),
        "sign": "DEM minus shots, metres above the DEM's reference sphere",
    }
    log.info("%d shots: %d on the DEM, %d on no data, %d outside; DEM - shots median "
             "%.2f m, NMAD %.2f m; shift E %.2f N %.2f U %.2f m (sigma %.2f %.2f %.2f)",
             len(shots), report["shots_on_dem"], report["shots_on_no_data"],
             report["shots_outside"], report["difference_before"].get("median_m", np.nan),
             report["difference_before"].get("nmad_m", np.nan), *shift, *alignment.sigma_m)
    if alignment.note:
        log.warning("%s", alignment.note)
    if not report["shots_on_dem"]:
        log.warning("no shot falls on the DEM's data: nothing compared")
    status = np.where(~inside, "outside", np.where(on_data, "on DEM", "no data"))
    lines = ["lon,lat,time_et,track,shot_height_m,dem_height_m,dem_minus_shot_m,"
             "after_alignment_m,status"]
    for k in range(len(shots)):
        t = "" if shots.time is None else f"{shots.time[k]:.6f}"
        lines.append(",".join([f"{shots.lon[k]:.7f}", f"{shots.lat[k]:.7f}", t,
                               str(int(shots.track[k]) if len(shots.track) else 0),
                               f"{heights[k]:.3f}", _num(before[k]), _num(diff[k]),
                               _num(after[k]), str(status[k])]))
    figures = _profiles(shots, col, row, heights, data, shift, post) if params.plots else {}
    run = StageRun("compare", params, resolved=resolved,
                   inputs={"DEM": dem_path, "SHOTS": shots_path}, folders={"--out": out_dir},
                   outputs={"--out": [out / n for n in ("report.json", "shots.csv",
                                                        *figures)],
                            "sidecar": sidecar_path(out / "report.json")})
    provenance = run.provenance
    with run.transaction():
        dio.write_json(out / "report.json", report)
        with dio.atomic_path(out / "shots.csv") as temporary:
            temporary.write_text("\n".join(lines) + "\n", encoding="utf-8")
        outputs = [out / "report.json", out / "shots.csv"]
        for name, figure in figures.items():
            with dio.atomic_path(out / name) as temporary:
                figure.savefig(temporary, dpi=100, format="png")
            outputs.append(out / name)
        provenance.write_sidecar(out / "report.json", report, outputs=outputs)
    return report


def _read_dem(path):
    """The DEM's raster, heights above its sphere (a radius DEM less the radius), as
    ``compare`` reads every DEM."""
    import dataclasses

    from demtool import io as dio
    from demtool.compare.planetary import radius_offset
    from demtool.sensors.isis_map import refuse_image_as_dem

    refuse_image_as_dem(path, "DEM")
    raster = dio.read_raster(path, what="DEM")
    offset = radius_offset(path, raster.crs, raster.data, "DEM")
    if offset:
        raster = dataclasses.replace(raster, data=(raster.data - offset).astype(np.float32))
    return raster


def _num(value) -> str:
    return f"{value:.3f}" if np.isfinite(value) else ""


def _profiles(shots, col, row, heights, dem, shift, post) -> dict:
    """One figure per track: shot heights, the DEM before and after the alignment,
    against the distance along the track (km)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    from demtool.compare.altimetry import sample_bilinear

    figures = {}
    tracks = shots.track if len(shots.track) else np.zeros(len(shots), dtype=int)
    for track in np.unique(tracks):
        sel = np.flatnonzero(tracks == track)
        if shots.time is not None:
            sel = sel[np.argsort(shots.time[sel])]
        xs = col[sel] * post[0]
        ys = row[sel] * post[1]
        along = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(xs), np.diff(ys)))]) / 1e3
        before = sample_bilinear(dem, col[sel], row[sel])
        after = sample_bilinear(dem, col[sel] - shift[0] / post[0],
                                row[sel] + shift[1] / post[1]) + shift[2]
        if not np.any(np.isfinite(before)):
            continue
        figure = Figure(figsize=(8, 3.5))
        axes = figure.add_subplot()
        axes.plot(along, heights[sel], ".", ms=3, color="k", label="shots")
        axes.plot(along, before, "-", color="tab:blue", lw=1, label="DEM")
        axes.plot(along, after, "-", color="tab:orange", lw=1, label="DEM aligned")
        axes.set_xlabel("distance along the track (km)")
        axes.set_ylabel("height (m)")
        axes.set_title(f"track {int(track)}: {len(sel)} shots")
        axes.legend(loc="best", fontsize=8)
        figure.tight_layout()
        figures[f"profile_track_{int(track)}.png"] = figure
    return figures
