"""`demtool bundle`: pycolmap SfM, conventions, alignment, errors."""

from __future__ import annotations

import json
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import bundle as core
from demtool import io as dio
from demtool.camera import PinholeCamera, cameras_from_arrays, look_at, to_pycolmap
from demtool.cli import cli
from demtool.errors import ProcessingError

APOLLO = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "apollo15"


def write_selection(path: Path, images: list[tuple[str, Path]]) -> Path:
    content = {
        "target": {"name": images[0][0], "path": str(images[0][1])},
        "roi": None,
        "selected": [{"name": n, "path": str(p), "matches": 100, "inliers": 90,
                      "overlap": 1.0} for n, p in images],
        "rejected": [],
        "parameters": {},
    }
    path.write_text(json.dumps(content))
    return path


def rotation(ax: float, ay: float, az: float) -> np.ndarray:
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    return (np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
            @ np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
            @ np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]]))


# --------------------------------------------------------------------------------------
# Pure functions
# --------------------------------------------------------------------------------------


def test_umeyama_recovers_a_known_similarity():
    rng = np.random.default_rng(0)
    source = rng.normal(size=(6, 3)) * 10
    R = rotation(0.3, -0.7, 1.9)
    target = 3.7 * source @ R.T + np.array([100.0, -20.0, 5.0])
    scale, R_est, t_est = core.umeyama(source, target)
    assert scale == pytest.approx(3.7, rel=1e-12)
    np.testing.assert_allclose(R_est, R, atol=1e-12)
    np.testing.assert_allclose(t_est, [100.0, -20.0, 5.0], atol=1e-9)
    assert np.linalg.det(R_est) == pytest.approx(1.0)


def test_umeyama_rejects_too_few_and_collinear_centres():
    with pytest.raises(ProcessingError, match="at least 3"):
        core.umeyama(np.zeros((2, 3)), np.zeros((2, 3)))
    line = np.outer(np.arange(4.0), [1.0, 2.0, 0.5])
    with pytest.raises(ProcessingError, match="collinear"):
        core.umeyama(line, line * 2)


def make_result(n_points: int = 50) -> core.BundleResult:
    rng = np.random.default_rng(1)
    points = np.column_stack([rng.uniform(-20, 20, (n_points, 2)), rng.normal(0, 1, n_points)])
    cameras = [look_at([x, y, 300.0], [0, 0, 0], focal_px=800, width=200, height=150)
               for x, y in [(0, 0), (60, 0), (0, 70), (-50, -40)]]
    return core.BundleResult(points=points, colors=np.ones(n_points),
                             track_length=np.full(n_points, 3),
                             reprojection_error=np.full(n_points, 0.1),
                             image_names=np.array(["a", "b", "c", "d"]), cameras=cameras,
                             distortion=np.zeros((4, 2)), target_index=0)


def test_similarity_keeps_projections_and_alignment_recovers_centres():
    truth = make_result()
    R = rotation(0.1, 0.2, -0.4)
    # A model frame: scaled, rotated and shifted copy of the truth.
    inverse_scale, inverse_R, inverse_t = 0.02, R, np.array([1.0, 2.0, 3.0])
    model = core.apply_similarity(truth, inverse_scale, inverse_R, inverse_t)
    for cam_truth, cam_model in zip(truth.cameras, model.cameras, strict=True):
        np.testing.assert_allclose(cam_model.project(model.points),
                                   cam_truth.project(truth.points), atol=1e-9)
    centres = {str(n): c.center for n, c in zip(truth.image_names, truth.cameras, strict=True)}
    aligned, report = core.align_to_centres(
        core.BundleResult(**{**model.__dict__, "aligned": False}), centres)
    assert aligned.aligned
    assert report["scale"] == pytest.approx(1 / inverse_scale)
    assert report["centre_rms_m"] < 1e-9
    np.testing.assert_allclose(aligned.points, truth.points, atol=1e-8)


