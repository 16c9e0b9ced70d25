"""Throughput of the sensor models: image_to_ground and ground_to_image, points per second,
and the time of ``dem``'s triangulation through two frame models for a 2048² disparity.

Targets (issue 11): ≥ 1 M points/s for a frame camera, ≥ 200 k points/s for a line
scanner, on 2 cores.  The models are the usgscsm test ISDs carried by the tests
(``tests/sensors/data``); when ``../shared/data/sensors`` exists the real-mission ISDs
(Apollo Metric frame, LRO NAC and CTX line scanners) are measured too.

    python bench/sensors.py [--points N] [--size 2048]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from demtool.sensors import read_sensor

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT / ".." / "shared" / "data" / "sensors"
MODELS = [("frame: usgscsm orbitalFramer", ROOT / "tests/sensors/data/orbitalFramer.json"),
          ("linescan: usgscsm orbitalLineScan", ROOT / "tests/sensors/data/orbitalLineScan.json"),
          ("frame: Apollo Metric (ALE)", SHARED / "ale/apollometric_isd.json"),
          ("frame: MESSENGER MDIS (ALE)", SHARED / "ale/messmdis_isd.json"),
          ("linescan: LRO NAC (ALE)", SHARED / "ale/lrolroc_isd.json"),
          ("linescan: MRO CTX (ALE)", SHARED / "ale/ctx_isd.json")]


def best_of(fn, repeats=3):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--size", type=int, default=2048,
                        help="side of the disparity triangulated through two frame models")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    print(f"{'model':38s} {'image_to_ground':>16s} {'ground_to_image':>16s} "
          f"{'max round trip':>15s}")
    print(f"{'':38s} {'points/s':>16s} {'points/s':>16s} {'px':>15s}")
    for label, path in MODELS:
        if not path.exists():
            print(f"{label:38s} (skipped: {path} absent)")
            continue
        model = read_sensor(path)
        n = args.points
        lines = rng.uniform(0.5, model.lines - 0.5, n)
        samples = rng.uniform(0.5, model.samples - 0.5, n)
        ground = model.image_to_ground(lines, samples)
        t_i2g = best_of(lambda m=model, ln=lines, sp=samples: m.image_to_ground(ln, sp))
        t_g2i = best_of(lambda m=model, g=ground: m.ground_to_image(g))
        line, sample = model.ground_to_image(ground)
        ray = model.image_to_ray(lines, samples)
        seen = np.sum(ray.direction * (ground - ray.origin), axis=-1) > 0
        err = np.nanmax(np.hypot(line - lines, sample - samples)[seen]) if seen.any() else np.nan
        print(f"{label:38s} {n / t_i2g:16,.0f} {n / t_g2i:16,.0f} {err:15.2e}")
    print("targets: frame ≥ 1,000,000 points/s, line scan ≥ 200,000 points/s (2 cores)")
    triangulation_time(args.size)


def triangulation_time(size: int) -> None:
    """Triangulate a size² disparity through two frame models and grid it on the map.

    A synthetic lunar pair (``demtool.synth``: 1000 m altitude, B/H 0.3, GSD 0.5 m) whose
    disparity is that of the sphere: the time of :func:`triangulate_sensors` plus
    :func:`dem_on_map`, the two steps of ``dem --disparity`` with a calibrated rectify.npz.
    """
    from demtool.dem.sensors import dem_on_map, triangulate_sensors
    from demtool.maps import body_by_name
    from demtool.sensors.pinhole import look_at
    from demtool.synth.body import placement
    from demtool.synth.sensors import frame_sensor

    place = placement("Moon")
    focal = 1000.0 / 0.5
    cameras = [frame_sensor(look_at((x, 0.0, 1000.0), (0.0, 0.0, 0.0), focal_px=focal,
                                    width=size, height=size), place,
                            sun_position=place.sun_position((0.0, -0.5, 0.8)))
               for x in (-150.0, 150.0)]
    lines, samples = np.mgrid[0.5:size, 0.5:size]
    left, right = cameras
    ground = left.image_to_ground(lines.ravel(), samples.ravel())
    right_line, right_sample = right.ground_to_image(ground)
    start = time.perf_counter()
    points = triangulate_sensors(left, right, lines.ravel(), samples.ravel(),
                                 right_line, right_sample)
    middle = time.perf_counter()
    keep = points.in_front & np.isfinite(points.gap)
    dem = dem_on_map(points.xyz[keep], points.gap[keep], body_by_name("Moon"), gsd_m=0.5,
                     left=left, right=right)
    end = time.perf_counter()
    valid = np.isfinite(dem.dem)
    print(f"\ndem triangulation, {size}² disparity through two frame models: "
          f"triangulate {middle - start:.2f} s, map DEM {end - middle:.2f} s, "
          f"total {end - start:.2f} s ({keep.sum() / (end - start):,.0f} points/s); "
          f"{dem.dem.shape[1]}×{dem.dem.shape[0]} cells, {100 * valid.mean():.1f} % valid, "
          f"height range {np.nanmin(dem.dem):.3f} … {np.nanmax(dem.dem):.3f} m (truth 0)")


if __name__ == "__main__":
    main()
