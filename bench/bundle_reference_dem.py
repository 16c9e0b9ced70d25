"""Issue 14, check 2: pose accuracy of ``bundle`` with and without a reference DEM.

An analytic frame block (tests/bundle/orbital.py: six frame cameras over the Moon's
sphere, tie points on hilly terrain seen through the true models with Gaussian noise,
no rendering) with pose priors 50 m / 0.5 mrad off the truth, adjusted by
:func:`demtool.bundle.priors.adjust_with_priors` (the core of ``bundle --sensors``)
with priors only, and with a reference DEM (the terrain at coarse posts with noise,
like LOLA: ``bundle --reference-dem``).  Reported per case: the largest position (m)
and pointing (mrad) error of the adjusted models against the truth (target: 5 m /
0.05 mrad), the largest image displacement of ground points between the adjusted and
the true models (pixels and metres on the ground: what a DEM made with the adjusted
models is off by) and the largest a-posteriori standard deviations (the covariance of
the adjustment: what the data can determine).

Cases: orbital geometry (100 km, the field of LRO WAC / Apollo Metric, 2048 px) and the
1 km geometry of ``synth --sensor frame`` (7–15° field, terrain scaled down 100 ×);
independent errors and pairwise opposite (zero-mean) errors; then the orbital case
with one thing changed at a time (field, image size, tie-point noise and count, DEM
posts and noise, relief).  The rendered end-to-end check (images, SIFT tie points,
the DEM from the adjusted ISDs) is bench/bundle_priors_dem.py with --reference-post.

Usage: ``.venv/bin/python bench/bundle_reference_dem.py [--quick]``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

ORBITAL = dict(altitude=100e3, field_deg=60.0, size=2048, spacing=30e3, noise_px=0.2,
               count=12000, dem_post_m=500.0, dem_noise_m=3.0, dem_sigma_m=5.0,
               relief_m=1000.0, scale=1.0)
#: synth --sensor frame's default block: 1 km up, 256–512 px over 128–256 m, views a few
#: hundred metres apart (here 100 m); the terrain 100 × smaller (10 m hills, 70–410 m)
NEAR = dict(ORBITAL, altitude=1e3, field_deg=14.6, size=512, spacing=100.0, count=6000,
            dem_post_m=8.0, dem_noise_m=0.2, dem_sigma_m=0.3, relief_m=10.0, scale=0.01)


def run_case(case: dict, *, reference: bool, zero_mean: bool, seed: int = 1) -> dict:
    """Adjust one block; the errors and sigmas of the module docstring."""
    from demtool.bundle.offsets import rotation_vector
    from demtool.bundle.priors import AdjustedSensor, adjust_with_priors
    from demtool.bundle.surface import ReferenceSurface
    from tests.bundle import orbital

    truth = orbital.true_models(altitude=case["altitude"], field_deg=case["field_deg"],
                                size=case["size"], spacing=case["spacing"])
    half = case["altitude"] * np.tan(np.radians(0.5 * case["field_deg"])) + case["spacing"]
    xyz = orbital.ground_points(case["count"], half_width_m=half, amplitude=case["relief_m"],
                                scale=case["scale"])
    obs, _ = orbital.tie_observations(truth, xyz, noise_px=case["noise_px"])
    surface = None
    if reference:
        heights, transform, crs = orbital.reference_dem(
            spacing_m=case["dem_post_m"], noise_m=case["dem_noise_m"], half_width_m=1.2 * half,
            amplitude=case["relief_m"], scale=case["scale"])
        surface = ReferenceSurface(heights, transform, crs, orbital.RADIUS,
                                   case["dem_sigma_m"])
    prior = orbital.perturbed(truth, zero_mean=zero_mean, seed=seed)
    started = time.perf_counter()
    adjusted = adjust_with_priors(prior, obs, position_sigma=50.0, pointing_sigma=0.5,
                                  surface=surface)
    wall = time.perf_counter() - started
    rows = []
    for model, true, offset in zip(prior, truth, adjusted.offsets, strict=True):
        moved = AdjustedSensor(model, offset)
        line0, sample0 = true.ground_to_image(xyz)
        line1, sample1 = moved.ground_to_image(xyz)
        seen = (line0 > 0) & (line0 < true.lines) & (sample0 > 0) & (sample0 < true.samples)
        rows.append((np.linalg.norm(moved.camera_center(0.0) - true.position),
                     np.linalg.norm(rotation_vector(offset.matrix @ model.rotation
                                                    @ true.rotation.T)) * 1e3,
                     np.max(np.hypot(line1 - line0, sample1 - sample0)[seen])))
    rows = np.array(rows)
    gsd = case["altitude"] * 2 * np.tan(np.radians(0.5 * case["field_deg"])) / case["size"]
    sigmas = adjusted.sigmas().max(axis=0)
    return {"position_m": rows[:, 0].max(), "pointing_mrad": rows[:, 1].max(),
            "image_px": rows[:, 2].max(), "ground_m": rows[:, 2].max() * gsd,
            "sigma_position_m": sigmas[0], "sigma_pointing_mrad": sigmas[1],
            "points": adjusted.observations.point_count, "gsd_m": gsd, "time_s": wall}


HEADER = ("| case | DEM | errors | max position m | max pointing mrad | max image px "
          "(ground m) | σ position m | σ pointing mrad | tie points | time s |\n"
          "|---|---|---|---|---|---|---|---|---|---|")


def row(label: str, r: dict, *, reference: bool, zero_mean: bool) -> str:
    return (f"| {label} | {'yes' if reference else 'no'} | "
            f"{'zero-mean' if zero_mean else 'independent'} | {r['position_m']:.2f} | "
            f"{r['pointing_mrad']:.4f} | {r['image_px']:.3f} ({r['ground_m']:.2f}) | "
            f"{r['sigma_position_m']:.2f} | {r['sigma_pointing_mrad']:.4f} | {r['points']} | "
            f"{r['time_s']:.0f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="main table only")
    args = parser.parse_args()
    print("Pose errors after bundle with priors 50 m / 0.5 mrad (target: 5 m / 0.05 mrad)")
    print(HEADER)
    for label, case in (("orbital 100 km, 60°, 2048 px", ORBITAL),
                        ("1 km, 14.6°, 512 px", NEAR)):
        for zero_mean in (False, True):
            for reference in (False, True):
                r = run_case(case, reference=reference, zero_mean=zero_mean)
                print(row(label, r, reference=reference, zero_mean=zero_mean), flush=True)
    if args.quick:
        return
    print("\nThe orbital case, one thing changed (independent errors, with the DEM)")
    print(HEADER)
    changes = [("field 20°", {"field_deg": 20.0}), ("field 40°", {"field_deg": 40.0}),
               ("field 74° (Apollo Metric)", {"field_deg": 74.0}),
               ("1024 px", {"size": 1024}), ("4096 px", {"size": 4096}),
               ("ties 0.1 px", {"noise_px": 0.1}), ("3000 ground points", {"count": 3000}),
               ("DEM 100 m posts, 1 m noise, σ 2 m",
                {"dem_post_m": 100.0, "dem_noise_m": 1.0, "dem_sigma_m": 2.0}),
               ("DEM 1 km posts, 5 m noise, σ 10 m",
                {"dem_post_m": 1000.0, "dem_noise_m": 5.0, "dem_sigma_m": 10.0}),
               ("relief 300 m", {"relief_m": 300.0}),
               ("relief 3 km", {"relief_m": 3000.0})]
    for label, change in changes:
        r = run_case(dict(ORBITAL, **change), reference=True, zero_mean=False)
        print(row(label, r, reference=True, zero_mean=False), flush=True)


if __name__ == "__main__":
    main()
