"""Tests of image selection (demtool.selection, demtool select)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner
from features_helpers import make_camera, make_terrain, render

from demtool import features, selection
from demtool import io as dio
from demtool.camera import PinholeCamera, look_at
from demtool.cli import cli
from demtool.errors import ParameterError


@pytest.fixture(scope="module")
def scene_files(small_scene_dir, tmp_path_factory):
    """The small scene's views plus a pure-noise image and a view of another terrain."""
    folder = tmp_path_factory.mktemp("select")
    for path in sorted(small_scene_dir.glob("view_*.tif")):
        shutil.copy(path, folder / path.name)
    shutil.copy(small_scene_dir / "cameras.npz", folder / "cameras.npz")
    shutil.copy(small_scene_dir / "scene.json", folder / "scene.json")
    rng = np.random.default_rng(7)
    dio.write_raster(folder / "noise.tif", rng.normal(1500, 200, (192, 192)).astype(np.float32))
    elsewhere = render(make_terrain(n=384, seed=11), make_camera((0, 0, 400), size=192,
                                                                 focal_px=400), seed=3)
    dio.write_raster(folder / "elsewhere.tif", elsewhere)
    return folder


def _views(folder):
    return sorted(str(p) for p in folder.glob("view_*.tif"))


def _invoke(*args):
    return CliRunner().invoke(cli, ["select", *map(str, args)])


def test_select_keeps_overlapping_views_and_rejects_noise_and_elsewhere(scene_files, tmp_path):
    out = tmp_path / "selection.json"
    images = [*_views(scene_files), scene_files / "noise.tif", scene_files / "elsewhere.tif"]
    run = _invoke(*images, "--target", scene_files / "view_00.tif", "--cameras",
                  scene_files / "cameras.npz", "--scene", scene_files / "scene.json",
                  "--rank", "--workers", "2", "--out", out)
    assert run.exit_code == 0, run.output
    result = json.loads(out.read_text())
    assert result["target"]["name"] == "view_00" and result["roi"] is None
    names = [entry["name"] for entry in result["selected"]]
    assert names[0] == "view_00" and result["selected"][0]["role"] == "target"
    assert sorted(names[1:]) == ["view_01", "view_02", "view_03"]
    rejected = {entry["name"]: entry for entry in result["rejected"]}
    assert set(rejected) == {"noise", "elsewhere"}
    for entry in rejected.values():
        assert "matches" in entry["reason"] and entry["matches"] < 50
    scene = json.loads((scene_files / "scene.json").read_text())
    truth = {view["name"]: view for view in scene["views"]}
    for entry in result["selected"][1:]:
        assert entry["matches"] >= 50 and entry["inliers"] >= 25
        assert entry["inliers"] <= entry["matches"]
        assert entry["overlap"] > 0.8
        assert entry["convergence_deg"] == pytest.approx(truth[entry["name"]]["convergence_deg"],
                                                         abs=0.5)
        assert entry["incidence_deg"] == pytest.approx(truth[entry["name"]]["incidence_deg"],
                                                       abs=0.5)
        assert entry["phase_deg"] == pytest.approx(truth[entry["name"]]["phase_deg"], abs=0.5)
    scores = [entry["score"] for entry in result["selected"][1:]]
    assert scores == sorted(scores, reverse=True)
    assert [entry["rank"] for entry in result["selected"][1:]] == [1, 2, 3]
    assert "view_01" in run.output and "rejected: only" in run.output  # the logged table
    sidecar = json.loads((tmp_path / "selection.json.json").read_text())
    assert sidecar["summary"]["selected"] == 3 and sidecar["summary"]["rejected"] == 2


