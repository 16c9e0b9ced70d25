"""The HiRISE ``cam2map`` pair of ``../shared/data/sensors/hirise_mapprojected`` through the
map-projected route: ``sgm`` on the two ISIS cubes, then ``dem --mapprojected`` with each
cube's raw camera read from its own tables (issue 24).

A weak pair (about 4° between the views): the check is that the route runs and states
its precision.  Printed: the surface each cube is raised to (the Mapping group's
ellipsoid; cam2map's MOLA shape model is named in the label but not shipped), the
convergence and the height one pixel of parallax stands for, the ray gaps of the
triangulation, the DEM's height range and the NMAD of its heights about their best-fit
plane (over ~170 m the terrain's own relief is small: mostly matching noise).  The
automatic disparity range is refused on this pair (its SIFT matches are offset 0.6 cells
north-south with a 1.3-cell spread, over sgm's 1-D limits), so the range is given:
``--min-disparity -8 --num-disparities 24`` (matches: −2.3 … 6.3 cells).
Skips cleanly when the data are absent.

    python bench/hirise_cam2map.py [--keep DIR]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
PAIR = ROOT / ".." / "shared" / "data" / "sensors" / "hirise_mapprojected"
LEFT = "ESP_014038_1415_RED0.30421_33069.boulder_shift.before.cub"
RIGHT = "ESP_031022_1415_RED1.34517_37165.boulder_shift.after.cub"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keep", type=Path, help="write the outputs here (kept)")
    args = parser.parse_args()
    left, right = PAIR / LEFT, PAIR / RIGHT
    if not (left.exists() and right.exists()):
        print(f"skipped: {PAIR} is absent")
        return
    import rasterio

    from demtool.dem.params import DemParams
    from demtool.dem.run import run_dem
    from demtool.sgm.params import SgmParams
    from demtool.sgm.run import run_sgm

    with tempfile.TemporaryDirectory() as scratch:
        out = args.keep or Path(scratch)
        out.mkdir(parents=True, exist_ok=True)
        start = time.perf_counter()
        run_sgm(left, right, out / "disparity.tif",
                SgmParams(min_disparity=-8, num_disparities=24))
        sgm_s = time.perf_counter() - start
        start = time.perf_counter()
        summary = run_dem(out / "dem.tif", DemParams(), disparity_path=out / "disparity.tif",
                          mapprojected=(left, right))
        dem_s = time.perf_counter() - start
        with rasterio.open(out / "dem.tif") as src:
            z = src.read(1)
    rows, cols = np.nonzero(np.isfinite(z))
    design = np.column_stack([rows, cols, np.ones_like(rows)]).astype(np.float64)
    coef, *_ = np.linalg.lstsq(design, z[rows, cols], rcond=None)
    residual = z[rows, cols] - design @ coef
    nmad = 1.4826 * float(np.median(np.abs(residual - np.median(residual))))
    print(f"surface: {summary['surfaces'][0]}")
    print(f"{'quantity':44s} {'value':>12s}")
    for name, value in [
            ("convergence at the map centre (deg)", summary.get("convergence_deg")),
            ("height per pixel of parallax (m)", summary.get("height_per_px_parallax_m")),
            ("map GSD (m)", summary["gsd_m"]),
            ("valid disparities", summary["valid_disparities"]),
            ("median ray gap (m)", summary["median_ray_gap_m"]),
            ("max ray gap kept (m, default)", summary["max_ray_gap_m"]),
            ("rays rejected by the gap", summary["rejected_ray_gap"]),
            ("measured fraction of the overlap", summary["measured_fraction_of_overlap"]),
            ("height median (m above the 3396.19 km sphere)", summary["height_median_m"]),
            ("height range (m)", summary["height_max_m"] - summary["height_min_m"]),
            ("NMAD about the best-fit plane (m)", nmad),
            ("sgm wall time (s)", sgm_s), ("dem wall time (s)", dem_s)]:
        print(f"{name:44s} {value:>12.4g}")


if __name__ == "__main__":
    main()
