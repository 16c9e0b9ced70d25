"""Issue 14, check 2: a DEM from bundle-adjusted ISDs as accurate as from the true ones.

``synth --sensor frame`` renders a scene on the Moon's sphere with one frame ISD per
view.  Every ISD's position is moved by 50 m and its pointing by 0.5 mrad, in random
(seeded) directions, and the perturbed copies are the priors of ``bundle --sensors
--adjusted-dir`` (``--position-sigma 50 --pointing-sigma 0.5``).  The adjusted models'
errors against the true ISDs are reported (target: within 5 m / 0.05 mrad), then the
calibrated route of the Makefile's ``dem_frame`` product (``rectify --sensor-left
--sensor-right`` → ``sgm`` → ``dem`` → ``compare`` against ``truth_dem_map.tif``) runs
three times: with the true, the perturbed and the adjusted ISDs.  Target: the adjusted
DEM as accurate as the true one.

Tie points see only the relative geometry of the block: a translation and rotation
common to all views (and a common scale) is determined by the priors alone, so the
adjusted block keeps the mean of the prior errors (≈ 50 m / √N, 0.5 mrad / √N for N
views with independent errors).  The script prints that mean beside the result.

Stages run through the CLI (``python -m demtool``) in subprocesses, as the Makefile
chains them.

Usage: ``.venv/bin/python bench/bundle_priors_dem.py [--size 256] [--image-size 256]
[--views 8] [--seed 0] [--keep DIR]``
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

POSITION_ERROR_M = 50.0
POINTING_ERROR_MRAD = 0.5


def demtool(*args: str) -> float:
    """Run one demtool stage (``python -m demtool -q ...``); its wall time, seconds."""
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "demtool", "-q", *map(str, args)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"demtool {args[0]} failed ({done.returncode}):\n{done.stderr}")
    return time.perf_counter() - start


def random_unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def perturb(scene: Path, out: Path, names: list[str], rng: np.random.Generator) -> None:
    """Write each view's ISD moved by 50 m and turned by 0.5 mrad (random directions)."""
    from demtool.bundle.priors import PoseOffset, pivot_of
    from demtool.bundle.writeback import adjust_isd, dumps_isd
    from demtool.sensors import read_sensor

    out.mkdir(parents=True, exist_ok=True)
    for name in names:
        path = scene / f"{name}.json"
        offset = PoseOffset(POSITION_ERROR_M * random_unit(rng),
                            POINTING_ERROR_MRAD * 1e-3 * random_unit(rng),
                            pivot_of(read_sensor(path)))
        isd = json.loads(path.read_text())
        (out / f"{name}.json").write_text(dumps_isd(adjust_isd(isd, offset)))


def pose_errors(folder: Path, scene: Path, names: list[str]) -> np.ndarray:
    """(N, 2): position error (m) and pointing error (mrad) of each model vs the truth;
    also (2, 3) mean position offset (m) and mean rotation vector (mrad)."""
    from demtool.bundle.priors import rotation_vector
    from demtool.sensors import read_sensor

    errors, d_pos, d_rot = [], [], []
    for name in names:
        true = read_sensor(scene / f"{name}.json")
        model = read_sensor(folder / f"{name}.json")
        d_pos.append(model.position - true.position)
        d_rot.append(rotation_vector(model.rotation @ true.rotation.T) * 1e3)
        errors.append((np.linalg.norm(d_pos[-1]), np.linalg.norm(d_rot[-1])))
    return np.array(errors), np.array([np.mean(d_pos, axis=0), np.mean(d_rot, axis=0)])


def dem_route(scene: Path, isds: Path, work: Path, target: str, partner: str) -> dict:
    """rectify (calibrated) → sgm → dem → compare; the compare report's headline."""
    work.mkdir(parents=True, exist_ok=True)
    wall = demtool("rectify", scene / f"{target}.tif", scene / f"{partner}.tif",
                   "--sensor-left", isds / f"{target}.json",
                   "--sensor-right", isds / f"{partner}.json", "--out", work / "stereo")
    wall += demtool("sgm", work / "stereo/left_rect.tif", work / "stereo/right_rect.tif",
                    "--rectify", work / "stereo/rectify.npz", "--out", work / "disparity.tif")
    wall += demtool("dem", "--disparity", work / "disparity.tif",
                    "--rectify", work / "stereo/rectify.npz", "--out", work / "dem.tif")
    wall += demtool("compare", work / "dem.tif", scene / "truth_dem_map.tif",
                    "--out", work / "report", "--label", work.name)
    report = json.loads((work / "report" / "report.json").read_text())
    report["_wall_s"] = wall
    return report