def test_feature_cache_hits_on_second_run(scene_files, tmp_path):
    images = _views(scene_files)
    cache = tmp_path / "cache"
    first_out, second_out = tmp_path / "a.json", tmp_path / "b.json"
    args = ["--target", scene_files / "view_00.tif", "--cache-dir", cache]
    assert _invoke(*images, *args, "--out", first_out).exit_code == 0
    first = json.loads((tmp_path / "a.json.json").read_text())["summary"]
    assert first["cache_misses"] == 4 and first["cache_hits"] == 0
    assert len(list(cache.glob("*.npz"))) == 4
    assert _invoke(*images, *args, "--out", second_out).exit_code == 0
    second = json.loads((tmp_path / "b.json.json").read_text())["summary"]
    assert second["cache_hits"] == 4 and second["cache_misses"] == 0
    a, b = json.loads(first_out.read_text()), json.loads(second_out.read_text())
    assert a["selected"] == b["selected"]
    # other parameters → other cache entries
    assert _invoke(*images, *args, "--contrast-threshold", "0.03",
                   "--out", tmp_path / "c.json").exit_code == 0
    third = json.loads((tmp_path / "c.json.json").read_text())["summary"]
    assert third["cache_misses"] == 4
    # the default cache lives beside the output
    assert _invoke(*images, "--target", scene_files / "view_00.tif",
                   "--out", tmp_path / "d" / "sel.json").exit_code == 0
    assert len(list((tmp_path / "d" / ".demtool-features").glob("*.npz"))) == 4


def test_roi_crops_the_target(scene_files, tmp_path):
    out = tmp_path / "selection.json"
    run = _invoke(*_views(scene_files), "--target", scene_files / "view_00.tif",
                  "--roi", 40, 50, 140, 150, "--min-matches", "30", "--min-inliers", "20",
                  "--no-cache", "--out", out)
    assert run.exit_code == 0, run.output
    result = json.loads(out.read_text())
    assert result["roi"] == [40, 50, 140, 150]
    full = features.detect_sift(dio.read_image(scene_files / "view_00.tif").data)
    assert result["selected"][0]["keypoints"] < 0.5 * len(full)
    assert len(result["selected"]) == 4
    for entry in result["selected"][1:]:
        assert 0.8 < entry["overlap"] <= 1.0 and entry["inlier_coverage"] <= 1.0


def test_check_roi():
    assert selection.check_roi(None, (100, 200)).as_list() == [0, 0, 200, 100]
    roi = selection.check_roi([10, 20, 30, 60], (100, 200))
    assert roi.area == 800 and roi.centre.tolist() == [19.5, 39.5]
    with pytest.raises(ParameterError, match="outside the target image .200 x 100"):
        selection.check_roi([150, 20, 250, 60], (100, 200))
    with pytest.raises(ParameterError, match="empty"):
        selection.check_roi([30, 20, 10, 60], (100, 200))


def test_false_matches_are_rejected_by_the_epipolar_test():
    """Descriptors that match but sit at random places: many matches, no geometry."""
    rng = np.random.default_rng(2)
    count = 300
    descriptors = rng.uniform(0, 100, (count, 128)).astype(np.float32)
    zeros = np.zeros(count, np.float32)
    target = features.Features(rng.uniform(0, 200, (count, 2)).astype(np.float32), descriptors,
                               zeros, zeros, zeros)
    shuffled = features.Features(rng.uniform(0, 200, (count, 2)).astype(np.float32),
                                 descriptors + 0.1, zeros, zeros, zeros)
    roi = selection.Roi(0, 0, 200, 200)
    result = selection.compare_with_target(target, shuffled, roi=roi, candidate_size=(200, 200))
    assert result.matches == count and not result.accepted
    assert "epipolar" in result.reason
    same = selection.compare_with_target(target, target, roi=roi, candidate_size=(200, 200))
    assert not same.accepted and "identical" in same.reason


def test_view_geometry_of_a_known_configuration():
    target = look_at((0, 0, 1000), (0, 0, 0), focal_px=1000, width=100, height=100)
    other = look_at((300, 0, 1000), (0, 0, 0), focal_px=1000, width=100, height=100)
    point = selection.surface_point(target, np.array([49.5, 49.5]))
    np.testing.assert_allclose(point, [0, 0, 0], atol=1e-9)
    sun = np.array([-np.sin(np.radians(60)) * np.sqrt(0.5), -np.sin(np.radians(60)) * np.sqrt(0.5),
                    np.cos(np.radians(60))])
    geometry = selection.view_geometry(target, other, point, sun)
    assert geometry.convergence_deg == pytest.approx(np.degrees(np.arctan(0.3)))
    assert geometry.emission_deg == pytest.approx(np.degrees(np.arctan(0.3)))
    assert geometry.incidence_deg == pytest.approx(60.0)
    assert geometry.sun_azimuth_deg == pytest.approx(225.0)
    assert geometry.base_to_height == pytest.approx(0.3)
    to_camera = np.array([300.0, 0, 1000]) / np.hypot(300, 1000)
    assert geometry.phase_deg == pytest.approx(np.degrees(np.arccos(sun @ to_camera)))
    flipped = PinholeCamera(K=target.K, R=np.diag([1.0, -1.0, -1.0]) @ target.R, t=[0, 0, -1000],
                            width=100, height=100)
    with pytest.raises(Exception, match="does not reach"):
        selection.surface_point(flipped, np.array([49.5, 49.5]))


