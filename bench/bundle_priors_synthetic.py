"""`demtool bundle --sensors` on a rendered synthetic frame block with perturbed ISDs.

Six 40° frame cameras 30 km above a textured spherical Moon with ±400 m hills
(``tests/bundle/frames.py``); the prior ISDs are 50 m and 0.5 mrad off the truth (in
opposite directions pairwise, so the block's mean pose is true: tie points cannot
see a common offset).  Target (issue 14): the adjusted ISDs within 5 m / 0.05 mrad of
the truth.  Accuracy depends on the pixel's angle: run at several image sizes.

Usage: ``.venv/bin/python bench/bundle_priors_synthetic.py [SIZE ...]`` (default 320 640)
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def run(size: int) -> None:
    from demtool.bundle.offsets import rotation_vector
    from demtool.bundle.params import BundleParams
    from demtool.bundle.run import run_bundle
    from demtool.sensors import read_sensor
    from tests.bundle import frames

    with tempfile.TemporaryDirectory() as scratch:
        work = Path(scratch)
        truth, images, isds = frames.write_block(work, size=size)
        start = time.perf_counter()
        summary = run_bundle(images, work / "bundle.npz",
                             BundleParams(matcher="spatial", position_sigma=50.0,
                                          pointing_sigma=0.5), sensors=isds,
                             adjusted_dir=work / "adjusted")
        wall = time.perf_counter() - start
        errors = []
        for true in truth:
            model = read_sensor(work / "adjusted" / f"{true.name}.json")
            errors.append((np.linalg.norm(model.position - true.position),
                           np.linalg.norm(rotation_vector(model.rotation @ true.rotation.T))
                           * 1e3))
    errors = np.array(errors)
    ifov = frames.SIZE * frames.PIXEL_MM / size / frames.FOCAL_MM * 1e3
    print(f"| {size} | {ifov:.2f} | {summary['points']} | "
          f"{summary['mean_reprojection_error_px']:.3f} | {errors[:, 0].max():.2f} | "
          f"{errors[:, 1].max():.3f} | {wall:.1f} |")


def main() -> None:
    sizes = [int(a) for a in sys.argv[1:]] or [320, 640]
    print("prior errors 50 m / 0.5 mrad; target: max error <= 5 m / 0.05 mrad")
    print("| size px | pixel mrad | tie points | mean residual px | max position error m "
          "| max pointing error mrad | time s |")
    print("|---|---|---|---|---|---|---|")
    for size in sizes:
        run(size)


if __name__ == "__main__":
    main()
