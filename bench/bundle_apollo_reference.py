"""Issue 27: the Apollo 15 cube pair adjusted with LOLA as ``--reference-dem``.

Reads ``../shared/data/sensors/apollo15_cubes`` (AS15-M-0297_crop, 0298_crop: ISIS
cubes with SPICE) and ``../shared/data/dems/ldem_4_reduced.cub`` (LOLA radii, 22 km
posts); skipped with a message when absent (``DEMTOOL_SHARED_DATA`` points elsewhere).

Three adjustments of the pair (``bundle --matcher spatial``, priors 100 m / 1 mrad):
priors only; LOLA with one σ for every tie point (``--reference-dem-sigma`` 10 m, the
tie-point σ before issue 27); LOLA with the defaults (10 m plus the DEM's
interpolation error, bilinear's bound post² / 8 × local curvature and the share of post
spacing × local slope it leaves, measured on LOLA itself).
Each row: the mean tie residual, each camera's move in units of its prior σ, the
tie points' heights minus LOLA (median, NMAD) and, through the adjusted models,
``rectify`` → ``sgm`` → ``dem`` (the calibrated sensor route) and that DEM minus LOLA
(median, NMAD, over the DEM's cells, LOLA interpolated there; and at LOLA's posts, the
DEM averaged over each LOLA cell, as gridded altimetry is compared).  Targets (issue
27, defaults): |median| < 100 m, NMAD ≤ 350 m, mean tie residual ≤ 0.15 px.

Usage: ``.venv/bin/python bench/bundle_apollo_reference.py [--no-dem]
[--cases priors,flat,defaults]``
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import numpy as np

DATA = Path(os.environ.get("DEMTOOL_SHARED_DATA", "")
            or Path(__file__).resolve().parents[1] / ".." / "shared" / "data")
CUBES = DATA / "sensors" / "apollo15_cubes"
LEFT, RIGHT = CUBES / "AS15-M-0297_crop.cub", CUBES / "AS15-M-0298_crop.cub"
LOLA = DATA / "dems" / "ldem_4_reduced.cub"


def nmad(values: np.ndarray) -> float:
    values = values[np.isfinite(values)]
    return float(1.4826 * np.median(np.abs(values - np.median(values))))


def pair_dem(work: Path, sensor_left: Path, sensor_right: Path) -> Path:
    """rectify → sgm → dem (defaults) of the cube pair through the given sensor models;
    writes ``work/dem.tif`` and its measured/filled mask ``work/filled.tif``."""
    from demtool.dem.params import DemParams
    from demtool.dem.run import run_dem
    from demtool.rectify.params import RectifyParams
    from demtool.rectify.run import run_rectify
    from demtool.sgm.params import SgmParams
    from demtool.sgm.run import run_sgm

    rect = work / "rect"
    run_rectify(LEFT, RIGHT, rect, RectifyParams(), sensor_left=sensor_left,
                sensor_right=sensor_right)
    run_sgm(rect / "left_rect.tif", rect / "right_rect.tif", work / "disparity.tif",
            SgmParams(), rectify=rect / "rectify.npz")
    run_dem(work / "dem.tif", DemParams(), disparity_path=work / "disparity.tif",
            rectify_path=rect / "rectify.npz", mask_path=work / "filled.tif")
    return work / "dem.tif"


def dem_minus_lola(work: Path, adjusted: Path, surface) -> np.ndarray:
    """rectify → sgm → dem through the adjusted models; DEM − LOLA per valid cell."""
    from demtool import io as dio
    from demtool.maps import map_to_xyz, to_pyproj_crs

    dem = dio.read_raster(pair_dem(work, adjusted / f"{LEFT.stem}.json",
                                   adjusted / f"{RIGHT.stem}.json"))
    filled = dio.read_raster(work / "filled.tif").data
    heights = dem.data
    rows, cols = np.nonzero(np.isfinite(heights) & (filled == 0))
    t = dem.transform
    x = t.c + (cols + 0.5) * t.a
    y = t.f + (rows + 0.5) * t.e
    xyz = map_to_xyz(to_pyproj_crs(dem.crs), x, y, heights[rows, cols].astype(np.float64))
    return (surface.residuals(xyz), at_lola_posts(surface, xyz, abs(t.a * t.e)),
            _relief(x, y, heights[rows, cols]), _relief(x, y, surface.dem_heights(xyz)))


def at_lola_posts(surface, xyz: np.ndarray, cell_area_m2: float) -> tuple[np.ndarray, ...]:
    """DEM − LOLA at LOLA's posts: the DEM's cells (body-fixed points ``xyz``, each
    ``cell_area_m2``) averaged over each LOLA cell they fall in (at least half of it
    measured; :func:`demtool.compare.coarse.block_mean`) minus LOLA there (its post, or
    the measured part's centroid in a partly measured cell:
    :func:`demtool.compare.coarse.reference_at_blocks`); also each post's measured share,
    the difference to the post itself and the post's height."""
    from demtool.compare.coarse import block_mean, reference_at_blocks
    from demtool.maps import xyz_to_lonlat_height

    _, _, height = xyz_to_lonlat_height(xyz, radii=surface.radius)
    rows, cols = surface.pixels(xyz)
    post = surface.post_spacing_m(np.nanmean(xyz, axis=0))
    block = block_mean(height, rows, cols, surface.heights.shape, post ** 2 / cell_area_m2)
    diff = block.mean - reference_at_blocks(surface.heights, block)
    keep = np.isfinite(diff)
    return (diff[keep], block.filled[keep], (block.mean - surface.heights)[keep],
            surface.heights[keep])


