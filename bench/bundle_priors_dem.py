"""Issue 14, check 2: a DEM from bundle-adjusted ISDs as accurate as from the true ones.

``synth --sensor frame`` renders a scene on the Moon's sphere with one frame ISD per
view.  Every ISD's position is moved by 50 m and its pointing by 0.5 mrad, in random
(seeded) directions, and the perturbed copies are the priors of ``bundle --sensors
--adjusted-dir`` (``--position-sigma 50 --pointing-sigma 0.5``).  The adjusted models'
errors against the true ISDs are reported (target: within 5 m / 0.05 mrad), then the
calibrated route of the Makefile's ``dem_frame`` product (``rectify --sensor-left
--sensor-right`` → ``sgm`` → ``dem`` → ``compare`` against ``truth_dem_map.tif``) runs
three times: with the true, the perturbed and the adjusted ISDs (each DEM compared
after a Nuth–Kääb shift, and after the shift plus ICP with scale).  Target: the
adjusted DEM as accurate as the true one.

Tie points fix the shape of the block, not its datum: a similarity (translation,
rotation, scale: 7 parameters) of all sensors and ground points leaves every image
unchanged, so the priors alone place it.  With independent 50 m errors on 8 sensors
1 km above the ground and a few hundred metres apart, the priors' best similarity is
off by a few percent in scale and tens of metres in height, and the DEM made with the
adjusted ISDs carries that offset (the script prints the similarity from the true to
the adjusted positions, and the move of the ground it implies, beside the DEM shift
that ``compare`` measures).  ``--zero-mean`` makes the errors pairwise opposite, which
cancels most of it.  With a narrow field of view (7° at 256 px) a lateral position
error e is also indistinguishable from a pointing error e / altitude, so pointing
is known only to about (position accuracy) / altitude.

Stages run through the CLI (``python -m demtool``) in subprocesses, as the Makefile
chains them.

With ``--reference-post N [--reference-noise M]`` the bundle also gets
``--reference-dem``: synth's map truth averaged over N×N cells plus noise (a LOLA-like
product), which ties the block's datum to the ground (bench/bundle_reference_dem.py
has the analytic orbital tables).  ``--synth '...'`` passes more synth options (an
orbital geometry).

Usage: ``.venv/bin/python bench/bundle_priors_dem.py [--size 256] [--image-size 256]
[--views 8] [--seed 0] [--zero-mean] [--reference-post N [--reference-noise M]]
[--synth '--altitude 100000 ...'] [--scene DIR] [--no-refine-ties] [--ties]
[--keep DIR]``

``--ties`` first prints each image pair's tie-observation error against the truth, split
along and across the pair's parallax direction, for SIFT and for SIFT + LSM (issue 14);
``--scene`` reuses a rendered scene; ``--no-refine-ties`` runs ``bundle`` on SIFT's
positions.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

POSITION_ERROR_M = 50.0
POINTING_ERROR_MRAD = 0.5


class StageFailed(RuntimeError):
    """A demtool stage exited non-zero; the message is its error line."""


def demtool(*args: str) -> float:
    """Run one demtool stage (``python -m demtool -q ...``); its wall time, seconds."""
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "demtool", "-q", *map(str, args)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        lines = [line for line in done.stderr.splitlines() if line.startswith("Error")]
        raise StageFailed(lines[-1] if lines else done.stderr.strip()[-500:])
    return time.perf_counter() - start


def random_unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def perturb(scene: Path, out: Path, names: list[str], rng: np.random.Generator, *,
            zero_mean: bool = False) -> None:
    """Write each view's ISD moved by 50 m and turned by 0.5 mrad (random directions;
    with ``zero_mean`` every second view takes the opposite of the previous one's
    offsets, so the block's mean error is zero where the number of views is even)."""
    from demtool.bundle.offsets import PoseOffset, pivot_of
    from demtool.bundle.writeback import adjust_isd, dumps_isd
    from demtool.sensors import read_sensor

    out.mkdir(parents=True, exist_ok=True)
    d_c = d_w = np.zeros(3)
    for i, name in enumerate(names):
        path = scene / f"{name}.json"
        if zero_mean and i % 2:
            d_c, d_w = -d_c, -d_w
        else:
            d_c = POSITION_ERROR_M * random_unit(rng)
            d_w = POINTING_ERROR_MRAD * 1e-3 * random_unit(rng)
        offset = PoseOffset(d_c, d_w, pivot_of(read_sensor(path)))
        isd = json.loads(path.read_text())
        (out / f"{name}.json").write_text(dumps_isd(adjust_isd(isd, offset)))