def test_alignment_needs_three_known_centres():
    result = make_result()
    with pytest.raises(ProcessingError, match="at least 3 registered images"):
        core.align_to_centres(result, {"a": np.zeros(3), "b": np.ones(3), "zz": np.ones(3)})


@pytest.mark.parametrize("model, extra", [("SIMPLE_PINHOLE", []), ("SIMPLE_RADIAL", [-0.05]),
                                          ("RADIAL", [0.03, -0.01])])
def test_projection_matches_colmap_with_half_pixel_convention(model, extra):
    """demtool's K (pixel centres at integers) + distortion reproduce COLMAP's projection
    of the same camera shifted by 0.5 px (COLMAP puts the first pixel centre at 0.5)."""
    import pycolmap

    from demtool.camera import from_pycolmap

    camera = look_at([30.0, -20.0, 400.0], [0, 0, 0], focal_px=900, width=320, height=240)
    colmap_camera, pose = to_pycolmap(camera)
    f = camera.K[0, 0]
    params = [f, camera.K[0, 2] + 0.5, camera.K[1, 2] + 0.5, *extra]
    colmap_camera = pycolmap.Camera(model=model, width=320, height=240, params=params,
                                    camera_id=1)
    image = SimpleNamespace(cam_from_world=pose)  # a registered pycolmap Image's pose
    converted = from_pycolmap(image, colmap_camera)
    np.testing.assert_allclose(converted.K, camera.K, atol=1e-12)
    np.testing.assert_allclose(converted.R, camera.R, atol=1e-12)
    distortion = core.radial_terms(colmap_camera)
    rng = np.random.default_rng(2)
    points = np.column_stack([rng.uniform(-60, 60, (20, 2)), rng.normal(0, 3, 20)])
    ours, depth = core.project_points(converted, points, distortion)
    cam_points = points @ camera.R.T + camera.t
    colmap = np.array([colmap_camera.img_from_cam(p) for p in cam_points])
    np.testing.assert_allclose(ours, colmap - 0.5, atol=1e-9)
    np.testing.assert_allclose(depth, cam_points[:, 2])


def test_to_uint8_keeps_8bit_data_and_stretches_others():
    from demtool.bundle import to_uint8

    eight_bit = np.arange(256, dtype=np.float32).reshape(16, 16)
    np.testing.assert_array_equal(to_uint8(eight_bit), eight_bit.astype(np.uint8))
    twelve_bit = np.linspace(100, 4000, 400, dtype=np.float32).reshape(20, 20)
    twelve_bit[0, 0] = np.nan
    converted = to_uint8(twelve_bit)
    assert converted.dtype == np.uint8 and converted[0, 0] == 0
    assert converted.max() == 255 and converted.ravel()[1:].min() <= 1


# --------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------


def scene_selection(scene_dir: Path, tmp_path: Path) -> Path:
    scene = json.loads((scene_dir / "scene.json").read_text())
    names = [scene["target"]] + [n for n in scene["names"] if n != scene["target"]]
    return write_selection(tmp_path / "selection.json",
                           [(n, scene_dir / f"{n}.tif") for n in names])


