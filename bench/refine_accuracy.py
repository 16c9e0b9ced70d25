"""Accuracy of `demtool refine` (shape from shading) on synthetic scenes with known truth.

Scenes: the default demo scene (`demtool synth` defaults: sun 30° above the horizon,
512 × 512 target image at 0.5 m GSD) and the same terrain under a sun 15° and 45°
high (two views each: target and stereo partner).  Inputs, refined with the
command's defaults (the NavCam/LRO NAC parameters) through :func:`run_refine`:

* A — ``truth_dem_target`` low-passed with a Gaussian of σ = 6 px plus white noise of
  0.2 GSD (the issue's synthetic coarse DEM);
* B — the SIAM DEM of the pipeline (``rectify`` → ``sgm`` → ``dem --cameras``) when
  those stages are implemented; otherwise the row says why it was skipped.

Per scene and input: RMSE and NMAD of the heights against the truth, RMS slope error
(the RMS length of the difference of the gradient vectors, m/m, and the RMS
difference of the slope angles, degrees), the mean height shift (|shift| < 0.1 GSD),
the coherent cut-off frequency (`demtool.imaging.spectral.coherence_cutoff`, coherence with the
truth ≥ 0.5), before → after, and the ratios beside the targets: RMSE ≤ 0.6 × before,
slope error ≤ 0.5 × before, coherent frequency ≥ 2 × before.

There is no reference SfS tool in the environment (Ames Stereo Pipeline's ``sfs`` is
not installable here), so the "before" column (the input DEM) is the baseline.  Wall
times are on a shared 2-core machine.

Usage: ``.venv/bin/python bench/refine_accuracy.py [--quick]`` (--quick: 192-px scenes).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

from demtool import io
from demtool.imaging.robust import nmad
from demtool.imaging.spectral import coherence_cutoff
from demtool.logs import configure_logging
from demtool.refine.run import run_refine
from demtool.synth import SceneParams
from demtool.synth.run import run_synth

SMALL = dict(seed=0, dem_size=256, image_size=192, crater_count=20,
             crater_max_diameter_m=50.0, boulder_count=100)
ELEVATIONS = (30.0, 15.0, 45.0)  # 30° is the default scene (incidence 60°)


def gradient_error(dem: np.ndarray, truth: np.ndarray, gsd: float) -> tuple[float, float]:
    """RMS gradient-vector error (m/m) and RMS slope-angle error (degrees)."""
    dr, dc = np.gradient(dem.astype(float), gsd)
    tr, tc = np.gradient(truth.astype(float), gsd)
    vector = float(np.sqrt(np.nanmean((dr - tr) ** 2 + (dc - tc) ** 2)))
    angle = np.degrees(np.arctan(np.hypot(dr, dc))) - np.degrees(np.arctan(np.hypot(tr, tc)))
    return vector, float(np.sqrt(np.nanmean(angle**2)))


def metrics(dem: np.ndarray, truth: np.ndarray, gsd: float) -> dict[str, float]:
    error = (dem - truth)[np.isfinite(dem - truth)]
    vector, angle = gradient_error(dem, truth, gsd)
    return {"rmse": float(np.sqrt(np.mean(error**2))),
            "nmad": nmad(error),
            "slope": vector, "slope_deg": angle,
            "coherent": coherence_cutoff(dem, truth, spacing=gsd, threshold=0.5),
            "mean": float(np.mean(error))}


def input_a(truth: np.ndarray, gsd: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (ndimage.gaussian_filter(truth.astype(float), 6.0)
            + rng.normal(0.0, 0.2 * gsd, truth.shape)).astype(np.float32)


def input_b(scene_dir: Path, work: Path) -> tuple[Path | None, str]:
    """The SIAM DEM from rectify → sgm → dem --cameras, or (None, why not)."""
    import logging

    from demtool.dem.run import run_dem
    from demtool.errors import DemtoolError
    from demtool.rectify.run import run_rectify
    from demtool.sgm.run import run_sgm

    description = io.read_json(scene_dir / "scene.json")
    target, partner = description["target"], description["partner"]
    stereo = work / "stereo"
    steps = [
        ("rectify", lambda: run_rectify(scene_dir / f"{target}.tif",
                                        scene_dir / f"{partner}.tif", stereo)),
        ("sgm", lambda: run_sgm(stereo / "left_rect.tif", stereo / "right_rect.tif",
                                stereo / "disparity_sgm.tif", rectify=stereo / "rectify.npz")),
        ("dem", lambda: run_dem(work / "dem_siam.tif", disparity_path=stereo /
                                "disparity_sgm.tif", rectify_path=stereo / "rectify.npz",
                                cameras_path=scene_dir / "cameras.npz",
                                scene_path=scene_dir / "scene.json")),
    ]
    logger = logging.getLogger("demtool")
    level = logger.level
    logger.setLevel(logging.WARNING)  # quiet, as `demtool -q`
    try:
        for name, step in steps:
            try:
                step()
            except DemtoolError as exc:
                return None, f"SIAM chain stopped at `{name}`: {str(exc)[:90]}"
    finally:
        logger.setLevel(level)
    return work / "dem_siam.tif", ""


def refine(image: Path, dem: Path, out: Path) -> tuple[np.ndarray, float, int]:
    start = time.perf_counter()
    result = run_refine(image, dem, out)
    return result.dem, time.perf_counter() - start, result.iterations


def row(label: str, before: dict, after: dict, gsd: float, seconds: float, iterations: int):
    ratio_rmse = after["rmse"] / before["rmse"]
    ratio_slope = after["slope"] / before["slope"]
    ratio_coherent = after["coherent"] / max(before["coherent"], 1e-12)
    shift = (after["mean"] - before["mean"]) / gsd
    checks = [ratio_rmse <= 0.6, ratio_slope <= 0.5, ratio_coherent >= 2.0, abs(shift) < 0.1]
    print(f"{label:<15} {before['rmse']:6.3f} → {after['rmse']:6.3f} ({ratio_rmse:4.2f})"
          f"  {before['nmad']:6.3f} → {after['nmad']:6.3f}"
          f"  {before['slope']:5.3f} → {after['slope']:5.3f} ({ratio_slope:4.2f})"
          f"  {before['slope_deg']:5.2f} → {after['slope_deg']:5.2f}"
          f"  {shift:+7.4f}"
          f"  {before['coherent']:5.3f} → {after['coherent']:5.3f} ({ratio_coherent:4.1f}×)"
          f"  {seconds:5.1f} s/{iterations:2d} it  "
          + " ".join("ok" if c else "MISS" for c in checks))
    return checks


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="192-px scenes")
    parser.add_argument("--no-siam", action="store_true", help="skip input B")
    args = parser.parse_args()
    configure_logging(-1)
    base = SMALL if args.quick else {}
    print("refine accuracy: before → after (ratio); RMSE/NMAD m, slope error m/m "
          "(gradient vector) and degrees (slope angle), mean shift in GSD, coherent "
          "cut-off cycles/m")
    print("targets: RMSE ≤ 0.6 × before, slope ≤ 0.5 × before, coherent ≥ 2 × before, "
          "|shift| < 0.1 GSD  (flags in that order)")
    header = (f"{'scene/input':<15} {'RMSE m':<22}  {'NMAD m':<16}  {'slope m/m':<20}  "
              f"{'slope °':<14}  {'shift':>7}  {'coherent c/m':<23}  {'time':<12}  checks")
    print(header)
    print("-" * len(header))
    all_checks = []
    with tempfile.TemporaryDirectory(prefix="refine_bench_") as tmp:
        for elevation in ELEVATIONS:
            params = SceneParams(**base, n_views=2, sun_incidence_deg=90.0 - elevation)
            scene_dir = Path(tmp) / f"sun{elevation:.0f}"
            run_synth(scene_dir, params)
            description = io.read_json(scene_dir / "scene.json")
            image = scene_dir / f"{description['target']}.tif"
            truth_raster = io.read_raster(scene_dir / "truth_dem_target.tif")
            truth, gsd = truth_raster.data, truth_raster.spacing[0]
            label = f"sun {elevation:.0f}°" + (" (default)" if elevation == 30.0 else "")
            coarse = input_a(truth, gsd, seed=int(elevation))
            coarse_path = scene_dir / "input_a.tif"
            io.write_raster(coarse_path, coarse, transform=truth_raster.transform,
                            tags={"frame": truth_raster.tags.get("frame", "")})
            refined, seconds, iterations = refine(image, coarse_path, scene_dir / "ref_a.tif")
            print(f"{label}")
            all_checks.append(row("  A: σ6+noise", metrics(coarse, truth, gsd),
                                  metrics(refined, truth, gsd), gsd, seconds, iterations))
            if args.no_siam:
                continue
            siam, why = input_b(scene_dir, scene_dir / "siam")
            if siam is None:
                print(f"  B: SIAM DEM    skipped — {why}")
                continue
            siam_dem = io.read_raster(siam, allow_all_nan=True).data
            refined, seconds, iterations = refine(image, siam, scene_dir / "ref_b.tif")
            all_checks.append(row("  B: SIAM", metrics(siam_dem, truth, gsd),
                                  metrics(refined, truth, gsd), gsd, seconds, iterations))
    met = np.array(all_checks)
    names = ["RMSE", "slope", "coherent frequency", "mean shift"]
    print("targets met on every row: " + ", ".join(
        f"{n} {'yes' if met[:, i].all() else 'NO'}" for i, n in enumerate(names)))


if __name__ == "__main__":
    main()