def pose_errors(folder: Path, scene: Path, names: list[str]) -> np.ndarray:
    """(N, 2) position error (m) and pointing error (mrad) of each model vs the truth;
    (2, 3) the block's common error: mean position offset (m, body-fixed) and mean
    rotation vector (mrad); (N, 2) the errors with that common error removed."""
    from demtool.bundle.offsets import rotation_vector
    from demtool.sensors import read_sensor

    errors, d_pos, d_rot = [], [], []
    for name in names:
        true = read_sensor(scene / f"{name}.json")
        model = read_sensor(folder / f"{name}.json")
        d_pos.append(model.position - true.position)
        d_rot.append(rotation_vector(model.rotation @ true.rotation.T) * 1e3)
        errors.append((np.linalg.norm(d_pos[-1]), np.linalg.norm(d_rot[-1])))
    common = np.array([np.mean(d_pos, axis=0), np.mean(d_rot, axis=0)])
    relative = np.stack([np.linalg.norm(np.array(d_pos) - common[0], axis=1),
                         np.linalg.norm(np.array(d_rot) - common[1], axis=1)], axis=1)
    return np.array(errors), common, relative


def datum_shift(folder: Path, scene: Path, names: list[str], target: str
                ) -> tuple[float, np.ndarray, float, float]:
    """The block's datum error, which tie points cannot see: the similarity (Umeyama
    1991) from the true sensor positions to the models' positions.

    Returns the scale − 1 (ppm), the shift (east, north, up; metres) that the
    similarity gives the ground point below the target camera (what a DEM made with
    these models is moved by) and the largest position residual after the similarity
    (metres) and the largest image displacement (pixels) of ground points near the
    target's footprint centre between the true models and these models with the points
    moved by the similarity (the block's shape error)."""
    from demtool.bundle.align import umeyama
    from demtool.sensors import read_sensor

    true_models = [read_sensor(scene / f"{n}.json") for n in names]
    models = [read_sensor(folder / f"{n}.json") for n in names]
    true = np.array([m.position for m in true_models])
    model = np.array([m.position for m in models])
    scale, rotation, translation = umeyama(true, model)
    isd = json.loads((scene / f"{target}.json").read_text())
    radius = float(isd["radii"]["semimajor"]) * (1000.0 if isd["radii"].get(
        "unit", "km").lower() == "km" else 1.0)
    up = true[names.index(target)] / np.linalg.norm(true[names.index(target)])
    ground = radius * up
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    moved = scale * rotation @ ground + translation - ground
    residual = np.linalg.norm(model - (scale * true @ rotation.T + translation), axis=1)
    # ground points around the target's footprint centre, moved by the similarity, seen
    # through the models, against the unmoved ones seen through the true models: the
    # block's shape error in pixels, the datum taken out
    offsets = np.linspace(-50.0, 50.0, 5)
    grid = np.array([ground + a * east + b * north for a in offsets for b in offsets])
    moved_grid = scale * grid @ rotation.T + translation
    pixels = 0.0
    for m, t in zip(models, true_models, strict=True):
        line, sample = m.ground_to_image(moved_grid)
        line0, sample0 = t.ground_to_image(grid)
        pixels = max(pixels, float(np.max(np.hypot(line - line0, sample - sample0))))
    return (scale - 1.0) * 1e6, np.array([moved @ east, moved @ north, moved @ up]), \
        float(residual.max()), pixels