def headline(report: dict) -> dict:
    """RMSE after alignment, mean shift before alignment, completeness, from report.json."""
    before = report.get("before_alignment") or report.get("raw") or {}
    after = report.get("after_alignment") or report.get("aligned") or {}
    return {"rmse": after.get("rmse", np.nan), "rmse_before": before.get("rmse", np.nan),
            "mean_before": before.get("mean", np.nan),
            "completeness": report.get("completeness", np.nan),
            "shift": report.get("alignment", {}).get("shift", None)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=256, help="synth --size (DEM cells)")
    parser.add_argument("--image-size", type=int, default=256, help="synth --image-size")
    parser.add_argument("--views", type=int, default=8, help="synth --views")
    parser.add_argument("--seed", type=int, default=0, help="seed of synth and the errors")
    parser.add_argument("--keep", type=Path, default=None, help="work folder to keep")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as scratch:
        work = args.keep or Path(scratch)
        scene = work / "scene"
        wall = demtool("synth", "--sensor", "frame", "--size", args.size, "--image-size",
                       args.image_size, "--views", args.views, "--seed", args.seed,
                       "--out", scene)
        description = json.loads((scene / "scene.json").read_text())
        target, partner = description["target"], description["partner"]
        names = sorted(p.stem for p in scene.glob("view_*.tif"))
        print(f"synth --sensor frame --size {args.size} --image-size {args.image_size} "
              f"--views {len(names)}: {wall:.1f} s")

        perturb(scene, work / "perturbed", names, np.random.default_rng(args.seed + 1))
        wall = demtool("bundle", *[scene / f"{n}.tif" for n in names],
                       *[a for n in names for a in ("--sensors", work / "perturbed" /
                                                    f"{n}.json")],
                       "--matcher", "spatial", "--position-sigma", POSITION_ERROR_M,
                       "--pointing-sigma", POINTING_ERROR_MRAD,
                       "--adjusted-dir", work / "adjusted", "--out", work / "bundle.npz")
        summary = json.loads((work / "bundle.npz.json").read_text())
        print(f"bundle: {wall:.1f} s")

        print("\nPose errors against the true ISDs (target: adjusted within 5 m / 0.05 mrad)")
        print("| models | max position m | mean position m | max pointing mrad "
              "| mean pointing mrad | common offset m | common rotation mrad |")
        print("|---|---|---|---|---|---|---|")
        for label in ("perturbed", "adjusted"):
            errors, common = pose_errors(work / label, scene, names)
            print(f"| {label} | {errors[:, 0].max():.2f} | {errors[:, 0].mean():.2f} | "
                  f"{errors[:, 1].max():.4f} | {errors[:, 1].mean():.4f} | "
                  f"{np.linalg.norm(common[0]):.2f} | {np.linalg.norm(common[1]):.4f} |")
        per_image = summary.get("summary", summary).get("images", None)
        if per_image:
            print("\nbundle report per image:", json.dumps(per_image)[:2000])

        print(f"\nDEM ({target}/{partner}, rectify --sensor-* → sgm → dem → compare vs "
              "truth_dem_map.tif; target: adjusted as accurate as true)")
        print("| ISDs | RMSE m (aligned) | RMSE m (before) | mean diff m (before) "
              "| completeness % | time s |")
        print("|---|---|---|---|---|---|")
        for label, folder in (("true", scene), ("perturbed", work / "perturbed"),
                              ("adjusted", work / "adjusted")):
            report = dem_route(scene, folder, work / f"dem_{label}", target, partner)
            h = headline(report)
            print(f"| {label} | {h['rmse']:.3f} | {h['rmse_before']:.3f} | "
                  f"{h['mean_before']:.3f} | {h['completeness']} | {report['_wall_s']:.0f} |",
                  flush=True)


if __name__ == "__main__":
    main()
