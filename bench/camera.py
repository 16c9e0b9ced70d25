"""`demtool camera` on the shared real models: the report and its time.

Target (issue 11): on the Apollo 15 Metric cubes both footprints overlap and B/H is near
0.34; every ALE ISD gives sane values.  Needs ``../shared/data/sensors`` (skips the parts
that are absent).

    python bench/camera.py
"""

from __future__ import annotations

import io
import time
from pathlib import Path

from demtool.camera.run import run_camera

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT / ".." / "shared" / "data" / "sensors"


def main() -> None:
    groups = [("Apollo 15 Metric cubes", sorted((SHARED / "apollo15_cubes").glob("*.cub"))),
              ("ALE ISDs", sorted((SHARED / "ale").glob("*.json")))]
    for title, paths in groups:
        if not paths:
            print(f"{title}: {SHARED} absent, skipped")
            continue
        text = io.StringIO()
        start = time.perf_counter()
        report = run_camera(paths, stream=text)
        elapsed = time.perf_counter() - start
        print(f"== {title}: {len(report['cameras'])} models, {elapsed:.2f} s ==")
        print(text.getvalue())
        if title.startswith("Apollo"):
            pair = report["pairs"][0]
            print(f"target: B/H near 0.34, both footprints overlapping -> B/H "
                  f"{pair['base_to_height']:.4f}, overlap {pair['overlap_fraction_first']:.1%}"
                  f" / {pair['overlap_fraction_second']:.1%}, convergence "
                  f"{pair['convergence_deg']:.2f}°\n")


if __name__ == "__main__":
    main()