def _relief(x: np.ndarray, y: np.ndarray, heights: np.ndarray) -> float:
    """NMAD of heights about their best-fitting plane, metres (the relief a DEM shows)."""
    design = np.column_stack([np.ones_like(x), x - x.mean(), y - y.mean()])
    good = np.isfinite(heights)
    coef, *_ = np.linalg.lstsq(design[good], heights[good], rcond=None)
    return nmad(heights[good] - design[good] @ coef)


def dem_at_points(dem_path: Path, points: np.ndarray, radius: float) -> np.ndarray:
    """The DEM's height at each bundle point's cell minus the point's height, metres
    (NaN off the DEM): whether the dense route reproduces the block's own points."""
    from demtool import io as dio
    from demtool.maps import lonlat_to_map, to_pyproj_crs, xyz_to_lonlat_height

    dem = dio.read_raster(dem_path)
    lon, lat, height = xyz_to_lonlat_height(points, radii=radius)
    x, y = lonlat_to_map(to_pyproj_crs(dem.crs), lon, lat)
    inverse = ~dem.transform
    cols = np.floor(inverse.a * x + inverse.b * y + inverse.c).astype(int)
    rows = np.floor(inverse.d * x + inverse.e * y + inverse.f).astype(int)
    inside = (rows >= 0) & (rows < dem.data.shape[0]) & (cols >= 0) & (cols < dem.data.shape[1])
    out = np.full(len(points), np.nan)
    out[inside] = dem.data[rows[inside], cols[inside]] - height[inside]
    return out