def test_rank_score_prefers_the_stereo_sweet_spot_and_sun_diversity():
    match = selection.CandidateMatch(keypoints=500, matches=300, inliers=250, overlap=0.9,
                                     inlier_coverage=0.8, accepted=True)

    def geometry(convergence, azimuth):
        return selection.ViewGeometry(60.0, convergence, 70.0, convergence, 300.0, 0.3, azimuth)

    def score(g):
        return selection.rank_score(match, g, min_matches=50, target_sun_azimuth_deg=225.0)[0]

    assert score(geometry(25, 225)) > score(geometry(5, 225)) > score(geometry(60, 225)) * 0.99
    assert score(geometry(25, 45)) > score(geometry(25, 225))
    plain, terms = selection.rank_score(match, None, min_matches=50)
    assert set(terms) == {"inliers", "overlap"} and 0 < plain <= 1


def test_target_given_separately_is_not_matched_with_itself(scene_files, tmp_path):
    out = tmp_path / "selection.json"
    others = [p for p in _views(scene_files) if not p.endswith("view_00.tif")]
    run = _invoke(*others, "--target", scene_files / "view_00.tif", "--no-cache", "--out", out)
    assert run.exit_code == 0, run.output
    result = json.loads(out.read_text())
    assert [e["name"] for e in result["selected"]][0] == "view_00"
    assert len(result["selected"]) == 4 and not result["rejected"]


def test_bad_inputs(scene_files, tmp_path):
    views = _views(scene_files)
    out = tmp_path / "selection.json"
    missing = _invoke(*views, "--target", tmp_path / "nope.tif", "--out", out)
    assert missing.exit_code == 1 and "nope.tif" in missing.output
    assert "not found" in missing.output
    empty = tmp_path / "empty.tif"
    dio.write_raster(empty, np.full((32, 32), np.nan, np.float32))
    nan_target = _invoke(*views, "--target", empty, "--out", out)
    assert nan_target.exit_code == 1 and "no valid" in nan_target.output
    outside = _invoke(*views, "--target", views[0], "--roi", 0, 0, 500, 100, "--out", out)
    assert outside.exit_code == 1 and "outside the target" in outside.output
    none_pass = _invoke(scene_files / "noise.tif", scene_files / "elsewhere.tif",
                        "--target", views[0], "--no-cache", "--out", out)
    assert none_pass.exit_code == 1 and "no image passes" in none_pass.output
    only_target = _invoke(views[0], "--target", views[0], "--out", out)
    assert only_target.exit_code == 1 and "no candidate" in only_target.output
    cameras = tmp_path / "cameras.npz"
    arrays = dio.read_npz(scene_files / "cameras.npz", "cameras")
    keep = arrays["names"] != "view_00"
    dio.write_npz(cameras, "cameras", {k: arrays[k][keep] for k in
                                       ("names", "K", "R", "t", "width", "height")})
    no_camera = _invoke(*views, "--target", views[0], "--cameras", cameras, "--out", out)
    assert no_camera.exit_code == 1 and "no camera for the target" in no_camera.output
    twin = tmp_path / "twin"
    twin.mkdir()
    shutil.copy(views[1], twin / "view_01.tif")
    duplicate = _invoke(*views, twin / "view_01.tif", "--target", views[0], "--out", out)
    assert duplicate.exit_code == 1 and "share the name" in duplicate.output
    unreadable = tmp_path / "broken.tif"
    unreadable.write_bytes(b"not a tiff")
    tolerated = _invoke(*views, unreadable, "--target", views[0], "--no-cache",
                        "--out", tmp_path / "ok.json")
    assert tolerated.exit_code == 0, tolerated.output
    result = json.loads((tmp_path / "ok.json").read_text())
    assert [e["name"] for e in result["rejected"]] == ["broken"]
    assert "unreadable" in result["rejected"][0]["reason"]
    assert not out.exists() and not (tmp_path / "selection.json.json").exists()