def tie_bias(scene: Path, names: list[str], *, max_features: int | None = None,
             refine: bool = True) -> dict:
    """Bias of ``bundle``'s tie observations against the truth, per image pair (issue 14).

    The tracks of :func:`demtool.bundle.ties.tie_points` (all pairs; ``refine``: with
    the LSM refinement of :mod:`demtool.bundle.tierefine`) are cast, for every pair of
    images (i, j) that a track meets, from its observation in i onto synth's terrain
    (the renderer's ray cast through the true ISD) and projected into j through j's true
    ISD.  The observed-minus-true offset in j is split along the pair's parallax
    direction (where a ground point moves in j as it rises: a bias there is a height
    bias of the pair's tie points) and across it.  Returns ``{"i-j": (count, mean
    along, median along, mean across, median across, RMS, metres of height per pixel
    of parallax)}``, pixels (observations within 3 px).  A parallax bias of a few
    hundredths of a pixel is metres of height at orbital B/H, which ``--reference-dem``
    turns into a common offset of the block (README, issue 14).
    """
    from itertools import combinations

    from demtool import io as dio
    from demtool.bundle.ties import tie_points
    from demtool.sensors import read_sensor
    from demtool.synth import render
    from demtool.synth.body import placement

    body = json.loads((scene / "scene.json").read_text())["body"]
    place = placement(body["body"], body["center_lon_deg"], body["center_lat_deg"])
    dem = dio.read_raster(scene / "truth_dem.tif", what="truth DEM")
    field = render.height_field(dem.data.astype(np.float64), dem.transform)
    images = [dio.read_raster(scene / f"{n}.tif", what="image").data for n in names]
    models = [read_sensor(scene / f"{n}.json") for n in names]
    pairs = list(combinations(range(len(names)), 2))
    obs, _ = tie_points(images, pairs, max_features=max_features, refine=refine)
    pixels = np.column_stack([obs.sample - 0.5, obs.line - 0.5])
    ground = np.full((len(pixels), 3), np.nan)  # every observation cast through its view
    for i, model in enumerate(models):
        k = obs.image == i
        ground[k] = place.to_body(render.pixel_hits(field, model, pixels[k], placement=place))
    table = {}
    for i, j in pairs:
        in_i = np.full(obs.point_count, -1)
        in_j = np.full(obs.point_count, -1)
        in_i[obs.point[obs.image == i]] = np.flatnonzero(obs.image == i)
        in_j[obs.point[obs.image == j]] = np.flatnonzero(obs.image == j)
        both = (in_i >= 0) & (in_j >= 0)
        a, b = in_i[both], in_j[both]
        good = np.isfinite(ground[a, 0])
        a, b = a[good], b[good]
        line, sample = models[j].ground_to_image(ground[a])
        up = ground[a] / np.linalg.norm(ground[a], axis=1, keepdims=True)
        line2, sample2 = models[j].ground_to_image(ground[a] + 100.0 * up)
        rise = np.column_stack([sample2 - sample, line2 - line])
        px_per_100m = np.linalg.norm(rise, axis=1)
        rise /= px_per_100m[:, None]
        error = np.column_stack([obs.sample[b] - sample, obs.line[b] - line])
        ok = np.all(np.abs(error) < 3.0, axis=1)
        if not ok.any():
            continue
        along = np.sum(error * rise, axis=1)[ok]
        across = (rise[:, 0] * error[:, 1] - rise[:, 1] * error[:, 0])[ok]
        table[f"{i}-{j}"] = (int(ok.sum()), float(along.mean()), float(np.median(along)),
                             float(across.mean()), float(np.median(across)),
                             float(np.sqrt(np.mean(error[ok] ** 2))),
                             float(100.0 / np.median(px_per_100m[ok])))
    return table


