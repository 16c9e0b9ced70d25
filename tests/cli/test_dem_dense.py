"""`demtool dem --points bundle.npz --dense DISPARITY RECTIFY`: the densified BAM DEM, its
report of measured and interpolated cells per source, and every bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.bundle import BundleResult
from demtool.cli import cli
from tests.cli.test_dem import bundle_points, write_bundle, write_pair
from tests.helpers.dem import BASELINE, nadir_camera, truth_grid


def run(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(cli, ["dem", *args])
    return result.exit_code, result.output


@pytest.fixture()
def block(tmp_path: Path) -> dict[str, Path]:
    """A metric bundle of 80 tie points (view_00 target, view_01) and the pair's files."""
    paths = write_pair(tmp_path)
    paths["bundle"] = write_bundle(tmp_path / "bundle.npz", bundle_points(80), nadir_camera(),
                                   aligned=True)
    return paths


def test_densified_dem_reports_both_sources(block, tmp_path):
    out, sparse = tmp_path / "dem.tif", tmp_path / "sparse.tif"
    code, output = run("--points", str(block["bundle"]), "--dense", str(block["disparity"]),
                       str(block["rectify"]), "--out", str(out), "--mask-band")
    assert code == 0, output
    code, output = run("--points", str(block["bundle"]), "--out", str(sparse))
    assert code == 0, output
    dem = dio.read_raster(out)
    assert dem.tags["dem_route"] == "points-metric-dense"
    assert dem.tags["frame"] == "image:view_00"
    summary = json.loads(Path(f"{out}.json").read_text())["summary"]
    cells = dem.data.size
    assert summary["measured_cells"] + summary["interpolated_cells"] == cells
    assert summary["measured_cells"] == (summary["cells_ties"] + summary["cells_dense_only"])
    assert summary["cells_dense_only"] > 0.7 * cells and summary["cells_ties"] < 80
    assert summary["dense_pairs"][0]["left"] == "view_00"
    assert summary["dense_pairs"][0]["median_ray_gap_px"] < 0.1
    sidecar = json.loads(Path(f"{out}.json").read_text())
    assert str(block["rectify"]) in json.dumps(sidecar)  # the pair's files are inputs
    truth = truth_grid(nadir_camera())
    inner = (slice(4, -4), slice(28, -4))  # where view_01 sees (not the 24 px strip)
    measured = dio.read_raster(out, band=2).data == 0
    assert measured[inner].all()
    assert np.abs(dem.data - truth)[inner].max() < 0.01
    sparse_dem = dio.read_raster(sparse).data
    assert (np.sqrt(np.mean((dem.data - truth)[4:-4, 4:-4] ** 2))
            <= np.sqrt(np.mean((sparse_dem - truth)[4:-4, 4:-4] ** 2)))


def test_dense_needs_points_usage_error(block, tmp_path):
    out = tmp_path / "dem.tif"
    code, output = run("--disparity", str(block["disparity"]), "--rectify",
                       str(block["rectify"]), "--cameras", str(block["cameras"]), "--dense",
                       str(block["disparity"]), str(block["rectify"]), "--out", str(out))
    assert code == 2 and "--dense" in output and "--points" in output
    assert not out.exists()


def _rectify_with(path: Path, source: Path, **changes) -> Path:
    arrays = dict(dio.read_npz(source, "rectification"))
    arrays.update(changes)
    dio.write_npz(path, "rectification", arrays)
    return path


def test_dense_bad_inputs_exit_1_without_output(block, tmp_path):
    out = tmp_path / "dem.tif"

    def refused(*args: str) -> str:
        code, output = run("--points", str(block["bundle"]), *args, "--out", str(out))
        assert code == 1, output
        assert output.startswith("Error:") and "Traceback" not in output
        assert not out.exists() and not Path(f"{out}.json").exists()
        return output

    disparity, rectify = str(block["disparity"]), str(block["rectify"])
    assert "input file not found" in refused("--dense", str(tmp_path / "none.tif"), rectify)
    # a pair of images this bundle did not register
    other_names = _rectify_with(tmp_path / "names.npz", block["rectify"],
                                right_name=np.asarray("view_07"))
    assert "no camera for view_07" in refused("--dense", disparity, str(other_names))
    # the bundle's camera and the rectification disagree on the image's size
    other_size = _rectify_with(tmp_path / "size.npz", block["rectify"],
                               size_right=np.array([128, 96]))
    assert "the right image is 128×96" in refused("--dense", disparity, str(other_size))
    # a rectification through sensor models (not homographies of the images)
    eye = np.eye(3)
    calibrated = _rectify_with(tmp_path / "calibrated.npz", block["rectify"],
                               calibrated=np.asarray(True), R_rect=eye, K_left_rect=eye,
                               K_right_rect=eye, pointing_correction=eye,
                               pointing_correction_mrad=np.zeros(3),
                               sensor_left_type=np.asarray("frame"),
                               sensor_right_type=np.asarray("frame"))
    assert "rectified with sensor models" in refused("--dense", disparity, str(calibrated))
    # the disparity is not on the rectification's canvas
    small = tmp_path / "small.tif"
    dio.write_raster(small, np.ones((10, 10), dtype=np.float32),
                     tags={"frame": "image:view_00_rect"})
    assert "rectified canvas" in refused("--dense", str(small), rectify)
    # the disparity of another pair (its frame names another left image)
    elsewhere = tmp_path / "elsewhere.tif"
    data = dio.read_raster(block["disparity"]).data
    dio.write_raster(elsewhere, data, tags={"frame": "image:view_05_rect"})
    assert "is it the rectification of this pair" in refused("--dense", str(elsewhere), rectify)
    # another block's bundle: view_01 is 30 px higher in the image of its camera
    camera = nadir_camera()
    shifted = write_bundle(tmp_path / "other_block.npz", bundle_points(80), camera,
                           aligned=True)
    arrays = dict(dio.read_npz(shifted, "bundle"))
    K = arrays["K"].copy()
    K[1, 1, 2] += 30.0
    arrays["K"] = K
    dio.write_npz(shifted, "bundle", arrays)
    code, output = run("--points", str(shifted), "--dense", disparity, rectify, "--out",
                       str(out))
    assert code == 1 and "miss each other" in output and not out.exists()
    # no overlap: the bundle's target view_02 sees another place than the pair
    far = tmp_path / "far.npz"
    points = bundle_points(80) + [5000.0, 0.0, 0.0]
    dio.write_npz(far, "bundle", BundleResult(
        points=points, colors=np.zeros(80), track_length=np.full(80, 2),
        reprojection_error=np.full(80, 0.2),
        image_names=np.array(["view_00", "view_01", "view_02"]),
        cameras=[camera, nadir_camera(BASELINE), nadir_camera(5000.0)],
        distortion=np.zeros((3, 2)), target_index=2, aligned=True).to_arrays())
    code, output = run("--points", str(far), "--dense", disparity, rectify, "--out", str(out))
    assert code == 1 and "no overlap with the target view_02" in output
    assert not out.exists()


