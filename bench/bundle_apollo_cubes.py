"""`demtool bundle` on the two Apollo 15 Metric Camera cubes with SPICE attached.

Reads ``../shared/data/sensors/apollo15_cubes`` (relative to the repository root;
skipped with a message when absent).  The cubes are their own sensor models: the pair,
which COLMAP's two-view initialiser rejected before (issue 14), is matched by footprint
overlap, triangulated with the SPICE poses and adjusted with position/pointing priors.
Target (issue 14): the pair registers; the mean reprojection error and each image's
change of position (m) and pointing (mrad) are reported.  Wall time on a shared 2-core
machine.

Usage: ``.venv/bin/python bench/bundle_apollo_cubes.py``
"""

from __future__ import annotations

import tempfile
from pathlib import Path

CUBES = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "sensors" / \
    "apollo15_cubes"


def main() -> None:
    cubes = sorted(CUBES.glob("*.cub")) if CUBES.is_dir() else []
    if len(cubes) < 2:
        print(f"skipped: Apollo 15 cubes not found in {CUBES.resolve()}")
        return
    from demtool.bundle.params import BundleParams
    from demtool.bundle.run import run_bundle

    with tempfile.TemporaryDirectory() as scratch:
        work = Path(scratch)
        summary = run_bundle(cubes, work / "bundle.npz", BundleParams(matcher="spatial"),
                             adjusted_dir=work / "adjusted")
    print(f"registered {summary['registered_count']}/{summary['image_count']} "
          f"(target 2/2); {summary['points']} tie points; reprojection error RMS "
          f"{summary['initial_rms_reprojection_error_px']:.3f} px with the SPICE poses, "
          f"mean {summary['mean_reprojection_error_px']:.3f} px / median "
          f"{summary['median_reprojection_error_px']:.3f} px adjusted "
          f"(priors {summary['position_sigma_m']:g} m, {summary['pointing_sigma_mrad']:g} "
          f"mrad); {summary['time_s']:.1f} s")
    print(f"| {'image':<20} | obs | mean residual px | position change m | "
          "pointing change mrad |")
    print(f"|{'-' * 22}|-----|------------------|-------------------|"
          "----------------------|")
    for name, row in summary["images"].items():
        print(f"| {name:<20} | {row['observations']} | {row['mean_residual_px']:.3f} | "
              f"{row['position_change_m']:.1f} | {row['pointing_change_mrad']:.3f} |")


if __name__ == "__main__":
    main()
