"""Issue 29's checks on a synthetic block: pairs → rectify → sgm → dem per pair → fuse.

A block of ``--views`` (≥ 4) frame cameras on the Moon (``synth --sensor frame``, known
truth ``truth_dem_map.tif``) goes through the chain the Makefile's block product runs:
``demtool pairs`` chooses the pairs (overlap, convergence / B/H, sun), each pair is
rectified from its sensor models, matched by ``sgm`` and triangulated by ``dem``
(``--error-out``), and ``demtool fuse`` combines the pair DEMs (``--method mean``,
``--method median`` with the error rasters, and ``--method huber``).  Every DEM is
resampled onto the truth's grid (bilinear, exact map transformation) and measured
there, without alignment (the models are exact, so a shift would hide nothing):

* RMSE of each pair's DEM and of the fused DEM (target: fused ≤ 0.8 × the best pair's);
* completeness on the truth grid (target: fused ≥ the union of the pairs' − 1 %);
* seams: RMSE of the fused DEM within 10 cells of a pair DEM's boundary over the RMSE
  elsewhere (target ≤ 1.2).  A boundary cell is a cell of the truth grid inside one pair
  DEM next to a cell outside it (where that pair stops contributing).  The pairs' own
  rows show their error on the same band (all pairs' boundaries), for comparison.  Most
  of the band lies along the truth area's edge, where the images end too; ``interior
  seams`` cuts each pair DEM by a half-plane inside the area to test boundaries away
  from that edge.

Then the block's second pass: the pairs fused on the first DEM's grid (``fuse``'s default),
each pair matched again around that DEM (``sgm --prior-dem``: the right image warped by the
disparity it predicts, the residual searched), triangulated and fused again (rows ``pass
2``; the check's last column divides by the best first-pass pair, and the summary line
gives the ratio to the best pass-2 pair as well).

Then why the fused DEM does not gain more (:func:`error_structure`, uses the truth): the
pairs' error correlation with and without a shared image, the floor that the error
common to all pairs puts on any average, the best constant and local weights chosen
with the truth beside the weights the data gives, the part of the common error that is
the terrain low-passed by the matching windows, and the fused RMSE without
co-registration.  ``--no-noise`` renders the images without noise: the pairs' errors
that remain are the matcher's deterministic response to terrain and geometry.
The 6-view block of issue 29's seam check is ``--views 6``.

Usage: ``.venv/bin/python bench/fuse_block.py [--views 4] [--size 256] [--seed 0]
[--max-pairs 0] [--no-noise] [--keep DIR]`` (about 15 s of CPU per pair at 256 px).
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


def run_pair(scene: Path, folder: Path, left: str, right: str, dem: Path, error: Path,
             sgm_args: tuple[str, ...] = ()) -> None:
    """rectify (from the sensor models) → sgm (with ``sgm_args``) → dem (with its error
    raster)."""
    demtool("rectify", str(scene / f"{left}.tif"), str(scene / f"{right}.tif"),
            "--sensor-left", str(scene / f"{left}.json"), "--sensor-right",
            str(scene / f"{right}.json"), "--out", str(folder))
    demtool("sgm", str(folder / "left_rect.tif"), str(folder / "right_rect.tif"),
            "--rectify", str(folder / "rectify.npz"), *sgm_args, "--out",
            str(folder / "disparity.tif"))
    demtool("dem", "--disparity", str(folder / "disparity.tif"), "--rectify",
            str(folder / "rectify.npz"), "--error-out", str(error), "--out", str(dem))


def rematch_pair(folder: Path, prior: Path, out: Path) -> tuple[Path, Path]:
    """The pair of ``folder`` matched again around the ``prior`` DEM (sgm --prior-dem) and
    triangulated: the block's second pass."""
    out.mkdir(parents=True, exist_ok=True)
    dem, error = out / "dem.tif", out / "dem_error.tif"
    if not dem.is_file():
        demtool("sgm", str(folder / "left_rect.tif"), str(folder / "right_rect.tif"),
                "--rectify", str(folder / "rectify.npz"), "--prior-dem", str(prior),
                "--out", str(out / "disparity.tif"))
        demtool("dem", "--disparity", str(out / "disparity.tif"), "--rectify",
                str(folder / "rectify.npz"), "--error-out", str(error), "--out", str(dem))
    return dem, error


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