@pytest.mark.slow
def test_bundle_registers_synthetic_views_and_aligns(small_scene_dir, tmp_path):
    selection = scene_selection(small_scene_dir, tmp_path)
    out = tmp_path / "bundle.npz"
    result = CliRunner().invoke(cli, ["-q", "bundle", str(selection), "--out", str(out),
                                      "--align-cameras", str(small_scene_dir / "cameras.npz"),
                                      "--colmap-dir", str(tmp_path / "colmap")])
    assert result.exit_code == 0, result.output
    bundle = dio.read_npz(out, "bundle")
    truth = cameras_from_arrays(dio.read_npz(small_scene_dir / "cameras.npz", "cameras"))
    names = [str(n) for n in bundle["image_names"]]
    assert sorted(names) == sorted(truth)  # every view registered
    assert names[int(bundle["target_index"])] == "view_00"
    assert bool(bundle["aligned"])
    assert len(bundle["points"]) > 100
    assert float(np.mean(bundle["reprojection_error"])) < 1.0
    assert bundle["track_length"].min() >= 2
    # Aligned cameras: centres within 1 % of the 1000 m distance (narrow field of view:
    # focal length and distance are nearly ambiguous), points on the truth surface.
    cameras = cameras_from_arrays(bundle)
    for name, camera in cameras.items():
        assert np.linalg.norm(camera.center - truth[name].center) < 10.0
    dem = dio.read_raster(small_scene_dir / "truth_dem.tif")
    inside = (np.abs(bundle["points"][:, 0]) < 90) & (np.abs(bundle["points"][:, 1]) < 90)
    cols = ((bundle["points"][inside, 0] - dem.transform.c) / dem.transform.a).astype(int)
    rows = ((bundle["points"][inside, 1] - dem.transform.f) / dem.transform.e).astype(int)
    height_error = bundle["points"][inside, 2] - dem.data[rows, cols]
    assert np.median(np.abs(height_error - np.median(height_error))) < 1.0
    sidecar = json.loads((tmp_path / "bundle.npz.json").read_text())
    summary = sidecar["summary"]
    assert summary["registered_count"] == summary["image_count"] == 4
    assert summary["points"] == len(bundle["points"])
    assert summary["p95_reprojection_error_px"] >= summary["mean_reprojection_error_px"]
    assert (tmp_path / "colmap" / "points3D.bin").is_file()


@pytest.mark.slow
def test_bundle_with_known_intrinsics_keeps_them(small_scene_dir, tmp_path):
    """--cameras: the output cameras carry exactly the known K (fixed), all views
    registered; on this narrow field of view COLMAP needs the free-mapping fallback."""
    selection = scene_selection(small_scene_dir, tmp_path)
    out = tmp_path / "bundle.npz"
    cameras_file = small_scene_dir / "cameras.npz"
    result = CliRunner().invoke(cli, ["-q", "bundle", str(selection), "--out", str(out),
                                      "--cameras", str(cameras_file),
                                      "--align-cameras", str(cameras_file)])
    assert result.exit_code == 0, result.output
    bundle = dio.read_npz(out, "bundle")
    truth = cameras_from_arrays(dio.read_npz(cameras_file, "cameras"))
    cameras = cameras_from_arrays(bundle)
    assert sorted(cameras) == sorted(truth)
    for name, camera in cameras.items():
        np.testing.assert_allclose(camera.K, truth[name].K, atol=1e-9)
        assert np.linalg.norm(camera.center - truth[name].center) < 10.0
    np.testing.assert_array_equal(bundle["distortion"], 0.0)
    assert float(np.mean(bundle["reprojection_error"])) < 1.0
    summary = json.loads((tmp_path / "bundle.npz.json").read_text())["summary"]
    assert summary["intrinsics"]["mode"].startswith("known")


def test_bundle_needs_two_images(tmp_path, small_scene_dir):
    selection = write_selection(tmp_path / "sel.json",
                                [("view_00", small_scene_dir / "view_00.tif")])
    out = tmp_path / "bundle.npz"
    result = CliRunner().invoke(cli, ["bundle", str(selection), "--out", str(out)])
    assert result.exit_code == 1
    assert "at least 2 images" in result.output and "view_00" in result.output
    assert not out.exists()