def degraded_reference(truth: Path, out: Path, *, factor: int, noise_m: float,
                       seed: int) -> tuple[Path, float]:
    """A LOLA-like reference DEM: ``truth`` (the map truth of synth) averaged over
    ``factor × factor`` blocks (posts ``factor`` times coarser) plus Gaussian noise of
    ``noise_m`` metres, written with the truth's CRS and body tags.  Returns the path
    and the DEM's error at the truth's cells (RMS of the truth minus its block means,
    and the noise), metres."""
    from affine import Affine

    from demtool import io as dio

    raster = dio.read_raster(truth, what="truth DEM")
    h, w = (s // factor * factor for s in raster.data.shape)
    blocks = raster.data[:h, :w].reshape(h // factor, factor, w // factor, factor)
    with warnings.catch_warnings():  # blocks in the truth's no-data margin stay NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        coarse = np.nanmean(blocks.astype(np.float64), axis=(1, 3))
    detail = blocks - coarse[:, None, :, None]
    error = float(np.sqrt(np.nanmean(detail ** 2) + noise_m ** 2))
    coarse += np.random.default_rng(seed).normal(0.0, noise_m, coarse.shape)
    body_tags = {k: v for k, v in raster.tags.items()
                 if k.startswith("body") or k in ("reference_sphere_radius_m",
                                                  "height_reference")}
    dio.write_raster(out, coarse, transform=raster.transform @ Affine.scale(factor),
                     crs=raster.crs,
                     tags=body_tags)
    return out, error


def dem_route(scene: Path, isds: Path, work: Path, target: str, partner: str, *,
              similarity: bool = True) -> dict:
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
    if not similarity:
        report["_wall_s"] = wall
        return report
    # co-registered by a similarity too (shift, then ICP with scale): what is left once
    # the block's datum, which tie points cannot see, is taken out
    wall += demtool("compare", work / "dem.tif", scene / "truth_dem_map.tif",
                    "--align", "nuth-kaab+icp", "--icp-scale", "--no-plots",
                    "--out", work / "report_similarity", "--label", work.name)
    similarity = json.loads((work / "report_similarity" / "report.json").read_text())
    report["_rmse_similarity"] = similarity["rmse"]
    report["_wall_s"] = wall
    return report


def headline(report: dict) -> dict:
    """RMSE after and before alignment, mean difference before alignment, the
    alignment's shift (metres) and completeness, from compare's report.json."""
    before = report["before_alignment"]
    shift = report["shift"]
    sx, sy = report["grid"]["spacing_m"]
    return {"rmse": report["rmse"], "rmse_before": before["rmse"],
            "mean_before": before["mean"], "completeness": report["completeness"],
            "shift_m": (shift["dx_px"] * sx, shift["dy_px"] * sy, shift["dz"])}


def experiment(work: Path, *, size: int = 256, image_size: int = 256, views: int = 8,
               seed: int = 0, zero_mean: bool = False, say=print,
               synth_args: tuple = (), reference: tuple[int, float] | None = None,
               reference_sigma: float | None = None, max_features: int | None = None,
               similarity: bool = True, ties: bool = False, refine_ties: bool = True,
               scene: Path | None = None,
               routes: tuple[str, ...] = ("true", "perturbed", "adjusted")) -> dict:
    """Run the whole check in ``work``; print the tables through ``say`` and return
    ``{"pose": {label: (errors, common, relative)}, "datum": {label: datum_shift(...)},
    "dem": {label: report.json dict or the error line}}``.

    ``synth_args`` are more ``synth`` options (an orbital geometry: ``--altitude``,
    ``--gsd``, ``--spacing``, ``--relief`` …); ``reference`` = (post factor, noise m)
    adds ``--reference-dem``: the map truth degraded by
    :func:`degraded_reference`, weighted by ``reference_sigma`` (default: that DEM's
    RMS error at the truth's cells, at least 0.1 m); ``ties`` first prints
    :func:`tie_bias`; ``refine_ties`` False runs ``bundle --no-refine-ties``; ``scene``
    reuses a rendered ``synth --sensor frame`` folder (read only) instead of rendering
    one (``size``, ``image_size``, ``views``, ``synth_args`` are then ignored)."""
    results: dict = {"pose": {}, "datum": {}, "dem": {}}
    if scene is None:
        scene = work / "scene"
        wall = demtool("synth", "--sensor", "frame", "--size", size, "--image-size",
                       image_size, "--views", views, "--seed", seed, *synth_args,
                       "--out", scene)
    else:
        wall = 0.0
    description = json.loads((scene / "scene.json").read_text())
    target, partner = description["target"], description["partner"]
    names = sorted(p.stem for p in scene.glob("view_*.tif"))
    made = (f"synth --sensor frame --size {size} --image-size {image_size} --views "
            f"{len(names)} --seed {seed}: {wall:.1f} s" if wall else f"scene {scene}")
    say(f"{made}; errors " + ("pairwise opposite (zero mean)" if zero_mean
                              else "independent")
        + ("" if refine_ties else "; bundle --no-refine-ties"))

    if ties:
        say("\nTie observations minus their true positions, per image pair (observation in "
            "i cast onto the truth through the true ISD, projected into j), pixels")
        say("| ties | pair | observations | mean along base | median along | mean across "
            "| median across | RMS | m height / px | mean along → m height |")
        say("|---|---|---|---|---|---|---|---|---|---|")
        for label, refine in (("SIFT", False), ("SIFT + LSM", True)):
            for pair, row in tie_bias(scene, names, max_features=max_features,
                                      refine=refine).items():
                say(f"| {label} | {pair} | {row[0]} | "
                    + " | ".join(f"{v:+.4f}" for v in row[1:5])
                    + f" | {row[5]:.3f} | {row[6]:.0f} | {row[1] * row[6]:+.2f} |")
    perturb(scene, work / "perturbed", names, np.random.default_rng(seed + 1),
            zero_mean=zero_mean)
    extra: list = ["--refine-ties" if refine_ties else "--no-refine-ties"]
    if max_features is not None:
        extra += ["--max-features", max_features]
    if reference is not None:
        factor, noise = reference
        ref, error = degraded_reference(scene / "truth_dem_map.tif",
                                        work / "reference_dem.tif", factor=factor,
                                        noise_m=noise, seed=seed + 2)
        if reference_sigma is None:
            reference_sigma = max(error, 0.1)
        extra += ["--reference-dem", ref, "--reference-dem-sigma", reference_sigma]
        say(f"reference DEM: truth averaged over {factor}×{factor} posts, noise {noise} m, "
            f"--reference-dem-sigma {reference_sigma:.2f} m")
    wall = demtool("bundle", *[scene / f"{n}.tif" for n in names], *extra,
                   *[a for n in names for a in ("--sensors", work / "perturbed" /
                                                f"{n}.json")],
                   "--matcher", "spatial", "--position-sigma", POSITION_ERROR_M,
                   "--pointing-sigma", POINTING_ERROR_MRAD,
                   "--adjusted-dir", work / "adjusted", "--out", work / "bundle.npz")
    summary = json.loads((work / "bundle.npz.json").read_text())
    say(f"bundle: {wall:.1f} s")

    say("\nPose errors against the true ISDs (target: adjusted within 5 m / 0.05 mrad)")
    say("| models | max position m | mean position m | max pointing mrad "
        "| mean pointing mrad | common offset m | common rotation mrad "
        "| max position m, common removed | max pointing mrad, common removed |")
    say("|---|---|---|---|---|---|---|---|---|")
    for label in ("perturbed", "adjusted"):
        errors, common, relative = results["pose"][label] = pose_errors(work / label, scene,
                                                                        names)
        say(f"| {label} | {errors[:, 0].max():.2f} | {errors[:, 0].mean():.2f} | "
            f"{errors[:, 1].max():.4f} | {errors[:, 1].mean():.4f} | "
            f"{np.linalg.norm(common[0]):.2f} | {np.linalg.norm(common[1]):.4f} | "
            f"{relative[:, 0].max():.2f} | {relative[:, 1].max():.4f} |")
    say("\nDatum (similarity true → model positions; tie points cannot see it)")
    say("| models | scale − 1 ppm | ground below the target moved E, N, U m "
        "| max position residual m | max image residual px |")
    say("|---|---|---|---|---|")
    for label in ("perturbed", "adjusted"):
        ppm, moved, residual, pixels = results["datum"][label] = datum_shift(
            work / label, scene, names, target)
        say(f"| {label} | {ppm:.0f} | {moved[0]:.2f}, {moved[1]:.2f}, {moved[2]:.2f} | "
            f"{residual:.2f} | {pixels:.2f} |")
    per_image = summary.get("summary", summary).get("images", None)
    if per_image:
        say("\n| view | observations | mean residual px | position change m "
            "| pointing change mrad |")
        say("|---|---|---|---|---|")
        for name, row in per_image.items():
            say(f"| {name} | {row['observations']} | {row['mean_residual_px']:.3f} | "
                f"{row['position_change_m']:.2f} | {row['pointing_change_mrad']:.3f} |")

    say(f"\nDEM ({target}/{partner}, rectify --sensor-* → sgm → dem → compare vs "
        "truth_dem_map.tif; target: adjusted as accurate as true)")
    say("| ISDs | RMSE m (Nuth-Kääb) | RMSE m (+ ICP with scale) | RMSE m (before) "
        "| mean diff m (before) | alignment shift dx, dy, dz m | completeness % "
        "| time s |")
    say("|---|---|---|---|---|---|---|---|")
    for label, folder in (("true", scene), ("perturbed", work / "perturbed"),
                          ("adjusted", work / "adjusted")):
        if label not in routes:
            continue
        try:
            report = dem_route(scene, folder, work / f"dem_{label}", target, partner,
                               similarity=similarity)
        except StageFailed as exc:
            results["dem"][label] = str(exc)
            say(f"| {label} | — | — | — | — | — | — | — | {exc}")
            continue
        results["dem"][label] = report
        h = headline(report)
        dx, dy, dz = h["shift_m"]
        similar = report.get("_rmse_similarity", float("nan"))
        say(f"| {label} | {h['rmse']:.3f} | {similar:.3f} | "
            f"{h['rmse_before']:.3f} | {h['mean_before']:.3f} | "
            f"{dx:.2f}, {dy:.2f}, {dz:.2f} | {h['completeness']:.1f} | "
            f"{report['_wall_s']:.0f} |")
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=256, help="synth --size (DEM cells)")
    parser.add_argument("--image-size", type=int, default=256, help="synth --image-size")
    parser.add_argument("--views", type=int, default=8, help="synth --views")
    parser.add_argument("--seed", type=int, default=0, help="seed of synth and the errors")
    parser.add_argument("--zero-mean", action="store_true",
                        help="pairwise opposite errors: the block's mean error is zero")
    parser.add_argument("--reference-post", type=int, default=None,
                        help="bundle --reference-dem: the truth averaged over N×N cells")
    parser.add_argument("--reference-noise", type=float, default=0.0,
                        help="Gaussian noise of that reference DEM, metres")
    parser.add_argument("--max-features", type=int, default=None,
                        help="bundle option (default: bundle's)")
    parser.add_argument("--synth", default="",
                        help="more synth options, e.g. '--altitude 100000 --gsd 100'")
    parser.add_argument("--routes", default="true,perturbed,adjusted",
                        help="the ISDs to run the DEM route with (comma-separated)")
    parser.add_argument("--no-similarity", action="store_true",
                        help="skip the compare with a similarity co-registration")
    parser.add_argument("--ties", action="store_true",
                        help="report the tie observations' bias against the truth")
    parser.add_argument("--no-refine-ties", action="store_true",
                        help="bundle --no-refine-ties (SIFT tie points as detected)")
    parser.add_argument("--scene", type=Path, default=None,
                        help="reuse this synth --sensor frame folder (read only)")
    parser.add_argument("--keep", type=Path, default=None, help="work folder to keep")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        experiment(args.keep or Path(scratch), size=args.size, image_size=args.image_size,
                   views=args.views, seed=args.seed, zero_mean=args.zero_mean,
                   synth_args=tuple(args.synth.split()), max_features=args.max_features,
                   reference=None if args.reference_post is None else
                   (args.reference_post, args.reference_noise),
                   routes=tuple(args.routes.split(",")), similarity=not args.no_similarity,
                   ties=args.ties, refine_ties=not args.no_refine_ties, scene=args.scene,
                   say=lambda text: print(text, flush=True))


if __name__ == "__main__":
    main()
