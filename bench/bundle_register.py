"""Issue 14: `bundle --reference-dem` started beyond the reach of the DEM's slopes.

Rendered orbital line-scan pairs (``synth --sensor linescan``: 100 km, 5 m pixels,
900 px, craters of 20 m–1.5 km, relief 10 m), the ISDs moved and turned by
(position m, pointing mrad) in random directions, ``--position-sigma`` and
``--pointing-sigma`` the same, a reference DEM = the map truth averaged over 4 × 4
cells (20 m posts) plus 1 m of noise.  ``bundle`` runs twice on the same inputs:
``--no-register-to-dem`` (the least-squares adjustment from the priors alone, what
ASP's ``bundle_adjust --heights-from-dem`` does without a ``pc_align`` first) and the
default (also from the prior block registered to the DEM; the lower cost wins).  The
score is what a DEM made with the adjusted models is off by: the mean and largest
distance (pixels) between where the adjusted and the true model see the same ground
points (9 × 9 pixels of each image cast through the true model onto the sphere).

Usage: ``.venv/bin/python bench/bundle_register.py [--seeds 0,1,2]
[--errors 50:0.5,200:2] [--keep DIR]`` (about 20 s a run; stages through
``python -m demtool`` as the Makefile chains them).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

SYNTH = ("--sensor", "linescan", "--altitude", "100000", "--gsd", "5", "--spacing", "5",
         "--size", "1200", "--image-size", "900", "--relief", "10", "--crater-min", "20",
         "--crater-max", "1500", "--craters", "80")


def _priors_bench():
    """bench/bundle_priors_dem.py, whose perturbation and reference DEM this bench shares
    (``bench`` as a namespace package from the repository root)."""
    from bench import bundle_priors_dem

    return bundle_priors_dem


def ground_offsets(scene: Path, adjusted: Path, names: list[str]) -> np.ndarray:
    """(N, 2): per image, the mean and largest distance (px) between where the adjusted
    and the true model see ground points (9 × 9 pixels of the image, cast through the
    true model onto the body's sphere)."""
    from demtool.sensors import ray_ellipsoid_intersection, read_sensor

    rows = []
    for name in names:
        true = read_sensor(scene / f"{name}.json")
        model = read_sensor(adjusted / f"{name}.json")
        line, sample = np.meshgrid(np.linspace(10, true.lines - 10, 9),
                                   np.linspace(10, true.samples - 10, 9), indexing="ij")
        ray = true.image_to_ray(line.ravel(), sample.ravel())
        ground = ray_ellipsoid_intersection(ray.origin, ray.direction, *true.radii)
        line1, sample1 = model.ground_to_image(ground)
        offset = np.hypot(line1 - line.ravel(), sample1 - sample.ravel())
        rows.append((offset.mean(), offset.max()))
    return np.array(rows)


def run(work: Path, seed: int, position_m: float, pointing_mrad: float) -> dict:
    """One scene and error level, both modes: ``{mode: (offsets (N, 2), summary)}``."""
    bench = _priors_bench()
    scene = work / f"scene_{seed}"
    if not scene.exists():
        bench.demtool("synth", *SYNTH, "--seed", seed, "--out", scene)
    names = sorted(p.stem for p in scene.glob("view_*.tif"))
    case = work / f"s{seed}_{position_m:g}_{pointing_mrad:g}"
    bench.POSITION_ERROR_M, bench.POINTING_ERROR_MRAD = position_m, pointing_mrad
    bench.perturb(scene, case / "perturbed", names, np.random.default_rng(seed + 1))
    reference, error = bench.degraded_reference(scene / "truth_dem_map.tif",
                                                case / "reference.tif", factor=4,
                                                noise_m=1.0, seed=seed + 2)
    out = {}
    for mode in ("--no-register-to-dem", "--register-to-dem"):
        folder = case / mode.strip("-")
        args = [scene / f"{n}.tif" for n in names]
        for n in names:
            args += ["--sensors", case / "perturbed" / f"{n}.json"]
        wall = bench.demtool("bundle", *args, "--position-sigma", position_m,
                             "--pointing-sigma", pointing_mrad, "--reference-dem", reference,
                             "--reference-dem-sigma", error, mode,
                             "--adjusted-dir", folder / "adjusted", "--out",
                             folder / "bundle.npz")
        summary = json.loads((folder / "bundle.npz.json").read_text())["summary"]
        out[mode] = (ground_offsets(scene, folder / "adjusted", names), summary, wall)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0,1,2", help="synth seeds, comma-separated")
    parser.add_argument("--errors", default="50:0.5,200:2",
                        help="position m:pointing mrad of the ISDs' errors, comma-separated")
    parser.add_argument("--keep", type=Path, default=None, help="work folder to keep")
    args = parser.parse_args()
    errors = [tuple(float(v) for v in e.split(":")) for e in args.errors.split(",")]
    print("| seed | ISD errors | from the priors: ground offset mean / max px | "
          "+ registered start: mean / max px | registration E, N, U m (used) | "
          "bundle s (priors / both) |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as scratch:
        work = args.keep or Path(scratch)
        for seed in (int(s) for s in args.seeds.split(",")):
            for position_m, pointing_mrad in errors:
                result = run(work, seed, position_m, pointing_mrad)
                (plain, _, wall0), (both, summary, wall1) = (
                    result["--no-register-to-dem"], result["--register-to-dem"])
                reg = summary["reference_dem"].get("registration")
                shift = (f"{reg['east_m']:+.0f}, {reg['north_m']:+.0f}, {reg['up_m']:+.0f} "
                         f"({'yes' if reg['used'] else 'no'})") if reg else "none"
                print(f"| {seed} | {position_m:g} m / {pointing_mrad:g} mrad | "
                      f"{plain[:, 0].mean():.2f} / {plain[:, 1].max():.2f} | "
                      f"{both[:, 0].mean():.2f} / {both[:, 1].max():.2f} | {shift} | "
                      f"{wall0:.0f} / {wall1:.0f} |", flush=True)


if __name__ == "__main__":
    main()