def interior_seams(work: Path, dems: list[Path], truth, inside: np.ndarray, uncut: Path
                   ) -> dict:
    """Seams where pair DEMs end inside the area: each pair DEM cut by a half-plane of its
    own direction (2π i / n, a quarter of the grid past the centre), fused with the
    default blending and without; the RMSE within ``SEAM_CELLS`` of a cut over the RMSE
    elsewhere (cells within ``SEAM_CELLS + 2`` of the truth's edge left out of both); and
    the same ratio for ``uncut`` (the pairs' fused DEM, no cut): where the band crosses
    worse ground (cast shadow), both are high, and only their difference is a seam."""
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
    diff = on_truth(uncut, truth) - truth.data  # the same band where nothing ends
    out["uncut"] = rmse(diff, band) / rmse(diff, ~band & interior)
    return out


def _min_variance_weights(second_moments: np.ndarray) -> np.ndarray:
    """The non-negative weights summing to 1 that minimise ``w @ S @ w`` (SLSQP)."""
    from scipy.optimize import minimize

    n = len(second_moments)
    result = minimize(lambda w: w @ second_moments @ w, np.full(n, 1.0 / n),
                      jac=lambda w: 2 * second_moments @ w, bounds=[(0.0, 1.0)] * n,
                      constraints=[{"type": "eq", "fun": lambda w: w.sum() - 1.0}],
                      method="SLSQP")
    return result.x