@pytest.mark.slow
def test_chain_of_the_comet_case_densified_beats_sparse(small_scene_dir, tmp_path):
    """select → bundle (intrinsics given, not aligned: eq. 2) → rectify → sgm → dem, on the
    small synthetic scene: the densified DEM is measured almost everywhere and closer to
    the truth than the sparse BAM DEM (offsets removed: eq. 2 has its own datum)."""
    from demtool.imaging.robust import nmad

    scene = small_scene_dir
    runner = CliRunner()

    def demtool(*args: str) -> None:
        result = runner.invoke(cli, ["-q", *args])
        assert result.exit_code == 0, (args, result.output)

    views = sorted(str(p) for p in scene.glob("view_*.tif"))
    demtool("select", *views, "--target", str(scene / "view_00.tif"), "--cameras",
            str(scene / "cameras.npz"), "--scene", str(scene / "scene.json"), "--out",
            str(tmp_path / "selection.json"))
    demtool("bundle", str(tmp_path / "selection.json"), "--cameras",
            str(scene / "cameras.npz"), "--out", str(tmp_path / "bundle.npz"))
    stereo = tmp_path / "stereo"
    demtool("rectify", str(scene / "view_00.tif"), str(scene / "view_01.tif"), "--out",
            str(stereo))
    demtool("sgm", str(stereo / "left_rect.tif"), str(stereo / "right_rect.tif"), "--rectify",
            str(stereo / "rectify.npz"), "--out", str(stereo / "disparity.tif"))
    base = ["dem", "--points", str(tmp_path / "bundle.npz"), "--scene",
            str(scene / "scene.json")]
    demtool(*base, "--out", str(tmp_path / "sparse.tif"))
    demtool(*base, "--dense", str(stereo / "disparity.tif"), str(stereo / "rectify.npz"),
            "--out", str(tmp_path / "dense.tif"))
    truth = dio.read_raster(scene / "truth_dem_target.tif").data.astype(np.float64)
    scores = {}
    for name in ("sparse", "dense"):
        error = dio.read_raster(tmp_path / f"{name}.tif").data - truth
        error -= np.median(error)
        summary = json.loads((tmp_path / f"{name}.tif.json").read_text())["summary"]
        scores[name] = (float(np.sqrt(np.mean(error**2))), nmad(error),
                        summary["measured_fraction"])
    assert scores["sparse"][2] < 0.05 and scores["dense"][2] > 0.95
    # measured 2026-11: sparse 0.54 / 0.48 m, dense 0.39 / 0.38 m (RMSE / NMAD)
    assert scores["dense"][0] < scores["sparse"][0] and scores["dense"][1] < scores["sparse"][1]
    summary = json.loads((tmp_path / "dense.tif.json").read_text())["summary"]
    assert summary["route"] == "points-eq2-dense"
    assert abs(summary["tie_minus_dense_median_m"]) < 0.5 * summary["tie_minus_dense_nmad_m"]


def test_dense_refuses_a_pair_of_another_block_of_the_same_names(block, tmp_path):
    """Issue 46: the pair's images are identified by content (the SHA-256 the sidecars of
    rectify and bundle record), not by their names: another block's view_00/view_01 are
    refused, naming the rectification and the image; the block's own pass."""
    from demtool.provenance import Provenance

    def images(folder: str, seed: int) -> list[Path]:
        (tmp_path / folder).mkdir()
        paths = [tmp_path / folder / f"view_0{i}.tif" for i in range(2)]
        for i, path in enumerate(paths):
            dio.write_raster(path, np.random.default_rng(seed + i).random((8, 8)))
        return paths

    ours, theirs = images("ours", 0), images("theirs", 10)
    Provenance("bundle", {}, ours).write_sidecar(block["bundle"])
    Provenance("rectify", {}, theirs).write_sidecar(block["rectify"])
    out = tmp_path / "dem.tif"
    code, output = run("--points", str(block["bundle"]), "--dense", str(block["disparity"]),
                       str(block["rectify"]), "--out", str(out))
    lines = [line for line in output.splitlines() if line.startswith("Error")]
    assert code == 1 and len(lines) == 1, output
    assert f"{block['rectify']}: its image view_00" in lines[0]
    assert "another block" in lines[0] and not out.exists()
    Provenance("rectify", {}, ours).write_sidecar(block["rectify"])
    code, output = run("--points", str(block["bundle"]), "--dense", str(block["disparity"]),
                       str(block["rectify"]), "--out", str(out))
    assert code == 0, output
