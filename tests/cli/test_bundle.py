"""`demtool bundle`: pycolmap SfM, conventions, alignment, errors."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import bundle as core
from demtool import io as dio
from demtool.cli import cli
from demtool.sensors.pinhole import cameras_from_arrays

APOLLO = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "apollo15"


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


def scene_selection(scene_dir: Path, tmp_path: Path) -> Path:
    scene = json.loads((scene_dir / "scene.json").read_text())
    names = [scene["target"]] + [n for n in scene["names"] if n != scene["target"]]
    return write_selection(tmp_path / "selection.json",
                           [(n, scene_dir / f"{n}.tif") for n in names])


@pytest.mark.slow
def test_bundle_registers_synthetic_views_and_aligns(small_scene_dir, tmp_path):
    selection = scene_selection(small_scene_dir, tmp_path)
    out = tmp_path / "bundle.npz"
    cameras = str(small_scene_dir / "cameras.npz")  # NavCam-like: a calibrated camera
    result = CliRunner().invoke(cli, ["-q", "bundle", str(selection), "--out", str(out),
                                      "--cameras", cameras, "--align-cameras", cameras,
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
    # the Metric camera's calibration (76.054 mm; 5 um pixels x 22.63, the frames'
    # downsampling): a near-flat strip does not determine the focal length (issue 27)
    result = CliRunner().invoke(cli, ["-q", "bundle", str(selection), "--focal-mm", "76.054",
                                      "--pixel-mm", "0.11314", "--out", str(out)])
    assert result.exit_code == 0, result.output
    summary = json.loads((tmp_path / "bundle.npz.json").read_text())["summary"]
    assert summary["registered_count"] == len(frames) == 4
    assert summary["registered_count"] >= registered
    assert summary["points"] >= min(points, 6224)
    assert summary["mean_reprojection_error_px"] <= max(error, 0.18) + 1e-9


# --- sensor models as priors (issue 14 part 2) -------------------------------------------


def _sensor_args(images, isds):
    args = [str(p) for p in images]
    for isd in isds:
        args += ["--sensors", str(isd)]
    return args


@pytest.fixture(scope="module")
def frame_block(tmp_path_factory):
    from tests.bundle import frames

    folder = tmp_path_factory.mktemp("frame_block")
    return frames.write_block(folder)


@pytest.mark.slow
def test_bundle_with_sensor_priors_writes_adjusted_isds(frame_block, tmp_path):
    """Frame ISDs 50 m / 0.5 mrad off: the adjusted ISDs are closer to the truth, in the
    body-fixed frame, and read back by read_sensor."""
    from demtool.bundle.offsets import rotation_vector
    from demtool.sensors import read_sensor
    from tests.bundle import frames

    truth, images, isds = frame_block
    out, adjusted = tmp_path / "bundle.npz", tmp_path / "adjusted"
    errors = []
    result = CliRunner().invoke(cli, ["-q", "bundle", *_sensor_args(images, isds), "--out",
                                      str(out), "--adjusted-dir", str(adjusted),
                                      "--matcher", "spatial", "--position-sigma", "50",
                                      "--pointing-sigma", "0.5", "--max-features", "3000"])
    assert result.exit_code == 0, result.output
    summary = json.loads(out.with_suffix(".npz.json").read_text())["summary"]
    assert summary["registered_count"] == 6
    assert len(summary["pairs"]) == 15  # every footprint overlaps every other
    assert summary["mean_reprojection_error_px"] < 0.3
    for true in truth:
        row = summary["images"][true.name]
        assert row["observations"] > 300
        assert 20.0 < row["position_change_m"] < 80.0
        model = read_sensor(adjusted / f"{true.name}.json")
        position = np.linalg.norm(model.position - true.position)
        pointing = np.linalg.norm(rotation_vector(model.rotation @ true.rotation.T)) * 1e3
        errors.append((position, pointing))
    errors = np.array(errors)
    # 320 px, 2.3 mrad per pixel (measured: <= 5.0 m, <= 0.13 mrad)
    assert errors[:, 0].max() < 7.0, errors
    assert errors[:, 1].max() < 0.2, errors
    bundle = dio.read_npz(out, "bundle")
    assert bool(bundle["aligned"])
    points = bundle["points"]
    height = np.linalg.norm(points, axis=1) - frames.RADIUS - frames.relief(points)
    # tie points on the terrain (±400 m hills; 68 m pixels, base to height 0.2)
    assert np.median(np.abs(height)) < 40.0


def test_bundle_sensor_count_must_match_images(frame_block, tmp_path):
    _, images, isds = frame_block
    out = tmp_path / "bundle.npz"
    result = CliRunner().invoke(cli, ["bundle", *_sensor_args(images[:3], isds[:2]),
                                      "--out", str(out), "--adjusted-dir",
                                      str(tmp_path / "adj")])
    assert result.exit_code == 1
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and "--sensors: 2 sensor model(s) for 3 images" in lines[0]
    assert not out.exists() and not (tmp_path / "adj").exists()


def test_bundle_sensor_model_of_wrong_size(frame_block, tmp_path):
    from tests.bundle import frames

    _, images, isds = frame_block
    wrong = tmp_path / "wrong.json"
    frames.write_isd(frames.true_models(size=500)[1], wrong)
    out = tmp_path / "bundle.npz"
    result = CliRunner().invoke(cli, ["bundle", *_sensor_args(images[:2], [isds[0], wrong]),
                                      "--out", str(out), "--adjusted-dir",
                                      str(tmp_path / "adj")])
    assert result.exit_code == 1
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and str(wrong) in lines[0] and "500x500" in lines[0]
    assert not out.exists() and not (tmp_path / "adj").exists()


def test_bundle_spatial_needs_sensors_and_overlap(frame_block, tmp_path):
    from tests.bundle import frames

    _, images, isds = frame_block
    out = tmp_path / "bundle.npz"
    result = CliRunner().invoke(cli, ["bundle", *map(str, images[:2]), "--out", str(out),
                                      "--matcher", "spatial"])
    assert result.exit_code == 1 and "--matcher spatial needs sensor models" in result.output
    far = frames.true_models(size=320)[0]
    far.position = far.position + np.array([0.0, 0.0, 200_000.0])
    far.name = "frame_01"  # given for image frame_01 (models are matched by name)
    moved = tmp_path / "far.json"
    frames.write_isd(far, moved)
    result = CliRunner().invoke(cli, ["bundle", *_sensor_args(images[:2], [isds[0], moved]),
                                      "--out", str(out), "--matcher", "spatial"])
    assert result.exit_code == 1
    assert len(result.output.strip().splitlines()) == 1
    assert "no two images overlap" in result.output
    assert not out.exists()


@pytest.mark.slow
def test_bundle_with_tsai_priors_writes_adjusted_tsai(frame_block, tmp_path):
    """.tsai priors (no image size, no body in the file) on three of the frames: the
    adjusted .tsai files are closer to the truth and keep their other lines."""
    from demtool.bundle.offsets import rotation_vector
    from demtool.sensors import read_tsai
    from tests.bundle import frames

    truth, images, _ = frame_block
    prior = frames.perturbed(truth)
    tsais = []
    for model in prior[:3]:
        path = tmp_path / f"{model.name}.tsai"
        frames.write_tsai(model, path)
        tsais.append(path)
    true_tsai = tmp_path / "true.tsai"
    frames.write_tsai(truth[0], true_tsai)
    line, sample = read_tsai(true_tsai, radii=(frames.RADIUS,) * 2).ground_to_image(
        truth[0].image_to_ground(100.5, 50.5))
    assert abs(line - 100.5) < 1e-6 and abs(sample - 50.5) < 1e-6  # the same camera
    out, adjusted = tmp_path / "bundle.npz", tmp_path / "adjusted"
    result = CliRunner().invoke(cli, ["-q", "bundle", *_sensor_args(images[:3], tsais),
                                      "--out", str(out), "--adjusted-dir", str(adjusted),
                                      "--position-sigma", "50", "--pointing-sigma", "0.5",
                                      "--max-features", "3000"])
    assert result.exit_code == 0, result.output
    for true, before in zip(truth[:3], prior[:3], strict=True):
        path = adjusted / f"{true.name}.tsai"
        assert "pitch = " in path.read_text()
        model = read_tsai(path)
        position = np.linalg.norm(model.center - true.position)
        pointing = np.linalg.norm(rotation_vector(model.R.T @ true.rotation.T)) * 1e3
        assert position < 0.5 * np.linalg.norm(before.position - true.position), position
        assert pointing < 0.25, pointing


def test_bundle_sensor_options_that_do_not_apply(frame_block, tmp_path):
    _, images, isds = frame_block
    out = tmp_path / "bundle.npz"
    for extra, option in ((["--focal-px", "500"], "--focal-px"),
                          (["--colmap-dir", str(tmp_path / "colmap")], "--colmap-dir")):
        result = CliRunner().invoke(cli, ["bundle", *_sensor_args(images[:2], isds[:2]),
                                          "--out", str(out), *extra])
        assert result.exit_code == 1
        assert len(result.output.strip().splitlines()) == 1
        assert f"{option} does not apply with sensor models" in result.output
    result = CliRunner().invoke(cli, ["bundle", *map(str, images[:2]), "--out", str(out),
                                      "--adjusted-dir", str(tmp_path / "adj")])
    assert result.exit_code == 1 and "--adjusted-dir needs sensor models" in result.output
    assert not out.exists() and not (tmp_path / "adj").exists()


def _bundle_refused(args, tmp_path, *parts):
    """Issue 31, class 5: one Error line naming the file, exit 1, nothing written."""
    out = tmp_path / "bundle.npz"
    result = CliRunner().invoke(cli, ["-q", "bundle", *args, "--out", str(out),
                                      "--adjusted-dir", str(tmp_path / "adj")])
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert result.exit_code == 1, result.output
    assert len(errors) == 1 and "Traceback" not in result.output, result.output
    for part in parts:
        assert part in errors[0], errors[0]
    assert not out.exists() and not (tmp_path / "adj").exists()


def test_bundle_models_in_another_order_than_the_images(frame_block, tmp_path):
    _, images, isds = frame_block
    _bundle_refused(_sensor_args(images[:3], [isds[1], isds[0], isds[2]]), tmp_path,
                    f"{isds[1]}: is the model of image frame_01", "given for image frame_00")


def test_bundle_model_of_another_body_in_the_block(frame_block, tmp_path):
    _, images, isds = frame_block
    mars = tmp_path / "frame_01.json"
    isd = json.loads(isds[1].read_text())
    scale = 3396190.0 / (isd["radii"]["semimajor"] * 1000.0)
    isd["radii"] = {"semimajor": 3396.19, "semiminor": 3376.2, "unit": "km"}
    block = isd["instrument_position"]
    block["positions"] = (np.asarray(block["positions"]) * scale).tolist()  # above Mars
    mars.write_text(json.dumps(isd))
    _bundle_refused(_sensor_args(images[:2], [isds[0], mars]), tmp_path,
                    f"{mars}: a model of a body of radius 3396.19 km", "one body")


def test_bundle_cameras_far_beyond_the_body(frame_block, tmp_path):
    _, images, isds = frame_block
    far = []
    for k in range(2):
        isd = json.loads(isds[k].read_text())
        block = isd["instrument_position"]  # metres written where km are read: 1000 x
        block["positions"] = (np.asarray(block["positions"]) * 1000.0).tolist()
        path = tmp_path / f"frame_{k:02d}.json"
        path.write_text(json.dumps(isd))
        far.append(path)
    # 1000 x farther along the same pointing the Moon is still in view, a dot smaller
    # than the ray grid's spacing (the model reads); the block refuses the distance
    _bundle_refused(_sensor_args(images[:2], far), tmp_path, f"{far[0]}: the camera is",
                    "radii (radius 1737.4 km): positions in metres labelled km?")


def test_block_refuses_a_camera_a_thousand_radii_out(tmp_path):
    """A nadir camera 1000 lunar radii out still sees the Moon; the block refuses it."""
    from demtool.bundle.block_checks import check_camera_distances
    from demtool.errors import InputError
    from demtool.sensors import read_sensor
    from tests.helpers.camera_isd import MOON_RADIUS, nadir_isd, write_isd

    camera = dict(focal_mm=50.0, pitch_mm=0.01, lines=64, samples=64)
    near = read_sensor(write_isd(tmp_path / "near.json",
                                 nadir_isd(10.0, 5.0, 50e3, **camera)))
    far_path = write_isd(tmp_path / "far.json",
                         nadir_isd(10.0, 5.0, 1000 * MOON_RADIUS, **camera))
    far = read_sensor(far_path)
    check_camera_distances([near], ["near.json"])
    with pytest.raises(InputError, match=r"far\.json: the camera is .* 1001 radii .*metres "
                                         "labelled km"):
        check_camera_distances([near, far], ["near.json", far_path])


def test_bundle_reference_dem_of_1e27(frame_block, tmp_path):
    from demtool.maps import body_by_name, grid_from_lonlat, xyz_to_lonlat_height
    from demtool.sensors import read_sensor

    _, images, isds = frame_block
    model = read_sensor(isds[0])
    centre = model.image_to_ground(0.5 * model.lines, 0.5 * model.samples)
    lon, lat, _ = xyz_to_lonlat_height(centre, radii=model.radii[0])
    moon = body_by_name("Moon")
    grid = grid_from_lonlat(moon, np.array([lon - 2, lon + 2]), np.array([lat - 2, lat + 2]),
                            2000.0)
    dem = tmp_path / "ref.tif"
    dio.write_raster(dem, np.full((grid.height, grid.width), 1e27), transform=grid.transform,
                     crs=grid.crs)
    _bundle_refused([*_sensor_args(images[:2], isds[:2]), "--reference-dem", str(dem)],
                    tmp_path, f"{dem}: DEM heights reach 1e+27 m")