def _smooth(values: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian mean of the finite values (NaN-aware normalised convolution)."""
    from scipy.ndimage import gaussian_filter

    ok = np.isfinite(values)
    num = gaussian_filter(np.where(ok, values, 0.0), sigma)
    den = gaussian_filter(ok.astype(float), sigma)
    return num / np.maximum(den, 1e-9)


def shadow_cells(scene: Path, truth) -> np.ndarray:
    """Truth cells in cast shadow: their ground point, seen by the scene's target view
    (nadir), is darker than a quarter of that image's median (noise only: nothing to
    match, for every pair alike, as the sun is the same in every image)."""
    import json

    from scipy.ndimage import map_coordinates

    from demtool import io as dio
    from demtool.maps import MapGrid, grid_xyz
    from demtool.sensors.readers import read_sensor

    target = json.loads((scene / "scene.json").read_text())["target"]
    grid = MapGrid(crs=truth.crs, transform=truth.transform, width=truth.data.shape[1],
                   height=truth.data.shape[0])
    line, sample = read_sensor(scene / f"{target}.json").ground_to_image(
        grid_xyz(grid, np.nan_to_num(truth.data)))
    image = dio.read_raster(scene / f"{target}.tif", what="image").data.astype(float)
    dn = map_coordinates(image, [line - 0.5, sample - 0.5], order=1, cval=np.nan)
    return dn < 0.25 * np.nanmedian(dn)


def error_structure(errors: np.ndarray, pairs: list[tuple[str, str]], truth: np.ndarray,
                    spacing_m: float, shadow: np.ndarray) -> list[str]:
    """Why the pairs' errors correlate, and the bound it puts on any fusion (uses the
    truth: a diagnosis, not a method).  On the cells every pair covers:

    * the error correlation of pairs sharing an image against pairs sharing none;
    * the shared-error floor ``sqrt(mean_{i≠j} mean(e_i e_j))``: if each error is a part
      common to all pairs plus independent noise, no average removes the common part;
    * the best non-negative constant weights, chosen with the truth (minimum of
      ``w S w`` on the simplex, ``S`` the pairs' error second moments): no weighting by
      one number per DEM — B/H, a global variance — can do better;
    * local inverse-variance weights, the variance smoothed over 8 cells, from the truth
      (what local weights could give) and from each DEM's residual against the
      leave-one-out mean of the others, iterated (an M-estimator over the stack: what the
      data gives);
    * the share of the mean error that is the terrain low-passed (``a (G_σ * truth −
      truth)``, Gaussian σ in metres): the matching windows' smoothing, common to all;
      and the share of its squares in cast shadow (``shadow``, (H, W) bool).
    """
    n = len(errors)
    common = np.all(np.isfinite(errors), axis=0)
    e = errors[:, common]
    second = e @ e.T / e.shape[1]
    rms = np.sqrt(np.diag(second))
    best = rms.min()
    corr = np.corrcoef(e)
    sharing, disjoint = [], []
    for i in range(n):
        for j in range(i + 1, n):
            (sharing if set(pairs[i]) & set(pairs[j]) else disjoint).append(corr[i, j])
    lines = [f"error correlation: pairs sharing an image {np.mean(sharing):.2f} (n={len(sharing)})"
             + (f", pairs sharing none {np.mean(disjoint):.2f} (n={len(disjoint)})"
                if disjoint else ", no two pairs without a common image")]
    off = second[~np.eye(n, dtype=bool)]
    floor = np.sqrt(max(off.mean(), 0.0))
    lines.append(f"on the {e.shape[1]} cells every pair covers: best pair {best:.3f} m; plain "
                 f"mean {np.sqrt(np.mean(e.mean(0) ** 2)) / best:.3f}x; shared-error floor "
                 f"{floor:.3f} m = {floor / best:.3f}x")
    w = _min_variance_weights(second)
    lines.append(f"best non-negative constant weights (chosen with the truth): "
                 f"{np.sqrt(w @ second @ w) / best:.3f}x (weights "
                 + " ".join(f"{v:.2f}" for v in w) + ")")
    values = np.where(np.isfinite(errors), errors, np.nan)
    ok = np.isfinite(values)
    zero = np.where(ok, values, 0.0)

    def local_weighted(variances):
        weights = np.where(ok, 1.0 / np.maximum(variances, 1e-6), 0.0)
        return (weights * zero).sum(0) / np.maximum(weights.sum(0), 1e-12)

    oracle = local_weighted(np.stack([_smooth(v**2, 8.0) for v in values]))
    weights = ok.astype(float)
    for _ in range(5):
        total = (weights * zero).sum(0)
        norm = weights.sum(0)
        residual = [values[i] - (total - weights[i] * zero[i]) / np.maximum(norm - weights[i],
                                                                            1e-12)
                    for i in range(n)]
        weights = np.where(ok, 1.0 / np.maximum(
            np.stack([_smooth(r**2, 8.0) for r in residual]), 1e-6), 0.0)
    irls = (weights * zero).sum(0) / np.maximum(weights.sum(0), 1e-12)
    lines.append(f"local inverse-variance weights (8 cells): variance from the truth "
                 f"{rmse(oracle, common) / best:.3f}x, from the residual to the others' mean "
                 f"(iterated) {rmse(irls, common) / best:.3f}x")
    mean_error = e.mean(0)
    fits = []
    for sigma_m in (0.5, 1.0, 1.5, 2.0):
        low = (_smooth(truth, sigma_m / spacing_m) - truth)[common]
        a = (low @ mean_error) / (low @ low)
        fits.append((1 - np.var(mean_error - a * low) / np.var(mean_error), sigma_m, a))
    r2, sigma_m, a = max(fits)
    lines.append(f"mean error of the pairs = {a:.2f} x (G_{sigma_m:g}m * truth - truth) + rest: "
                 f"R^2 {r2:.2f} (terrain smoothed by the matching windows, common to all)")
    dark = shadow[common]
    lines.append(f"cast shadow: {100 * dark.mean():.1f} % of the cells, "
                 f"{100 * np.sum(mean_error[dark] ** 2) / np.sum(mean_error ** 2):.0f} % of the "
                 f"mean error's squares (correlation there "
                 f"{np.corrcoef(e[:, dark])[~np.eye(n, dtype=bool)].mean():.2f})")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=4)
    parser.add_argument("--size", type=int, default=256, help="DEM and image size, px")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-pairs", type=int, default=0)
    parser.add_argument("--keep", type=Path, help="work folder to keep (and resume from)")
    parser.add_argument("--no-noise", action="store_true",
                        help="images without photon and read noise (synth --no-noise)")
    parser.add_argument("--sgm-arg", action="append", default=[],
                        help="an option passed to every pair's sgm (repeat per word)")
    args = parser.parse_args(argv)
    work = args.keep or Path(tempfile.mkdtemp(prefix="fuse_block_"))
    scene = work / "scene"
    start = time.perf_counter()
    if not (scene / "scene.json").is_file():
        demtool("synth", "--sensor", "frame", "--views", str(args.views), "--seed",
                str(args.seed), "--size", str(args.size), "--image-size", str(args.size),
                *(["--no-noise"] if args.no_noise else []), "--out", str(scene))
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
                run_pair(scene, folder, left, right, dem, error, tuple(args.sgm_arg))
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
    for method in ("mean", "median", "huber"):
        out = work / f"fused_{method}.tif"
        extra = [a for e in errors for a in ("--error", str(e))] if method == "median" else []
        demtool("fuse", *map(str, dems), "--method", method, *extra, "--grid-like",
                str(scene / "truth_dem_map.tif"), "--out", str(out))
        fused[method] = out
    # The second pass, as a user runs it: the pairs fused on the first DEM's grid (fuse's
    # default), each pair matched again around that DEM, the new pair DEMs fused.
    prior = work / "fused_prior.tif"
    demtool("fuse", *map(str, dems), "--out", str(prior))
    dems2 = [rematch_pair(work / f"{left}+{right}", prior, work / "pass2" / f"{left}+{right}")[0]
             for left, right in pairs]
    fused["huber, pass 2"] = work / "fused_pass2.tif"
    demtool("fuse", *map(str, dems2), "--grid-like", str(scene / "truth_dem_map.tif"),
            "--out", str(fused["huber, pass 2"]))
    wall = time.perf_counter() - start

    from scipy.ndimage import binary_erosion

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
    interior = binary_erosion(inside, iterations=SEAM_CELLS + 2)
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
    best_pass2 = np.inf
    for (left, right), dem in zip(pairs, dems2, strict=True):
        diff = on_truth(dem, truth) - truth.data
        seam, rest, total = rmse(diff, band), rmse(diff, ~band & inside), rmse(diff)
        best_pass2 = min(best_pass2, total)
        compl = 100 * np.count_nonzero(np.isfinite(diff) & inside) / np.count_nonzero(inside)
        print(f"{left[-2:] + ' / ' + right[-2:] + ', pass 2':<22}{total:>9.3f}{compl:>9.2f}"
              f"{seam:>11.3f}{rest:>11.3f}{seam / rest:>7.2f}")
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
    print(f"\nunion of the pairs' completeness: {union_pct:.2f} %; best pair RMSE {best:.3f} m "
          f"(matched around the fused DEM: {best_pass2:.3f} m, fused pass 2 / that "
          f"{rmse(on_truth(fused['huber, pass 2'], truth) - truth.data) / best_pass2:.3f}); "
          f"boundary band: {np.count_nonzero(band)} cells within {SEAM_CELLS} of a pair "
          f"DEM's edge, {100 * np.count_nonzero(band & ~interior) / np.count_nonzero(band):.0f} "
          f"% of them within {SEAM_CELLS + 2} cells of the truth area's edge (where every "
          "image ends too)")
    errors_on_truth = np.stack([on_truth(d, truth) - truth.data for d in dems])
    for line in error_structure(errors_on_truth, pairs, truth.data, abs(truth.transform.a),
                                shadow_cells(scene, truth)):
        print(line)
    unaligned = work / "fused_align_none.tif"
    demtool("fuse", *map(str, dems), "--align", "none", "--grid-like", str(truth.path),
            "--out", str(unaligned))
    aligned_rmse = rmse(on_truth(fused["huber"], truth) - truth.data)
    print(f"co-registration: fused RMSE (huber, the default) {aligned_rmse:.3f} m aligned "
          f"(nuth-kaab), {rmse(on_truth(unaligned, truth) - truth.data):.3f} m with --align none")
    seams = interior_seams(work, dems, truth, inside, fused["huber"])
    print(f"{'check':<44}{'target':>10}" + "".join(f"{m:>10}" for m, *_ in checks[:3])
          + f"{'pass 2':>10}")
    print(f"{'fused RMSE / best pair RMSE':<44}{'<= 0.80':>10}"
          + "".join(f"{c[1]:>10.3f}" for c in checks))
    print(f"{'completeness − union of pairs (points)':<44}{'>= -1.00':>10}"
          + "".join(f"{c[2]:>10.2f}" for c in checks))
    print(f"{'seam RMSE / RMSE elsewhere':<44}{'<= 1.20':>10}"
          + "".join(f"{c[3]:>10.3f}" for c in checks))
    print(f"{'interior seams: seam RMSE / elsewhere':<44}{'<= 1.20':>10}"
          f"{seams['blend']:>10.3f}{'':>10}   (--blend 0: {seams['none']:.3f}; the uncut "
          f"pairs' fused DEM on the same band: {seams['uncut']:.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
