"""Issue 29's checks on a synthetic block: pairs → rectify → sgm → dem per pair → fuse.

A block of ``--views`` (≥ 4) frame cameras on the Moon (``synth --sensor frame``, known
truth ``truth_dem_map.tif``) goes through the chain the Makefile's block product runs:
``demtool pairs`` chooses the pairs (overlap, convergence / B/H, sun), each pair is
rectified from its sensor models, matched by ``sgm`` and triangulated by ``dem``
(``--error-out``), and ``demtool fuse`` combines the pair DEMs (``--method mean``, and
``--method median`` with the error rasters).  Every DEM is resampled onto the truth's
grid (bilinear, exact map transformation) and measured there, without alignment (the
models are exact, so a shift would hide nothing):

* RMSE of each pair's DEM and of the fused DEM (target: fused ≤ 0.8 × the best pair's);
* completeness on the truth grid (target: fused ≥ the union of the pairs' − 1 %);
* seams: RMSE of the fused DEM within 10 cells of a pair DEM's boundary over the RMSE
  elsewhere (target ≤ 1.2).  A boundary cell is a cell of the truth grid inside one pair
  DEM next to a cell outside it (where that pair stops contributing).

Usage: ``.venv/bin/python bench/fuse_block.py [--views 4] [--size 256] [--seed 0]
[--max-pairs 0] [--keep DIR]`` (about 40 s of CPU per pair at 256 px on 2 cores).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SEAM_CELLS = 10


class StageFailed(Exception):
    pass


def demtool(*args: str) -> None:
    command = [sys.executable, "-m", "demtool", "-q", *args]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    if result.returncode != 0:
        raise StageFailed(f"demtool {args[0]}: {result.stderr.strip().splitlines()[-1]}")


def run_pair(scene: Path, folder: Path, left: str, right: str, dem: Path, error: Path) -> None:
    """rectify (from the sensor models) → sgm → dem (with its error raster)."""
    demtool("rectify", str(scene / f"{left}.tif"), str(scene / f"{right}.tif"),
            "--sensor-left", str(scene / f"{left}.json"), "--sensor-right",
            str(scene / f"{right}.json"), "--out", str(folder))
    demtool("sgm", str(folder / "left_rect.tif"), str(folder / "right_rect.tif"),
            "--rectify", str(folder / "rectify.npz"), "--out", str(folder / "disparity.tif"))
    demtool("dem", "--disparity", str(folder / "disparity.tif"), "--rectify",
            str(folder / "rectify.npz"), "--error-out", str(error), "--out", str(dem))


def on_truth(path: Path, truth) -> np.ndarray:
    from demtool import io as dio
    from demtool.compare.grids import Grid, resample_to_grid

    raster = dio.read_raster(path, what="DEM")
    return resample_to_grid(raster.data, Grid(raster.data.shape, raster.transform, raster.crs),
                            Grid(truth.data.shape, truth.transform, truth.crs))


def rmse(diff: np.ndarray, where: np.ndarray | None = None) -> float:
    values = diff[np.isfinite(diff) & (True if where is None else where)]
    return float(np.sqrt(np.mean(values**2))) if values.size else float("nan")


def boundary_band(masks: list[np.ndarray], inside: np.ndarray, width: int) -> np.ndarray:
    """Cells within ``width`` cells of where some pair DEM's coverage ends inside the truth
    area (its cells next to a truth cell it does not cover)."""
    from scipy.ndimage import binary_dilation

    band = np.zeros(masks[0].shape, dtype=bool)
    for mask in masks:
        band |= mask & binary_dilation(~mask & inside)
    disk = np.hypot(*np.mgrid[-width:width + 1, -width:width + 1]) <= width
    return binary_dilation(band, structure=disk)


def interior_seams(work: Path, dems: list[Path], truth, inside: np.ndarray) -> dict:
    """Seams where pair DEMs end inside the area: each pair DEM cut by a half-plane of its
    own direction (2π i / n, a quarter of the grid past the centre), fused with the
    default blending and without; the RMSE within ``SEAM_CELLS`` of a cut over the RMSE
    elsewhere (cells within ``SEAM_CELLS + 2`` of the truth's edge left out of both)."""
    from scipy.ndimage import binary_erosion

    from demtool import io as dio

    folder = work / "interior_seams"
    folder.mkdir(exist_ok=True)
    cut = []
    for i, dem in enumerate(dems):
        raster = dio.read_raster(dem, what="DEM")
        h, w = raster.data.shape
        rows, cols = np.mgrid[0:h, 0:w]
        angle = 2 * np.pi * i / len(dems)
        keep = ((cols - w / 2) * np.cos(angle) + (rows - h / 2) * np.sin(angle)) < 0.25 * w
        path = folder / f"cut_{i}.tif"
        dio.write_raster(path, np.where(keep, raster.data, np.nan), transform=raster.transform,
                         crs=raster.crs, tags=raster.tags)
        cut.append(path)
    masks = [np.isfinite(on_truth(p, truth)) & inside for p in cut]
    interior = binary_erosion(inside, iterations=SEAM_CELLS + 2)
    band = boundary_band(masks, inside, SEAM_CELLS) & interior
    out = {}
    for name, blend in (("blend", []), ("none", ["--blend", "0"])):
        fused = folder / f"fused_{name}.tif"
        demtool("fuse", *map(str, cut), *blend, "--grid-like",
                str(truth.path), "--out", str(fused))
        diff = on_truth(fused, truth) - truth.data
        out[name] = rmse(diff, band) / rmse(diff, ~band & interior)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=4)
    parser.add_argument("--size", type=int, default=256, help="DEM and image size, px")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-pairs", type=int, default=0)
    parser.add_argument("--keep", type=Path, help="work folder to keep (and resume from)")
    args = parser.parse_args(argv)
    work = args.keep or Path(tempfile.mkdtemp(prefix="fuse_block_"))
    scene = work / "scene"
    start = time.perf_counter()
    if not (scene / "scene.json").is_file():
        demtool("synth", "--sensor", "frame", "--views", str(args.views), "--seed",
                str(args.seed), "--size", str(args.size), "--image-size", str(args.size),
                "--out", str(scene))
    models = sorted(str(p) for p in scene.glob("view_*.json"))
    demtool("pairs", *models, "--max-pairs", str(args.max_pairs), "--out",
            str(work / "pairs.txt"))
    pairs = [line.split() for line in (work / "pairs.txt").read_text().splitlines()]
    dems, errors, failed, kept = [], [], [], []
    for left, right in pairs:
        folder = work / f"{left}+{right}"
        dem, error = folder / "dem.tif", folder / "dem_error.tif"
        if (folder / "failed.txt").is_file():
            failed.append((left, right, (folder / "failed.txt").read_text().strip()))
            continue
        try:
            if not dem.is_file():
                run_pair(scene, folder, left, right, dem, error)
        except StageFailed as exc:  # a pair the chain cannot match: reported, not fused
            folder.mkdir(parents=True, exist_ok=True)
            (folder / "failed.txt").write_text(str(exc))
            failed.append((left, right, str(exc)))
            continue
        kept.append((left, right))
        dems.append(dem)
        errors.append(error)
    pairs = kept
    fused = {}
    for method in ("mean", "median"):
        out = work / f"fused_{method}.tif"
        extra = [a for e in errors for a in ("--error", str(e))] if method == "median" else []
        demtool("fuse", *map(str, dems), "--method", method, *extra, "--grid-like",
                str(scene / "truth_dem_map.tif"), "--out", str(out))
        fused[method] = out
    wall = time.perf_counter() - start

    from demtool import io as dio

    truth = dio.read_raster(scene / "truth_dem_map.tif", what="truth")
    inside = np.isfinite(truth.data)
    rows = []
    masks = []
    for (left, right), dem in zip(pairs, dems, strict=True):
        values = on_truth(dem, truth)
        masks.append(np.isfinite(values) & inside)
        rows.append((f"{left} / {right}", rmse(values - truth.data),
                     100 * np.count_nonzero(masks[-1]) / np.count_nonzero(inside)))
    union = np.logical_or.reduce(masks)
    union_pct = 100 * np.count_nonzero(union) / np.count_nonzero(inside)
    band = boundary_band(masks, inside, SEAM_CELLS) & inside
    best = min(r[1] for r in rows)
    print(f"synthetic block: {args.views} frame views on the Moon, {args.size} px, seed "
          f"{args.seed}; {len(pairs)} pairs chosen by `demtool pairs`; {wall:.0f} s")
    for left, right, why in failed:
        print(f"pair {left} / {right} left out: {why}")
    print(f"{'DEM':<22}{'RMSE m':>9}{'compl %':>9}{'seam RMSE':>11}{'else RMSE':>11}"
          f"{'ratio':>7}")
    for (name, value, compl), dem in zip(rows, dems, strict=True):
        diff = on_truth(dem, truth) - truth.data
        seam, rest = rmse(diff, band), rmse(diff, ~band & inside)
        print(f"{name:<22}{value:>9.3f}{compl:>9.2f}{seam:>11.3f}{rest:>11.3f}"
              f"{seam / rest:>7.2f}")
    checks = []
    for method, path in fused.items():
        values = on_truth(path, truth)
        diff = values - truth.data
        compl = 100 * np.count_nonzero(np.isfinite(values) & inside) / np.count_nonzero(inside)
        seam, rest = rmse(diff, band), rmse(diff, ~band & inside)
        total = rmse(diff)
        print(f"{'fused ' + method:<22}{total:>9.3f}{compl:>9.2f}{seam:>11.3f}{rest:>11.3f}"
              f"{seam / rest:>7.2f}")
        checks.append((method, total / best, compl - union_pct, seam / rest))
    print(f"\nunion of the pairs' completeness: {union_pct:.2f} %; best pair RMSE {best:.3f} m; "
          f"boundary band: {np.count_nonzero(band)} cells within {SEAM_CELLS} of a pair "
          "DEM's edge")
    errors_on_truth = np.stack([on_truth(d, truth) - truth.data for d in dems])
    common = np.all(np.isfinite(errors_on_truth), axis=0)
    corr = np.corrcoef(errors_on_truth[:, common])
    off = corr[~np.eye(len(corr), dtype=bool)]
    print(f"correlation of the pairs' errors: mean {off.mean():.2f}, range {off.min():.2f} … "
          f"{off.max():.2f}; RMSE of the plain mean of the pairs on the truth grid "
          f"{rmse(errors_on_truth[:, common].mean(axis=0)):.3f} m (cells all pairs cover)")
    seams = interior_seams(work, dems, truth, inside)
    print(f"{'check':<44}{'target':>10}" + "".join(f"{m:>10}" for m, *_ in checks))
    print(f"{'fused RMSE / best pair RMSE':<44}{'<= 0.80':>10}"
          + "".join(f"{c[1]:>10.3f}" for c in checks))
    print(f"{'completeness − union of pairs (points)':<44}{'>= -1.00':>10}"
          + "".join(f"{c[2]:>10.2f}" for c in checks))
    print(f"{'seam RMSE / RMSE elsewhere':<44}{'<= 1.20':>10}"
          + "".join(f"{c[3]:>10.3f}" for c in checks))
    print(f"{'interior seams: seam RMSE / elsewhere':<44}{'<= 1.20':>10}"
          f"{seams['blend']:>10.3f}{'':>10}   (--blend 0: {seams['none']:.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
