"""`demtool bundle` beside plain pycolmap on Middlebury's templeSparseRing (issue 44).

Reads ``../shared/data/multiview/templeSparseRing`` (relative to the repository root;
skipped with a message when absent): 16 views of a plaster temple on black, 640 × 480
px, on a ring around it, with the true cameras in ``templeSR_par.txt`` (``P = K [R | t]``,
world to camera; Seitz et al. 2006).  Views 0001 and 0011 share one pose, so the ring
has 15 distinct viewpoints.  Both runs have free intrinsics and no target.

Scores, after the similarity (Umeyama 1991) that best maps the registered camera
centres onto the true ones: the distinct viewpoints registered, the median and largest
rotation error (degrees), the median and largest centre error (% of the ring's radius,
the mean distance of the true centres from their centroid), the principal point's
distance from the true one (pixels; the true K's origin is the top-left pixel's centre,
as demtool's) and the focal length's relative error (against the mean of the true fx,
fy).  Targets (issue 44): 15/15 viewpoints, median rotation error ≤ 0.3°, centres ≤
0.5 % of the radius, principal point within 3 px.  Wall times are on a shared, loaded
2-core machine.

Usage: ``.venv/bin/python bench/bundle_ring.py [--keep DIR] [--no-plain]``
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

RING = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "multiview" / \
    "templeSparseRing"


def read_truth(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(K, R, t) by view name (file stem) from a Middlebury ``*_par.txt``."""
    truth = {}
    for line in path.read_text().splitlines()[1:]:
        parts = line.split()
        if len(parts) != 22:
            continue
        values = np.array(parts[1:], dtype=np.float64)
        truth[Path(parts[0]).stem] = (values[:9].reshape(3, 3), values[9:18].reshape(3, 3),
                                      values[18:])
    return truth


def viewpoint_groups(truth: dict) -> dict[str, int]:
    """Index of the distinct viewpoint of each view (views within 1 mm and 0.1° share one)."""
    groups: dict[str, int] = {}
    reps: list[tuple[np.ndarray, np.ndarray]] = []
    for name, (_, R, t) in sorted(truth.items()):
        centre = -R.T @ t
        for index, (c, Rr) in enumerate(reps):
            angle = np.degrees(np.arccos(np.clip((np.trace(R.T @ Rr) - 1) / 2, -1, 1)))
            if np.linalg.norm(c - centre) < 1e-3 and angle < 0.1:
                groups[name] = index
                break
        else:
            groups[name] = len(reps)
            reps.append((centre, R))
    return groups


def score(names, K, R, t, truth: dict) -> dict:
    """Scores of estimated cameras (world to camera, demtool convention) against the truth."""
    from demtool.bundle.align import umeyama

    names = [str(n) for n in names]
    centres = np.array([-Ri.T @ ti for Ri, ti in zip(R, t, strict=True)])
    true_centres = np.array([-truth[n][1].T @ truth[n][2] for n in names])
    all_true = np.array([-Rt.T @ tt for _, Rt, tt in truth.values()])
    radius = float(np.mean(np.linalg.norm(all_true - all_true.mean(axis=0), axis=1)))
    s, Q, T = umeyama(centres, true_centres)
    moved = s * centres @ Q.T + T
    centre_error = np.linalg.norm(moved - true_centres, axis=1) / radius * 100
    rotation_error = []
    for n, Ri in zip(names, R, strict=True):
        D = truth[n][1].T @ Ri @ Q.T
        rotation_error.append(np.degrees(np.arccos(np.clip((np.trace(D) - 1) / 2, -1, 1))))
    groups = viewpoint_groups(truth)
    Kt = next(iter(truth.values()))[0]
    pp = np.array([np.hypot(k[0, 2] - Kt[0, 2], k[1, 2] - Kt[1, 2]) for k in K])
    f_true = 0.5 * (Kt[0, 0] + Kt[1, 1])
    f_error = np.array([abs(0.5 * (k[0, 0] + k[1, 1]) - f_true) / f_true * 100 for k in K])
    return {"registered": len(names), "viewpoints": len({groups[n] for n in names}),
            "distinct": len(set(groups.values())),
            "rotation_median": float(np.median(rotation_error)),
            "rotation_max": float(np.max(rotation_error)),
            "centre_median": float(np.median(centre_error)),
            "centre_max": float(np.max(centre_error)),
            "pp_error": float(np.max(pp)), "f_error": float(np.max(f_error))}


