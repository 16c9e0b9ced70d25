"""demtool.synth.folder.load_scene on sensor scenes (frame and line-scan ISDs beside the images)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from demtool.cli import cli
from demtool.errors import InputError
from demtool.synth import SceneParams, make_scene
from demtool.synth.folder import load_scene

ARGS = ["--size", "96", "--views", "3", "--image-size", "48", "--craters", "8",
        "--crater-max", "20", "--boulders", "20"]


@pytest.fixture(scope="module")
def linescan_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("ls") / "scene"
    result = CliRunner().invoke(cli, ["-q", "synth", "--out", str(out), "--sensor", "linescan",
                                      *ARGS])
    assert result.exit_code == 0, result.output
    assert not (out / "cameras.npz").exists()
    return out


def test_load_scene_reads_a_linescan_scene(linescan_dir):
    loaded = load_scene(linescan_dir)
    params = SceneParams(**json.loads((linescan_dir / "scene.json").read_text())["parameters"])
    truth = make_scene(params)
    assert loaded.sensor == "linescan" and loaded.cameras == {}
    assert loaded.names == truth.names == ("view_00", "view_01")
    assert loaded.placement == truth.placement
    for name in truth.names:
        model, ref = loaded.sensors[name], truth.sensors[name]
        assert model.kind == "linescan" and model.image_size == ref.image_size
        lines, samples = np.mgrid[0.5:48:7, 0.5:48:7]
        # The ISD round trip keeps the geometry: same ground points within a millimetre.
        np.testing.assert_allclose(model.image_to_ground(lines, samples),
                                   ref.image_to_ground(lines, samples), atol=1e-3, rtol=0)
        np.testing.assert_allclose(loaded.images[name], truth.images[name], atol=0)
        # Depths and shadows ray-cast again through the read sensors match the render's.
        np.testing.assert_allclose(loaded.depths[name], truth.depths[name], atol=1e-3)
        assert np.mean(loaded.shadows[name] != truth.shadows[name]) < 1e-3
    np.testing.assert_array_equal(loaded.truth_target, truth.truth_target)


def test_load_scene_without_geometry_skips_ray_casting(linescan_dir):
    loaded = load_scene(linescan_dir, with_geometry=False)
    assert loaded.depths == {} and loaded.shadows == {}
    assert set(loaded.sensors) == {"view_00", "view_01"}


def test_linescan_scene_missing_isd_is_named(linescan_dir, tmp_path):
    copy = tmp_path / "scene"
    shutil.copytree(linescan_dir, copy)
    (copy / "view_01.json").unlink()
    with pytest.raises(InputError, match=r"view_01\.json"):
        load_scene(copy, with_geometry=False)


def test_linescan_scene_without_sensor_models_says_so(linescan_dir, tmp_path):
    copy = tmp_path / "scene"
    shutil.copytree(linescan_dir, copy)
    description = json.loads((copy / "scene.json").read_text())
    del description["sensor_models"]
    (copy / "scene.json").write_text(json.dumps(description))
    with pytest.raises(InputError, match=r"scene\.json: a 'linescan' scene without "
                                         r"'sensor_models'"):
        load_scene(copy, with_geometry=False)


def test_load_scene_reads_a_frame_scene_with_its_isds(tmp_path):
    out = tmp_path / "scene"
    result = CliRunner().invoke(cli, ["-q", "synth", "--out", str(out), "--sensor", "frame",
                                      *ARGS])
    assert result.exit_code == 0, result.output
    loaded = load_scene(out, with_geometry=False)
    assert loaded.sensor == "frame" and set(loaded.sensors) == set(loaded.cameras)
    # The ISD frame camera and the local pinhole see the same pixel at the same place
    # (CSM puts the first pixel's centre at 0.5, the pinhole at 0).
    model = loaded.sensors[loaded.target]
    ground = model.image_to_ground(np.array([10.5, 30.5]), np.array([20.5, 5.5]))
    local = loaded.placement.to_local(ground)
    pixels = loaded.cameras[loaded.target].project(local)
    np.testing.assert_allclose(pixels, [[20.0, 10.0], [5.0, 30.0]], atol=1e-3)