def test_bundle_missing_files_and_bad_selection(tmp_path, small_scene_dir):
    out = tmp_path / "bundle.npz"
    runner = CliRunner()
    result = runner.invoke(cli, ["bundle", str(tmp_path / "nope.json"), "--out", str(out)])
    assert result.exit_code == 1 and "nope.json: selection file not found" in result.output
    selection = write_selection(tmp_path / "sel.json",
                                [("view_00", small_scene_dir / "view_00.tif"),
                                 ("gone", tmp_path / "gone.tif")])
    result = runner.invoke(cli, ["bundle", str(selection), "--out", str(out)])
    assert result.exit_code == 1 and "gone.tif: image named in" in result.output
    (tmp_path / "bad.json").write_text('{"something": 1}')
    result = runner.invoke(cli, ["bundle", str(tmp_path / "bad.json"), "--out", str(out)])
    assert result.exit_code == 1 and "not a selection file" in result.output
    selection = scene_selection(small_scene_dir, tmp_path)
    result = runner.invoke(cli, ["bundle", str(selection), "--out", str(out), "--align-cameras",
                                 str(selection)])
    assert result.exit_code == 1 and "not a readable NPZ" in result.output
    result = runner.invoke(cli, ["bundle", str(selection), "--out", str(out),
                                 "--focal-px", "100", "--cameras", "x.npz"])
    assert result.exit_code == 2
    assert not out.exists()


def test_bundle_fails_clearly_on_unrelated_images(tmp_path):
    rng = np.random.default_rng(5)
    images = []
    for name in ("noise_a", "noise_b", "noise_c"):
        path = tmp_path / f"{name}.tif"
        dio.write_raster(path, rng.normal(100, 20, (96, 96)))
        images.append((name, path))
    selection = write_selection(tmp_path / "sel.json", images)
    out = tmp_path / "bundle.npz"
    result = CliRunner().invoke(cli, ["bundle", str(selection), "--out", str(out)])
    assert result.exit_code == 1
    assert "reconstruction failed" in result.output and "of 3 images registered" in result.output
    assert not out.exists() and not (tmp_path / "bundle.npz.json").exists()


# --------------------------------------------------------------------------------------
# Real data: Apollo 15 Metric Camera frames (skipped when ../shared/data is absent)
# --------------------------------------------------------------------------------------


def plain_pycolmap(image_folder: Path, work: Path) -> tuple[int, int, float, float]:
    """COLMAP with its defaults (the issue's reference run): registered, points, error, s."""
    import pycolmap

    start = time.perf_counter()
    database = work / "plain.db"
    pycolmap.extract_features(database, image_folder)
    pycolmap.match_exhaustive(database)
    models = pycolmap.incremental_mapping(database, image_folder, work / "plain")
    best = max(models.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))
    return (best.num_reg_images(), best.num_points3D(), best.compute_mean_reprojection_error(),
            time.perf_counter() - start)


@pytest.mark.data
@pytest.mark.slow
def test_apollo15_at_least_as_good_as_plain_pycolmap(tmp_path):
    if not APOLLO.is_dir():
        pytest.skip("../shared/data/apollo15 is absent")
    frames = sorted(APOLLO.glob("AS15-M-*.png"))
    selection = write_selection(tmp_path / "sel.json", [(p.stem, p) for p in frames])
    out = tmp_path / "bundle.npz"
    core.set_colmap_verbosity(False)
    registered, points, error, _ = plain_pycolmap(APOLLO, tmp_path)
    result = CliRunner().invoke(cli, ["-q", "bundle", str(selection), "--out", str(out)])
    assert result.exit_code == 0, result.output
    summary = json.loads((tmp_path / "bundle.npz.json").read_text())["summary"]
    assert summary["registered_count"] == len(frames) == 4
    assert summary["registered_count"] >= registered
    assert summary["points"] >= min(points, 6224)
    assert summary["mean_reprojection_error_px"] <= max(error, 0.18) + 1e-9


def test_known_intrinsics_are_written_to_colmap(tmp_path):
    """--cameras intrinsics reach COLMAP with the +0.5 px principal-point shift."""
    camera = PinholeCamera(K=[[850.0, 0, 99.5], [0, 860.0, 74.5], [0, 0, 1]], R=np.eye(3),
                           t=np.zeros(3), width=200, height=150)
    text = core.colmap_camera_params("PINHOLE", camera.K)
    assert [float(v) for v in text.split(",")] == [850.0, 860.0, 100.0, 75.0]
    text = core.colmap_camera_params("RADIAL", camera.K)
    assert [float(v) for v in text.split(",")] == [855.0, 100.0, 75.0, 0.0, 0.0]