def case(work: Path, label: str, params, *, reference: bool, flat_sigma: bool,
         surface, with_dem: bool) -> dict:
    import demtool.bundle.run_reference as reference_module
    from demtool import io as dio
    from demtool.bundle.run import run_bundle

    original = reference_module.read_reference_surface
    if flat_sigma:  # issue 27's "before": one σ for every tie point
        def flat(*args, **kwargs):
            return original(*args, **{**kwargs, "slope_sigma": False})
        reference_module.read_reference_surface = flat
    try:
        folder = work / label.replace(" ", "_")
        summary = run_bundle([LEFT, RIGHT], folder / "bundle.npz", params,
                             adjusted_dir=folder / "adjusted",
                             reference_dem=LOLA if reference else None)
    finally:
        reference_module.read_reference_surface = original
    points = dio.read_npz(folder / "bundle.npz", "bundle")["points"]
    tie = surface.residuals(points)
    row = {"label": label, "mean_px": summary["mean_reprojection_error_px"],
           "moves": [(r["position_change_m"], r["position_change_prior_sigmas"],
                      r["pointing_change_mrad"], r["pointing_change_prior_sigmas"])
                     for r in summary["images"].values()],
           "tie_median": float(np.nanmedian(tie)), "tie_nmad": nmad(tie),
           "tie_sigma": summary.get("reference_dem", {}).get("tie_point_sigma_median_m")}
    if with_dem:
        diff, posts, dem_relief, lola_relief = dem_minus_lola(folder, folder / "adjusted",
                                                              surface)
        at_ties = dem_at_points(folder / "dem.tif", points, surface.radius)
        row.update(dem_median=float(np.nanmedian(diff)), dem_nmad=nmad(diff),
                   dem_cells=int(np.isfinite(diff).sum()), **_post_row(*posts),
                   dem_at_ties=float(np.nanmedian(at_ties)), dem_relief=dem_relief,
                   lola_relief=lola_relief, **coregistered(folder))
    return row


def coregistered(folder: Path) -> dict:
    """``demtool compare`` of the DEM with LOLA (radii read as heights) at the DEM's cells:
    its Nuth & Kääb shift, and the median / NMAD after it — how much of DEM − LOLA is a
    horizontal offset of the block, which the height ties of ``--reference-dem`` do not
    constrain."""
    from demtool.compare.params import CompareParams
    from demtool.compare.run import run_compare

    report = run_compare(folder / "dem.tif", LOLA, folder / "compare",
                         CompareParams(grid="dem", plots=False))
    cell_x, cell_y = (abs(v) for v in report["grid"]["spacing_m"])
    shift = report["shift"]
    failed = report["alignment"]["method"] == "none"
    return {"aligned_median": report["median"], "aligned_nmad": report["nmad"],
            "shift_m": (shift["dx_px"] * cell_x, shift["dy_px"] * cell_y, shift["dz"]),
            "alignment_failed": report["warnings"][0] if failed else None}


