"""Throughput of the sensor models: image_to_ground and ground_to_image, points per second.

Targets (issue 11): ≥ 1 M points/s for a frame camera, ≥ 200 k points/s for a line
scanner, on 2 cores.  The models are the usgscsm test ISDs carried by the tests
(``tests/sensors/data``); when ``../shared/data/sensors`` exists the real-mission ISDs
(Apollo Metric frame, LRO NAC and CTX line scanners) are measured too.

    python bench/sensors.py [--points N]
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


if __name__ == "__main__":
    main()
