"""Speed and memory of ``demtool mapproject`` on a large synthetic line-scan image, and the
map-projected stereo route's time beside the image-frame route's.

Target (issue 12): a 4096 × 16384 (samples × lines) line-scan image map-projected in
≤ 30 s with a peak of ≤ 1 GB, on 2 cores.  The image is a synthetic lunar pushbroom
strip (tests/helpers/linescan.py: 1 m pixels, 50 km altitude, rolled 10°), written
once; each case runs ``run_mapproject`` in a child process (NUMBA_NUM_THREADS=2) so
its wall time and peak resident memory are its own.  Cases: onto the sphere
(``--height``) and onto a DEM at 4 m (the analytic hills, 80 m of relief).

    python bench/mapproject.py [--lines 16384] [--samples 4096] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CHILD = """
import json, sys, time
from demtool.mapproject.params import MapprojectParams
from demtool.mapproject.run import run_mapproject
args = json.loads(sys.argv[1])
start = time.perf_counter()
summary = run_mapproject(args["image"], args["isd"], args["out"],
                         MapprojectParams(height=args["height"], gsd=args["gsd"]),
                         dem_path=args["dem"])
summary["wall_s"] = time.perf_counter() - start
print(json.dumps(summary))
"""


def write_inputs(folder: Path, lines: int, samples: int):
    """The ISD, a textured image written in blocks, and a 4 m DEM of the hills."""
    from demtool import io as dio
    from demtool.mapproject.core import ortho_grid
    from demtool.maps import snap_grid
    from tests.helpers.linescan import MOON, isd_dict, linescan_sensor, write_truth_dem

    sensor = linescan_sensor(lines=lines, samples=samples, roll_deg=10.0, name="strip")
    isd = folder / "strip.json"
    isd.write_text(json.dumps(isd_dict(sensor)))
    image = folder / "strip.tif"
    rng = np.random.default_rng(0)
    with dio.raster_writer(image, height=lines, width=samples) as writer:
        for r0 in range(0, lines, 1024):
            r1 = min(r0 + 1024, lines)
            rows, cols = np.mgrid[r0:r1, 0:samples].astype(np.float32)
            block = (0.5 + 0.2 * np.sin(rows / 7.0) * np.cos(cols / 5.0)
                     + 0.05 * rng.standard_normal(rows.shape).astype(np.float32))
            writer.write(block, r0, 0)
    grid = ortho_grid(sensor, MOON, height=0.0, gsd=4.0)
    grid = snap_grid(grid.crs, *grid.bounds(), 4.0)
    dem = write_truth_dem(folder / "dem_4m.tif", grid)
    return sensor, image, isd, dem


def run_case(image, isd, out, *, height=None, dem=None, gsd=None) -> dict:
    env = dict(os.environ, NUMBA_NUM_THREADS="2", OMP_NUM_THREADS="1",
               PYTHONPATH=str(ROOT))
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    before, cpu_before = usage.ru_maxrss, usage.ru_utime + usage.ru_stime
    start = time.perf_counter()
    args = {"image": str(image), "isd": str(isd), "out": str(out), "height": height, "gsd": gsd,
            "dem": None if dem is None else str(dem)}
    done = subprocess.run([sys.executable, "-c", CHILD, json.dumps(args)], env=env,
                          capture_output=True, text=True, check=True)
    total = time.perf_counter() - start
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    peak = usage.ru_maxrss
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    summary["process_s"] = total
    summary["cpu_s"] = usage.ru_utime + usage.ru_stime - cpu_before
    summary["peak_mb"] = max(peak, before) / 1024.0
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=16384)
    parser.add_argument("--samples", type=int, default=4096)
    parser.add_argument("--keep", type=Path, default=None, help="Folder to keep the files in "
                        "(reused when they are already there).")
    args = parser.parse_args()
    folder = args.keep or Path(tempfile.mkdtemp(prefix="bench_mapproject_"))
    folder.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    image, isd, dem = folder / "strip.tif", folder / "strip.json", folder / "dem_4m.tif"
    if args.keep is None or not all(p.exists() for p in (image, isd, dem)):
        _, image, isd, dem = write_inputs(folder, args.lines, args.samples)
        print(f"inputs: {args.samples} x {args.lines} image written in "
              f"{time.perf_counter() - start:.1f} s ({folder})")
    else:
        print(f"inputs: reused from {folder}")
    print(f"load average before: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"{'case':22s} {'map cells':>12s} {'seen %':>7s} {'run s':>7s} {'process s':>9s} "
          f"{'CPU s':>7s} {'peak MB':>8s} {'max err px':>10s}  target")
    for label, kwargs in (("sphere (--height 0)", {"height": 0.0}),
                          ("DEM 4 m, 1 m ortho", {"dem": dem, "gsd": 1.0})):
        s = run_case(image, isd, folder / "ortho.tif", **kwargs)
        cells = s["width"] * s["height"]
        print(f"{label:22s} {cells:12,d} {100 * s['valid_fraction']:7.1f} {s['wall_s']:7.1f} "
              f"{s['process_s']:9.1f} {s['cpu_s']:7.1f} {s['peak_mb']:8.0f} "
              f"{s['max_interpolation_error_px']:10.4f}  <= 30 s, <= 1000 MB")
    route_times(folder / "routes")


def _demtool(*args) -> float:
    """Run ``demtool -q ARGS`` in a child process; its wall time, seconds."""
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "demtool", "-q", *map(str, args)], check=True)
    return time.perf_counter() - start


def _accuracy(dem: Path, truth: Path, out: Path) -> dict:
    done = subprocess.run([sys.executable, "-m", "demtool", "-q", "compare", str(dem),
                           str(truth), "--out", str(out), "--no-plots", "--json"],
                          check=True, capture_output=True, text=True)
    report = json.loads(done.stdout)
    return {"rmse": report["before_alignment"]["rmse"], "mean": report["before_alignment"]["mean"],
            "completeness": report["completeness"]}


def route_times(work: Path) -> None:
    """The two stereo routes on one synthetic frame-camera scene (issue 12).

    ``synth --sensor frame`` (the demo scene on the Moon); image-frame route: calibrated
    ``rectify`` → ``sgm`` → ``dem``; map-projected route: ``mapproject`` both views onto
    the sphere → ``sgm`` on the orthos → ``dem --mapprojected``.  Both DEMs are compared
    with ``truth_dem_map.tif`` before any alignment.
    """
    scene, frame, ortho = work / "scene", work / "frame", work / "ortho"
    _demtool("synth", "--sensor", "frame", "--out", scene)
    left, right = scene / "view_00", scene / "view_01"
    times = {"image-frame": {}, "map-projected": {}}
    t = times["image-frame"]
    t["rectify"] = _demtool("rectify", f"{left}.tif", f"{right}.tif", "--sensor-left",
                            f"{left}.json", "--sensor-right", f"{right}.json", "--out", frame)
    t["sgm"] = _demtool("sgm", frame / "left_rect.tif", frame / "right_rect.tif", "--rectify",
                        frame / "rectify.npz", "--out", frame / "disparity.tif")
    t["dem"] = _demtool("dem", "--disparity", frame / "disparity.tif", "--rectify",
                        frame / "rectify.npz", "--out", frame / "dem.tif")
    t = times["map-projected"]
    t["mapproject"] = (_demtool("mapproject", f"{left}.tif", "--sensor", f"{left}.json",
                                "--height", 0, "--out", ortho / "left.tif")
                       + _demtool("mapproject", f"{right}.tif", "--sensor", f"{right}.json",
                                  "--height", 0, "--grid-like", ortho / "left.tif", "--out",
                                  ortho / "right.tif"))
    t["sgm"] = _demtool("sgm", ortho / "left.tif", ortho / "right.tif", "--out",
                        ortho / "disparity.tif")
    t["dem"] = _demtool("dem", "--disparity", ortho / "disparity.tif", "--mapprojected",
                        ortho / "left.tif", ortho / "right.tif", "--out", ortho / "dem.tif")
    truth = scene / "truth_dem_map.tif"
    print("\nstereo routes on the synthetic frame scene (wall s per stage, child processes; "
          "DEM against truth_dem_map.tif before alignment):")
    for route, folder in (("image-frame", frame), ("map-projected", ortho)):
        stages = times[route]
        a = _accuracy(folder / "dem.tif", truth, folder / "report")
        print(f"  {route:14s} " + ", ".join(f"{k} {v:.1f}" for k, v in stages.items())
              + f"; total {sum(stages.values()):.1f} s; RMSE {a['rmse']:.3f} m, mean "
              f"{a['mean']:+.3f} m, complete {a['completeness']:.1f} %")


if __name__ == "__main__":
    main()