def _post_row(diff: np.ndarray, filled: np.ndarray, at_post: np.ndarray,
              lola: np.ndarray) -> dict:
    if not diff.size:
        return {"posts": 0}
    # the DEM's relief at LOLA's resolution: its cell means regressed on LOLA's posts
    slope = float(np.polyfit(lola, lola + at_post, 1)[0]) if diff.size >= 3 else float("nan")
    return {"posts": int(diff.size), "post_median": float(np.median(diff)),
            "post_slope": slope,
            "post_nmad": nmad(diff), "post_rms": float(np.sqrt(np.mean(diff ** 2))),
            "post_values": [round(float(v)) for v in diff],
            "post_filled": [round(float(v), 2) for v in filled],
            "post_at_post_values": [round(float(v)) for v in at_post]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-dem", action="store_true", help="skip rectify/sgm/dem")
    parser.add_argument("--cases", default="priors,flat,defaults",
                        help="comma-separated subset of priors, flat, defaults")
    args = parser.parse_args()
    if not (LEFT.is_file() and RIGHT.is_file() and LOLA.is_file()):
        print(f"skipped: needs {CUBES} and {LOLA}")
        return
    from demtool.bundle.params import BundleParams
    from demtool.bundle.run_reference import read_reference_surface
    from demtool.sensors import read_sensor

    surface = read_reference_surface(LOLA, [read_sensor(LEFT), read_sensor(RIGHT)],
                                     [LEFT, RIGHT], sigma=1.0, slope_sigma=False)
    params = BundleParams(matcher="spatial")
    rows = []
    with tempfile.TemporaryDirectory(prefix="demtool-apollo-ref-") as folder:
        work = Path(folder)
        cases = {"priors": ("priors only", False, False),
                 "flat": ("LOLA, sigma 10 m flat", True, True),
                 "defaults": ("LOLA, defaults", True, False)}
        for key in args.cases.split(","):
            label, reference, flat = cases[key]
            rows.append(case(work, label, params, reference=reference, flat_sigma=flat,
                             surface=surface, with_dem=not args.no_dem))
            print(rows[-1], flush=True)
    print("\nApollo 15 cube pair, bundle --matcher spatial (priors 100 m / 1 mrad)")
    print("| case | mean tie px | moves 0297 / 0298: m (σ), mrad (σ) | tie-point σ median m "
          "| ties − LOLA median / NMAD m | DEM − LOLA median / NMAD m (cells) |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        moves = "; ".join(f"{p:.0f} m ({ps:.1f}), {w:.2f} mrad ({ws:.1f})"
                          for p, ps, w, ws in r["moves"])
        sigma = "–" if r["tie_sigma"] is None else f"{r['tie_sigma']:.0f}"
        dem = (f"{r['dem_median']:+.0f} / {r['dem_nmad']:.0f} ({r['dem_cells']})"
               if "dem_median" in r else "–")
        print(f"| {r['label']} | {r['mean_px']:.3f} | {moves} | {sigma} | "
              f"{r['tie_median']:+.0f} / {r['tie_nmad']:.0f} | {dem} |")
    print("| target (defaults) | ≤ 0.15 | warning above 3 σ | | | |median| < 100 / ≤ 350 |")
    print("\nDEM − LOLA two ways: at the DEM's cells (LOLA interpolated bilinearly, as above) "
          "and at LOLA's posts (the DEM averaged over each LOLA cell, ≥ 50 % measured)")
    print("| case | DEM cells: median / NMAD m (cells) | LOLA posts: median / NMAD / RMS m "
          "(posts) | each post m (measured share; vs the post itself) | DEM cell means on "
          "LOLA posts, slope |")
    print("|---|---|---|---|---|")
    for r in rows:
        if r.get("posts"):
            each = ", ".join(f"{v:+d} ({f:.2f}; {p:+d})" for v, f, p in zip(
                r["post_values"], r["post_filled"], r["post_at_post_values"], strict=True))
            print(f"| {r['label']} | {r['dem_median']:+.0f} / {r['dem_nmad']:.0f} "
                  f"({r['dem_cells']}) | {r['post_median']:+.0f} / {r['post_nmad']:.0f} / "
                  f"{r['post_rms']:.0f} ({r['posts']}) | {each} | {r['post_slope']:.2f} |")
    print("\nDEM − LOLA after compare's co-registration (Nuth & Kääb, at the DEM's cells)")
    print("| case | compare's shift dx / dy / dz m (grid columns, rows) | median / NMAD m after |")
    print("|---|---|---|")
    for r in rows:
        if r.get("alignment_failed"):
            print(f"| {r['label']} | {r['alignment_failed']} | – |")
        elif "aligned_nmad" in r:
            print(f"| {r['label']} | " + " / ".join(f"{v:+.0f}" for v in r["shift_m"])
                  + f" | {r['aligned_median']:+.0f} / {r['aligned_nmad']:.0f} |")
    print("\nWhat limits DEM − LOLA (the DEM's measured cells; relief = NMAD about a plane)")
    print("| case | DEM − its own tie points, median m | DEM relief m | LOLA relief at the "
          "same cells m | tie-point σ used, median m (defaults: 10 m ⊕ LOLA interpolation) |")
    print("|---|---|---|---|---|")
    for r in rows:
        if "dem_at_ties" in r:
            sigma = "–" if r["tie_sigma"] is None else f"{r['tie_sigma']:.0f}"
            print(f"| {r['label']} | {r['dem_at_ties']:+.1f} | {r['dem_relief']:.0f} | "
                  f"{r['lola_relief']:.0f} | {sigma} |")
    print("LOLA's posts here are 22.7 km (ldem_4 reduced 3 x 3 by averaging: cell means) "
          "over a 63 km footprint. The DEM passes through its own tie points to a few "
          "metres and shows twice LOLA's relief at its cells; at LOLA's own posts, where "
          "the relief between posts no longer counts, DEM − LOLA still spreads by hundreds "
          "of metres over the few posts the DEM covers (table above).")


if __name__ == "__main__":
    main()
