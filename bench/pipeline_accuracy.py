"""Accuracy of the two DEM routes of the NavCam study on a synthetic scene with known truth.

Runs, through the command line in a temporary folder:

* BAM: ``synth`` → ``select`` → ``bundle`` → ``dem --points`` (eq. 2 with the scene's
  distance; and a metric variant with ``bundle --align-cameras``);
* SIAM: ``synth`` → ``rectify`` (target + partner) → ``sgm`` → ``dem --disparity``,
  both the calibrated route (``--cameras``) and the study's projective fit to the BAM
  DEM (``--reference``).

Each DEM is compared with ``truth_dem_target.tif`` after removing a vertical offset
(the median difference): RMSE, NMAD, and completeness (finite cells in the ROI, the
whole target image) beside the fraction actually measured (not interpolated).
Targets (issue 4): calibrated SIAM RMSE < 1 GSD; BAM RMSE < 2 GSD; 100 % of the ROI
filled.

Reference rows, measured in the same run on the same inputs:
* BAM points interpolated with SciPy's ``griddata`` (Delaunay-linear, nearest outside
  the hull) instead of the spring metaphor;
* the calibrated route on a disparity from OpenCV's StereoSGBM (MODE_HH, same
  range) instead of ``demtool sgm``.

Wall times are on a shared, loaded 2-core machine.

Usage: ``.venv/bin/python bench/pipeline_accuracy.py [--quick] [--keep DIR]``
(--quick: the 192-px test scene instead of the 512-px demo scene).
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

from demtool import io
from demtool.imaging.robust import nmad

QUICK_SCENE = ["--seed", "0", "--size", "256", "--views", "4", "--image-size", "192",
               "--craters", "20", "--crater-max", "50", "--boulders", "100"]
DEMO_SCENE = ["--seed", "0"]


class StageFailed(RuntimeError):
    pass


def demtool(*args: str, timings: dict[str, float], label: str) -> None:
    """Run one stage through the CLI; StageFailed with its message on failure."""
    start = time.perf_counter()
    completed = subprocess.run([sys.executable, "-m", "demtool", "-q", *args],
                               capture_output=True, text=True)
    timings[label] = time.perf_counter() - start
    if completed.returncode != 0:
        message = (completed.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise StageFailed(f"{label}: {message}")


def metrics(dem_path: Path, truth: np.ndarray) -> dict[str, float]:
    dem = io.read_raster(dem_path, allow_all_nan=True).data.astype(np.float64)
    finite = np.isfinite(dem)
    difference = (dem - truth)[finite & np.isfinite(truth)]
    difference -= np.median(difference)
    sidecar = json.loads(Path(f"{dem_path}.json").read_text())["summary"]
    return {
        "rmse": float(np.sqrt(np.mean(difference**2))),
        "nmad": nmad(difference),
        "complete": float(finite.mean()),
        "measured": float(sidecar.get("measured_fraction", finite.mean())),
    }


def griddata_reference(bundle_path: Path, scene: dict, out: Path) -> None:
    """BAM points, eq. 2 heights, SciPy griddata instead of springs (same outlier test)."""
    from scipy.interpolate import griddata

    from demtool.dem import local_median_inliers, target_samples
    from demtool.sensors.pinhole import cameras_from_arrays

    bundle = io.read_npz(bundle_path, "bundle")
    index = int(bundle["target_index"])
    camera = cameras_from_arrays(bundle)[str(bundle["image_names"][index])]
    samples = target_samples(bundle["points"], camera, aligned=False,
                             distance_m=scene["distance_m"],
                             distortion=bundle["distortion"][index])
    keep = local_median_inliers(samples.pixels, samples.heights)
    rows, cols = np.mgrid[:camera.height, :camera.width]
    linear = griddata(samples.pixels[keep], samples.heights[keep], (cols, rows), "linear")
    nearest = griddata(samples.pixels[keep], samples.heights[keep], (cols, rows), "nearest")
    dem = np.where(np.isfinite(linear), linear, nearest)
    io.write_raster(out, dem, transform=io.image_frame_transform(scene["gsd_m"]))
    Path(f"{out}.json").write_text(json.dumps({"summary": {
        "measured_fraction": float(np.mean(np.isfinite(linear)))}}))


def opencv_disparity(rect_dir: Path, rectification: dict, out: Path) -> None:
    """OpenCV StereoSGBM (MODE_HH) on the rectified pair, same disparity range."""
    import cv2

    def to8(path: Path) -> np.ndarray:
        data = io.read_raster(path, allow_all_nan=True).data
        valid = np.isfinite(data)
        low, high = np.percentile(data[valid], [0.5, 99.5])
        return np.where(valid, np.clip((data - low) / (high - low) * 255, 0, 255),
                        0).astype(np.uint8)

    left, right = to8(rect_dir / "left_rect.tif"), to8(rect_dir / "right_rect.tif")
    low, high = (float(v) for v in rectification["disparity_range"])
    minimum = int(np.floor(low))
    count = int(np.ceil((high - minimum) / 16.0)) * 16
    block = 5
    matcher = cv2.StereoSGBM_create(minDisparity=minimum, numDisparities=count,
                                    blockSize=block, P1=8 * block * block,
                                    P2=32 * block * block, disp12MaxDiff=1,
                                    uniquenessRatio=5, mode=cv2.STEREO_SGBM_MODE_HH)
    raw = matcher.compute(left, right).astype(np.float32) / 16.0
    disparity = np.where(raw < minimum, np.nan, raw)
    io.write_raster(out, disparity)


def run(args: argparse.Namespace, work: Path) -> list[dict]:
    timings: dict[str, float] = {}
    scene_dir = work / "scene"
    demtool("synth", "--out", str(scene_dir), *(QUICK_SCENE if args.quick else DEMO_SCENE),
            timings=timings, label="synth")
    scene = json.loads((scene_dir / "scene.json").read_text())
    gsd = float(scene["gsd_m"])
    truth_path = scene_dir / "truth_dem_target.tif"
    truth = io.read_raster(truth_path).data.astype(np.float64)
    target = scene_dir / f"{scene['target']}.tif"
    partner = scene_dir / f"{scene['partner']}.tif"
    views = [str(scene_dir / f"{name}.tif") for name in scene["names"]]
    rows: list[dict] = []

    def add(name: str, route: str, dem: Path | None, target_gsd: float | None,
            stages: list[str], error: str | None = None) -> None:
        row = {"name": name, "route": route, "target": target_gsd,
               "time": sum(timings.get(s, 0.0) for s in stages), "error": error}
        if dem is not None and error is None:
            row.update(metrics(dem, truth))
        rows.append(row)

    bam = work / "dem_bam.tif"
    try:
        demtool("select", *views, "--target", str(target), "--out", str(work / "sel.json"),
                timings=timings, label="select")
        demtool("bundle", str(work / "sel.json"), "--out", str(work / "bundle.npz"),
                timings=timings, label="bundle")
        demtool("dem", "--points", str(work / "bundle.npz"), "--scene",
                str(scene_dir / "scene.json"), "--out", str(bam), timings=timings,
                label="dem bam")
        add("BAM (eq. 2)", "select+bundle+dem --points", bam, 2.0,
            ["select", "bundle", "dem bam"])
        start = time.perf_counter()
        griddata_reference(work / "bundle.npz", scene, work / "dem_griddata.tif")
        timings["griddata"] = time.perf_counter() - start
        add("  ref: griddata-linear", "same points, SciPy griddata", work / "dem_griddata.tif",
            None, ["select", "bundle", "griddata"])
    except StageFailed as exc:
        add("BAM (eq. 2)", "select+bundle+dem --points", None, 2.0, [], str(exc))
    try:
        demtool("bundle", str(work / "sel.json"), "--out", str(work / "bundle_aligned.npz"),
                "--align-cameras", str(scene_dir / "cameras.npz"), timings=timings,
                label="bundle aligned")
        demtool("dem", "--points", str(work / "bundle_aligned.npz"), "--gsd", str(gsd),
                "--out", str(work / "dem_bam_metric.tif"), timings=timings,
                label="dem bam metric")
        add("BAM (aligned, metric)", "bundle --align-cameras + dem",
            work / "dem_bam_metric.tif", 2.0, ["select", "bundle aligned", "dem bam metric"])
    except StageFailed as exc:
        add("BAM (aligned, metric)", "bundle --align-cameras + dem", None, 2.0, [], str(exc))

    rect = work / "rect"
    try:
        demtool("rectify", str(target), str(partner), "--out", str(rect), timings=timings,
                label="rectify")
        demtool("sgm", str(rect / "left_rect.tif"), str(rect / "right_rect.tif"), "--rectify",
                str(rect / "rectify.npz"), "--out", str(work / "disparity.tif"),
                timings=timings, label="sgm")
        demtool("dem", "--disparity", str(work / "disparity.tif"), "--rectify",
                str(rect / "rectify.npz"), "--cameras", str(scene_dir / "cameras.npz"),
                "--out", str(work / "dem_siam_cal.tif"), timings=timings, label="dem siam cal")
        add("SIAM calibrated", "rectify+sgm+dem --cameras", work / "dem_siam_cal.tif", 1.0,
            ["rectify", "sgm", "dem siam cal"])
    except StageFailed as exc:
        add("SIAM calibrated", "rectify+sgm+dem --cameras", None, 1.0, [], str(exc))
    if (work / "disparity.tif").exists() and bam.exists():
        try:
            demtool("dem", "--disparity", str(work / "disparity.tif"), "--rectify",
                    str(rect / "rectify.npz"), "--reference", str(bam), "--out",
                    str(work / "dem_siam_proj.tif"), timings=timings, label="dem siam proj")
            add("SIAM projective fit", "… + dem --reference BAM", work / "dem_siam_proj.tif",
                0.0, ["rectify", "sgm", "dem siam proj"])
        except StageFailed as exc:
            add("SIAM projective fit", "… + dem --reference BAM", None, 2.0, [], str(exc))
    else:
        add("SIAM projective fit", "… + dem --reference BAM", None, 2.0, [],
            "needs the BAM DEM and the disparity")
    if (rect / "rectify.npz").exists():
        try:
            rectification = io.read_npz(rect / "rectify.npz", "rectification")
            start = time.perf_counter()
            opencv_disparity(rect, rectification, work / "disparity_sgbm.tif")
            timings["sgbm"] = time.perf_counter() - start
            demtool("dem", "--disparity", str(work / "disparity_sgbm.tif"), "--rectify",
                    str(rect / "rectify.npz"), "--cameras", str(scene_dir / "cameras.npz"),
                    "--out", str(work / "dem_sgbm_cal.tif"), timings=timings,
                    label="dem sgbm")
            add("  ref: OpenCV SGBM calibrated", "rectify+SGBM HH+dem --cameras",
                work / "dem_sgbm_cal.tif", None, ["rectify", "sgbm", "dem sgbm"])
        except StageFailed as exc:
            add("  ref: OpenCV SGBM calibrated", "", None, None, [], str(exc))
    for row in rows:
        row["gsd"] = gsd
    return rows


def print_table(rows: list[dict], scene_name: str) -> None:
    print(f"\nDEM accuracy vs truth_dem_target.tif ({scene_name}; vertical offset removed)")
    header = (f"{'DEM':<30} {'RMSE m':>8} {'RMSE/GSD':>9} {'NMAD m':>8} {'complete':>9} "
              f"{'measured':>9} {'time s':>7}  {'target':<16} met")
    print(header)
    print("-" * len(header))
    for row in rows:
        if row.get("error"):
            print(f"{row['name']:<30} {'—':>8} {'—':>9} {'—':>8} {'—':>9} {'—':>9} {'—':>7}  "
                  f"skipped: {row['error']}")
            continue
        ratio = row["rmse"] / row["gsd"]
        if row["target"] is None:
            target, met = "(reference)", ""
        elif row["target"] == 0.0:
            target, met = "(no target)", ""
        else:
            target = f"< {row['target']:g} GSD, 100 %"
            met = "yes" if ratio < row["target"] and row["complete"] >= 1.0 else "NO"
        print(f"{row['name']:<30} {row['rmse']:8.3f} {ratio:9.2f} {row['nmad']:8.3f} "
              f"{100 * row['complete']:8.1f}% {100 * row['measured']:8.1f}% "
              f"{row['time']:7.1f}  {target:<16} {met}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="192-px test scene")
    parser.add_argument("--keep", type=Path, help="keep the intermediate files in DIR")
    args = parser.parse_args()
    if args.keep:
        args.keep.mkdir(parents=True, exist_ok=True)
        rows = run(args, args.keep)
    else:
        with tempfile.TemporaryDirectory(prefix="demtool-pipeline-") as folder:
            rows = run(args, Path(folder))
    print_table(rows, "quick 192-px scene" if args.quick else "demo scene, 512 px")


if __name__ == "__main__":
    main()
