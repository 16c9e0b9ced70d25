"""`demtool bundle` beside plain pycolmap on the four Apollo 15 Metric Camera frames.

Reads ``../shared/data/apollo15`` (relative to the repository root; skipped with a
message when absent).  Plain pycolmap is COLMAP with its defaults (one SIMPLE_RADIAL
camera per image, exhaustive matching, incremental mapping); ``demtool bundle`` runs
with its defaults (one shared camera, SIMPLE_RADIAL while mapping, k2 freed in a final
global adjustment).  Target (issue 4): at least 4/4 registered, ≥ 6 224 points, mean
reprojection error ≤ 0.18 px, and at least as good as plain pycolmap in the same run.
Wall times are on a shared, loaded 2-core machine.

Usage: ``.venv/bin/python bench/bundle_apollo.py``
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

APOLLO = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "apollo15"


def plain_pycolmap(work: Path) -> dict:
    import pycolmap

    from demtool.bundle import set_colmap_verbosity

    set_colmap_verbosity(False)
    start = time.perf_counter()
    database = work / "plain.db"
    pycolmap.extract_features(database, APOLLO)
    pycolmap.match_exhaustive(database)
    models = pycolmap.incremental_mapping(database, APOLLO, work / "plain")
    best = max(models.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))
    errors = np.array([p.error for p in best.points3D.values()])
    return {"registered": best.num_reg_images(), "points": best.num_points3D(),
            "mean": float(errors.mean()), "p95": float(np.percentile(errors, 95)),
            "time": time.perf_counter() - start}


def demtool_bundle(work: Path, frames: list[Path]) -> dict:
    from demtool.bundle.run import run_bundle

    selection = work / "selection.json"
    selection.write_text(json.dumps({
        "target": {"name": frames[0].stem, "path": str(frames[0])}, "roi": None,
        "selected": [{"name": p.stem, "path": str(p)} for p in frames], "rejected": [],
        "parameters": {}}))
    start = time.perf_counter()
    summary = run_bundle([str(selection)], work / "bundle.npz")
    return {"registered": summary["registered_count"], "points": summary["points"],
            "mean": summary["mean_reprojection_error_px"],
            "p95": summary["p95_reprojection_error_px"], "time": time.perf_counter() - start}


def main() -> None:
    if not APOLLO.is_dir():
        print(f"skipped: {APOLLO} is absent")
        return
    frames = sorted(APOLLO.glob("AS15-M-*.png"))
    with tempfile.TemporaryDirectory(prefix="demtool-apollo-") as folder:
        work = Path(folder)
        plain = plain_pycolmap(work)
        ours = demtool_bundle(work, frames)
    print(f"\nBundle adjustment of the {len(frames)} Apollo 15 frames (1012 × 1012 px)")
    header = f"{'':<22} {'registered':>10} {'points':>7} {'mean px':>8} {'p95 px':>7} {'time s':>7}"
    print(header)
    print("-" * len(header))
    for name, row in (("plain pycolmap", plain), ("demtool bundle", ours)):
        print(f"{name:<22} {row['registered']:>8}/{len(frames)} {row['points']:>7} "
              f"{row['mean']:8.4f} {row['p95']:7.3f} {row['time']:7.1f}")
    print(f"{'target':<22} {'4/4':>10} {'>= 6224':>7} {'<= 0.18':>8}")
    met = ours["registered"] >= 4 and ours["points"] >= 6224 and ours["mean"] <= 0.18
    as_good = (ours["registered"] >= plain["registered"] and ours["points"] >= plain["points"]
               and ours["mean"] <= plain["mean"])
    print(f"target met: {'yes' if met else 'NO'}; at least as good as plain pycolmap: "
          f"{'yes' if as_good else 'NO'}")


if __name__ == "__main__":
    main()
