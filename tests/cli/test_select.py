"""Tests of image selection (demtool.select.core, demtool select)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from demtool.imaging import features
from tests.helpers.features import make_camera, make_terrain, render


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
    # candidates that cannot be read are named as such, not as a question of overlap
    text = tmp_path / "text.tif"
    text.write_text("not an image")
    unreadable = _invoke(tmp_path / "gone.tif", text, "--target", views[0], "--no-cache",
                         "--out", out)
    assert unreadable.exit_code == 1
    assert ("no candidate image could be read: " in unreadable.output
            and "gone.tif: image not found (and 1 more unreadable)" in unreadable.output)
    assert "--min-matches" not in unreadable.output
    mixed = _invoke(scene_files / "noise.tif", tmp_path / "gone.tif", "--target", views[0],
                    "--no-cache", "--out", out)
    assert mixed.exit_code == 1 and "best noise with" in mixed.output
    assert "1 unreadable, e.g. " in mixed.output and "gone.tif: image not found" in mixed.output
    assert not out.exists()
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
