"""Calibrated frame stereo on real data: the Apollo 15 Metric Camera cubes (issue 11).

Runs ``rectify --sensor-left/--sensor-right`` (ISIS3 cubes with SPICE attached), ``sgm``
and ``dem`` (triangulation through the models onto the Moon's map) on
``../shared/data/sensors/apollo15_cubes/AS15-M-0297_crop.cub`` / ``0298``, and prints
the vertical residual under the SPICE, the fitted pointing correction, the median ray
gap, the share of the stereo overlap measured (target ≥ 50 %) and the DEM's height
range above the 1737.4 km sphere; then ``sgm`` again with ``--cost census`` on the same
rectified pair, and what each matched (issue 26: the default must match wherever census
does): the cost "auto" chose, the left–right-consistent fraction of the valid canvas,
the filled fractions and the pixels without a disparity.  Skips cleanly when the data
are absent.

    python bench/apollo15_stereo.py [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CUBES = ROOT / ".." / "shared" / "data" / "sensors" / "apollo15_cubes"
LEFT, RIGHT = CUBES / "AS15-M-0297_crop.cub", CUBES / "AS15-M-0298_crop.cub"


def run(folder: Path) -> dict:
    from demtool.dem.params import DemParams
    from demtool.dem.run import run_dem
    from demtool.rectify.params import RectifyParams
    from demtool.rectify.run import run_rectify
    from demtool.sgm.params import SgmParams
    from demtool.sgm.run import run_sgm

    rect = folder / "rect"
    times = {}
    start = time.perf_counter()
    run_rectify(LEFT, RIGHT, rect, RectifyParams(), sensor_left=LEFT, sensor_right=RIGHT)
    times["rectify"] = time.perf_counter() - start
    rectify = json.loads((rect / "rectify.npz.json").read_text())["summary"]
    start = time.perf_counter()
    run_sgm(rect / "left_rect.tif", rect / "right_rect.tif", folder / "disparity.tif",
            SgmParams(), rectify=rect / "rectify.npz")
    times["sgm"] = time.perf_counter() - start
    start = time.perf_counter()
    dem = run_dem(folder / "dem.tif", DemParams(), disparity_path=folder / "disparity.tif",
                  rectify_path=rect / "rectify.npz", error_path=folder / "ray_gap.tif",
                  mask_path=folder / "filled.tif")
    times["dem"] = time.perf_counter() - start
    run_sgm(rect / "left_rect.tif", rect / "right_rect.tif", folder / "disparity_census.tif",
            SgmParams(cost="census"), rectify=rect / "rectify.npz")
    matched = {label: json.loads((folder / f"{name}.tif.json").read_text())["summary"]
               for label, name in (("default", "disparity"), ("census", "disparity_census"))}
    return {"rectify": rectify, "dem": dem, "seconds": times, "sgm": matched}


def print_matched(sgm: dict) -> None:
    """What the default and ``--cost census`` matched (fractions of the valid canvas)."""
    print("\nsgm on the rectified pair: fractions of the valid left pixels")
    print(f"  {'cost':<8} {'used':<11} {'LR-consistent':>13} {'filled occ':>10} "
          f"{'filled mis':>10} {'none':>6}")
    for label, s in sgm.items():
        print(f"  {label:<8} {s.get('cost_used', label):<11} "
              f"{100 * s['lr_consistent_fraction']:12.1f}% "
              f"{100 * s['filled_occlusion_fraction']:9.1f}% "
              f"{100 * s['filled_mismatch_fraction']:9.1f}% {100 * s['invalid_fraction']:5.1f}%")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keep", type=Path, help="write the products here (default: a "
                        "temporary folder)")
    args = parser.parse_args()
    if not (LEFT.exists() and RIGHT.exists()):
        print(f"skipped: {CUBES} is absent (the Apollo 15 cubes are in ../shared/data)")
        return 0
    if args.keep:
        args.keep.mkdir(parents=True, exist_ok=True)
        result = run(args.keep)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            result = run(Path(tmp))
    r, d = result["rectify"], result["dem"]
    rows = [
        ("SIFT matches / agreeing with the models", f"{r['matches']} / {r['inliers']}", ""),
        ("vertical residual under the SPICE, RMS (median)",
         f"{r['rms_vertical_residual_before_px']:.2f} px "
         f"({r['median_vertical_residual_before_px']:+.2f} px)", ""),
        ("pointing correction of 0298 (rectified x, y, z)",
         ", ".join(f"{v:+.3f}" for v in r["pointing_correction_mrad"])
         + f" mrad (|ω| {r['pointing_correction_angle_mrad']:.3f})",
         "a few mrad"),
        ("vertical residual after rectification, RMS", f"{r['rms_vertical_residual_px']:.3f} px",
         "< 1 px"),
        ("median ray gap of the SIFT matches, SPICE as given / corrected",
         f"{r['median_ray_gap_spice_m']:.1f} m / {r['median_ray_gap_m']:.1f} m", "reported"),
        ("median ray gap of the dense points", f"{d['median_ray_gap_m']:.2f} m", "reported"),
        (f"rays rejected (gap > {d['max_ray_gap_m']:.1f} m) / behind a camera",
         f"{d['rejected_ray_gap']} / {d['behind_camera']}", ""),
        ("DEM", f"{d['shape'][1]} x {d['shape'][0]} at {d['gsd_m']:.1f} m, {d['crs'][:44]}",
         ""),
        ("stereo overlap measured", f"{100 * d['measured_fraction_of_overlap']:.1f} %",
         ">= 50 %"),
        ("heights above the 1737.4 km sphere",
         f"{d['height_min_m']:.0f} … {d['height_max_m']:.0f} m "
         f"(median {d['height_median_m']:.0f} m)", ""),
        ("time rectify / sgm / dem", " / ".join(f"{v:.1f} s"
                                                for v in result["seconds"].values()), ""),
    ]
    width = max(len(name) for name, _, _ in rows)
    print("Apollo 15 Metric AS15-M-0297 / 0298 (cubes, SPICE attached), calibrated route")
    for name, value, target in rows:
        print(f"{name:<{width}}  {value:<52} {target}")
    print_matched(result["sgm"])
    ok = d["measured_fraction_of_overlap"] >= 0.5
    default, census = result["sgm"]["default"], result["sgm"]["census"]
    matches = default["lr_consistent_fraction"] >= census["lr_consistent_fraction"] - 0.02
    print("PASS" if ok else "FAIL: less than half of the overlap measured")
    print("PASS: the default matches what census matches (within 2 points)" if matches
          else "FAIL: the default matches markedly less than --cost census")
    ok = ok and matches
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