def plain_pycolmap(work: Path, images: list[Path], truth: dict) -> dict:
    """COLMAP with its defaults (one SIMPLE_RADIAL camera per image, exhaustive matching)."""
    import pycolmap

    from demtool.bundle import set_colmap_verbosity

    set_colmap_verbosity(False)
    folder = work / "plain_images"
    folder.mkdir()
    for path in images:
        shutil.copy(path, folder / path.name)
    start = time.perf_counter()
    database = work / "plain.db"
    pycolmap.extract_features(database, folder)
    pycolmap.match_exhaustive(database)
    models = pycolmap.incremental_mapping(database, folder, work / "plain")
    elapsed = time.perf_counter() - start
    best = max(models.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))
    names, K, R, t = [], [], [], []
    for image_id in sorted(best.reg_image_ids()):
        image = best.image(image_id)
        camera = best.camera(image.camera_id)
        pose = image.cam_from_world()
        names.append(Path(image.name).stem)
        k = np.asarray(camera.calibration_matrix(), dtype=np.float64).copy()
        k[:2, 2] -= 0.5  # COLMAP's pixel centres are at +0.5
        K.append(k)
        R.append(pose.rotation.matrix())
        t.append(np.asarray(pose.translation))
    return {**score(names, K, R, t, truth), "time": elapsed}


def demtool_bundle(work: Path, images: list[Path], truth: dict, args: list[str]) -> dict:
    """``demtool bundle IMAGES`` (with ``args``), as a user runs it; scores and sidecar."""
    import json
    import subprocess

    out = work / "bundle.npz"
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "demtool", "bundle", *map(str, images), "--out",
                    str(out), *args], check=True)
    elapsed = time.perf_counter() - start
    with np.load(out, allow_pickle=False) as data:
        names, K, R, t = (data["image_names"], data["K"], data["R"], data["t"])
    summary = json.loads(Path(f"{out}.json").read_text())["summary"]
    return {**score(names, K, R, t, truth), "time": elapsed, "summary": summary}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keep", type=Path, help="keep the runs' files in this folder")
    parser.add_argument("--no-plain", action="store_true", help="skip plain pycolmap")
    parser.add_argument("--no-record", action="store_true",
                        help="do not write bench/results/35_bundle_ring.json")
    parser.add_argument("bundle_args", nargs="*", help="extra options of demtool bundle")
    options = parser.parse_args()
    if not RING.is_dir():
        print(f"skipped: {RING} is absent")
        return
    truth = read_truth(RING / "templeSR_par.txt")
    images = sorted(RING.glob("templeSR*.png"))
    with tempfile.TemporaryDirectory(prefix="demtool-ring-") as folder:
        work = Path(options.keep) if options.keep else Path(folder)
        work.mkdir(parents=True, exist_ok=True)
        ours = demtool_bundle(work, images, truth, options.bundle_args)
        plain = None if options.no_plain else plain_pycolmap(work, images, truth)
    rows = [("demtool bundle", ours)] + ([("plain pycolmap", plain)] if plain else [])
    columns = ["", "viewpoints", "rotation median / max (°)", "centres median / max (% r)",
               "principal point (px)", "focal length (%)", "time (s)"]
    table = []
    for name, row in rows:
        table.append([name, f"{row['viewpoints']}/{row['distinct']}",
                      f"{row['rotation_median']:.3f} / {row['rotation_max']:.3f}",
                      f"{row['centre_median']:.3f} / {row['centre_max']:.3f}",
                      f"{row['pp_error']:.2f}", f"{row['f_error']:.2f}",
                      f"{row['time']:.0f}"])
    table.append(["target", "15/15", "≤ 0.3 (median)", "≤ 0.5 (median)", "≤ 3", "", ""])
    print(f"\ntempleSparseRing ({len(images)} views, free intrinsics, no target)")
    for line in table:
        print(" | ".join(f"{c:<26}" if i == 0 else f"{c:>14}" for i, c in enumerate(line)))
    intrinsics = ours["summary"].get("intrinsics", {})
    print("intrinsics:", {k: v for k, v in intrinsics.items() if k != "sigma"})
    if not ours["summary"].get("not_registered"):
        print("every view registered")
    else:
        print("not registered:", ours["summary"].get("unregistered_reasons")
              or ours["summary"]["not_registered"])
    met = (ours["viewpoints"] == ours["distinct"] and ours["rotation_median"] <= 0.3
           and ours["centre_median"] <= 0.5 and ours["pp_error"] <= 3)
    print(f"targets met: {'yes' if met else 'NO'}")
    if options.no_record or options.bundle_args:
        return
    from bench.validation_page import write_result

    write_result("35_bundle_ring", title="Bundle: templeSparseRing (a ring of 16 views)",
                 section="Bundle adjustment", order=35,
                 command="python bench/bundle_ring.py", date=time.strftime("%Y-%m-%d"),
                 machine="shared 2-core VM (loaded)", columns=columns, rows=table,
                 notes="Middlebury templeSparseRing, free intrinsics, no target; errors "
                 "after a similarity alignment of the registered centres to the true "
                 "ones; r = the ring's radius. Views 0001 and 0011 share a pose (15 "
                 "distinct viewpoints). demtool: standard SIFT registers 13 of 16 views "
                 "(before issue 44 the result: 12/15 viewpoints, 0.787° / 0.285 %, "
                 "principal point at the image centre, 18.7 px off, 46 s), so the "
                 "default features=auto maps again with rich features.")


if __name__ == "__main__":
    main()
