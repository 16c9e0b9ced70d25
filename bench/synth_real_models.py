"""Synthetic truth through real geometry (issue 24): ``synth --sensor-model`` on a pair,
then the map-projected route (mapproject → sgm → dem --mapprojected → compare).

Targets: DEM RMSE before alignment < 1 GSD, completeness ≥ 95 %.

Cases
    ctx      two of the shared MRO CTX ISDs (``ctx_knoten``, F02 and J07: 23° between the
             rays), skipped when ``../shared/data/sensors`` is absent;
    push     two push-frame ISDs made here: the synthetic line-scan pair's orbits
             (``demtool.synth.sensors.linescan_sensor``, ±12.5° roll, 1 m GSD on the
             Moon) imaged by a framelet camera (16-line framelets, one eighth overlap).

Each case renders ``--image-size`` windows with ``--relief 15 --crater-max 600`` (CTX) or
the default terrain (push frames).

    python bench/synth_real_models.py [--image-size 384] [--cases ctx push]
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

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT / ".." / "shared" / "data" / "sensors"


def push_frame_pair(folder: Path, *, lines: int = 768, samples: int = 512,
                    framelet: int = 16, gsd_m: float = 1.0) -> list[Path]:
    """Two push-frame ISDs over (0°, 0°) on the Moon, converging by 25°."""
    from demtool.sensors import Detector
    from demtool.sensors.isd import write_isd
    from demtool.sensors.pushframe import PushFrameSensor
    from demtool.synth.body import placement
    from demtool.synth.sensors import PIXEL_PITCH_MM, linescan_sensor

    place = placement("Moon", 0.0, 0.0)
    sun = place.sun_position(np.array([0.5, 0.3, 0.8]))
    paths = []
    for name, roll in (("push_left", -12.5), ("push_right", 12.5)):
        base = linescan_sensor(place, off_nadir_deg=roll, altitude_m=50_000.0, gsd_m=gsd_m,
                               ground_speed_m_s=1600.0, lines=lines, samples=samples,
                               sun_position=sun, name=name)
        p = PIXEL_PITCH_MM
        # detector lines run forward along track (the look is (−u, −v, −f): −y is ahead)
        detector = Detector(np.array([0.0, 1.0 / p, 0.0]), np.array([0.0, 0.0, -1.0 / p]),
                            0.5 * samples, 0.5 * framelet)
        delay = framelet * float(base.int_times[0]) * 7.0 / 8.0
        count = lines // framelet
        model = PushFrameSensor(
            framelet_height=framelet, exposure_duration=0.001, interframe_delay=delay,
            starting_time=-0.5 * count * delay - 0.0005, positions=base.positions,
            t0_ephem=base.t0_ephem, dt_ephem=base.dt_ephem, quaternions=base.quaternions,
            t0_quat=base.t0_quat, dt_quat=base.dt_quat, focal_length=base.focal_length,
            detector=detector, lines=lines, samples=samples, radii=base.radii,
            sun_positions=base.sun_positions, velocities=base.velocities, name=name,
            center_time=0.0)
        paths.append(write_isd(folder / f"{name}.json", model))
    return paths


def run(*args: str | Path) -> None:
    cmd = [sys.executable, "-m", "demtool", *map(str, args)]
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if done.returncode:
        raise SystemExit(f"{' '.join(cmd)}\n{done.stderr[-2000:]}")


def route(left: Path, right: Path, work: Path, image_size: int, extra: list[str]) -> dict:
    start = time.perf_counter()
    scene = work / "scene"
    run("synth", "--out", scene, "--sensor-model", left, right, "--image-size", image_size,
        *extra)
    run("mapproject", scene / "view_00.tif", "--sensor", scene / "view_00.json", "--height",
        0, "--out", work / "left_ortho.tif")
    run("mapproject", scene / "view_01.tif", "--sensor", scene / "view_01.json", "--height",
        0, "--grid-like", work / "left_ortho.tif", "--out", work / "right_ortho.tif")
    run("sgm", work / "left_ortho.tif", work / "right_ortho.tif", "--out", work / "disp.tif")
    run("dem", "--disparity", work / "disp.tif", "--mapprojected", work / "left_ortho.tif",
        work / "right_ortho.tif", "--out", work / "dem.tif")
    run("compare", work / "dem.tif", scene / "truth_dem_map.tif", "--out", work / "report")
    report = json.loads((work / "report" / "report.json").read_text())
    views = json.loads((scene / "scene.json").read_text())["views"]
    gsd = json.loads((scene / "scene.json").read_text())["gsd_m"]
    return {"convergence": max(v["convergence_deg"] for v in views), "gsd": gsd,
            "rmse0": report["before_alignment"]["rmse"], "rmse": report["rmse"],
            "completeness": report["completeness"], "seconds": time.perf_counter() - start}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--image-size", type=int, default=384)
    parser.add_argument("--cases", nargs="+", default=["ctx", "push"])
    args = parser.parse_args()
    print(f"{'case':6s} {'conv °':>7s} {'GSD m':>6s} {'RMSE m (before align)':>22s} "
          f"{'RMSE/GSD':>9s} {'RMSE m (aligned)':>17s} {'compl %':>8s} {'s':>6s}")
    with tempfile.TemporaryDirectory() as tmp:
        for case in args.cases:
            work = Path(tmp) / case
            work.mkdir()
            if case == "ctx":
                folder = SHARED / "ctx_knoten"
                if not folder.is_dir():
                    print(f"{case:6s} (skipped: {folder} absent)")
                    continue
                pair = (folder / "F02_036648_2021_XN_22N022W.cal.json",
                        folder / "J07_047448_2024_XN_22N022W.cal.json")
                extra = ["--relief", "15", "--crater-max", "600"]
            else:
                pair = tuple(push_frame_pair(work))
                extra = []
            r = route(*pair, work, args.image_size, extra)
            print(f"{case:6s} {r['convergence']:7.1f} {r['gsd']:6.2f} {r['rmse0']:22.3f} "
                  f"{r['rmse0'] / r['gsd']:9.2f} {r['rmse']:17.3f} {r['completeness']:8.1f} "
                  f"{r['seconds']:6.0f}")
    print("targets: RMSE before alignment < 1 GSD, completeness >= 95 %")


if __name__ == "__main__":
    main()
