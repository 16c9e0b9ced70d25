"""synth --sensor-model: synthetic terrain rendered through windows of two real models."""

import json

import numpy as np
import pytest

from demtool.errors import InputError
from demtool.sensors import read_sensor
from demtool.sensors.isd import isd_from_sensor, read_isd
from demtool.synth.real import window
from tests.helpers.linescan import isd_dict, linescan_sensor


def test_window_is_the_same_camera_shifted():
    from pathlib import Path

    frame = read_isd(Path(__file__).parents[1] / "sensors" / "data" / "orbitalFramer.json")
    line = linescan_sensor(lines=300, samples=200, roll_deg=10.0)
    for model, (l0, s0) in ((frame, (3, 5)), (line, (40, 17))):
        cut = window(model, l0, s0, 8, 9)
        assert cut.image_size == (8, 9)
        ll, ss = np.meshgrid(np.arange(8) + 0.5, np.arange(9) + 0.5, indexing="ij")
        a, b = cut.image_to_ray(ll, ss), model.image_to_ray(ll + l0, ss + s0)
        np.testing.assert_allclose(a.origin, b.origin, atol=1e-6)
        np.testing.assert_allclose(a.direction, b.direction, atol=1e-12)
        # and its ISD rebuilds the window
        from demtool.sensors.isd import sensor_from_isd

        again = sensor_from_isd(isd_from_sensor(cut))
        np.testing.assert_allclose(again.image_to_ground(ll, ss), cut.image_to_ground(ll, ss),
                                   atol=1e-3)


def _pair(tmp_path):
    paths = []
    for name, lon0 in (("left", 10.0), ("right", 10.003)):  # 91 m apart on the Moon
        sensor = linescan_sensor(lines=600, samples=400, gsd=1.0, lon0=lon0, name=name)
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(isd_dict(sensor)))
        paths.append(path)
    return paths


def test_synth_through_two_line_scan_models(tmp_path):
    from demtool.synth import SceneParams
    from demtool.synth.run import run_synth

    paths = _pair(tmp_path)
    out = tmp_path / "scene"
    scene = run_synth(out, SceneParams(image_size=64, crater_count=5, boulder_count=10),
                      sensor_models=tuple(paths))
    assert scene.names == ("view_00", "view_01")
    for name in scene.names:
        assert (out / f"{name}.tif").exists() and (out / f"{name}.json").exists()
        view = read_sensor(out / f"{name}.json")
        assert view.image_size == (64, 64)
    # The scene centre (the footprints' common centre) projects to both windows' centres.
    place = scene.placement
    for name in scene.names:
        line, sample = scene.sensors[name].ground_to_image(place.origin)
        assert abs(line - 32) <= 1.0 and abs(sample - 32) <= 1.0
    # DEM cells are half the finer window GSD (1 m / px here, ±5 % off nadir)
    assert scene.params.spacing_m == pytest.approx(0.5, rel=0.05)
    assert (out / "truth_dem_map.tif").exists()


def test_synth_refuses_models_it_cannot_window(tmp_path):
    from demtool.synth import SceneParams
    from demtool.synth.run import run_synth
    from tests.sensors.test_rpc import rpc_dict, write_rpc_txt

    rpc = write_rpc_txt(tmp_path / "scene_RPC.TXT", rpc_dict())
    left, _ = _pair(tmp_path)
    with pytest.raises(InputError, match=r"scene_RPC\.TXT: --sensor-model takes frame, "
                                         r"line-scan or push-frame models on a body, not a rpc"):
        run_synth(tmp_path / "o", SceneParams(image_size=64), sensor_models=(left, rpc))
    far = linescan_sensor(lines=600, samples=400, lon0=40.0, name="far")
    far_path = tmp_path / "far.json"
    far_path.write_text(json.dumps(isd_dict(far)))
    with pytest.raises(InputError, match=r"the two footprints do not overlap"):
        run_synth(tmp_path / "o", SceneParams(image_size=64), sensor_models=(left, far_path))
    with pytest.raises(InputError, match=r"left\.json: a 1000 px window .* leaves the 600 x 400"):
        run_synth(tmp_path / "o", SceneParams(image_size=1000), sensor_models=_pair(tmp_path))
    assert not (tmp_path / "o").exists()


def test_push_frame_window_and_isd():
    from pathlib import Path

    from demtool.sensors.isd import sensor_from_isd

    path = Path(__file__).parents[1] / "sensors" / "data" / "orbitalPushFrame.json"
    for reversed_order in (False, True):
        isd = json.loads(path.read_text())
        isd["framelet_order_reversed"] = reversed_order
        model = sensor_from_isd(isd, "pf.json")
        cut = window(model, 48, 3, 36, 10)  # framelets 4-6 of 30, samples 3-12
        ll, ss = np.meshgrid(np.arange(36) + 0.5, np.arange(10) + 0.5, indexing="ij")
        a, b = cut.image_to_ray(ll, ss), model.image_to_ray(ll + 48, ss + 3)
        np.testing.assert_allclose(a.origin, b.origin, atol=1e-6)
        np.testing.assert_allclose(a.direction, b.direction, atol=1e-12)
        again = sensor_from_isd(isd_from_sensor(cut), "cut.json")
        assert again.kind == "pushframe" and again.framelet_order_reversed == reversed_order
        np.testing.assert_allclose(again.image_to_ground(ll, ss), cut.image_to_ground(ll, ss),
                                   atol=1e-3)
    with pytest.raises(ValueError, match="whole framelets: line 5"):
        window(model, 5, 0, 12, 16)


def test_synth_refuses_one_model_twice(tmp_path):
    """Issue 46: one model given twice has no baseline (no parallax): refused, naming it."""
    from demtool.synth import SceneParams
    from demtool.synth.run import run_synth

    left, _ = _pair(tmp_path)
    with pytest.raises(InputError, match=r"left\.json: sees the overlap from where .*left\.json "
                                         r"does \(convergence 0°"):
        run_synth(tmp_path / "o", SceneParams(image_size=64), sensor_models=(left, left))
    assert not (tmp_path / "o").exists()


def test_windows_of_lines_by_samples_moved_inside_with_a_bounded_dem(tmp_path, monkeypatch):
    """Issue 47: --image-lines × --image-size windows; a full-width window is moved inside
    the image; a DEM that would pass MAX_DEM_SIZE gets coarser cells; the truth map's
    lattice shortcut marks the same cells as projecting every cell."""
    from demtool.synth import SceneParams, maptruth, real, render
    from demtool.synth.run import run_synth

    paths = _pair(tmp_path)  # 600 x 400 px, the two centres 91 m apart across track
    monkeypatch.setattr(real, "MAX_DEM_SIZE", 200)
    out = tmp_path / "scene"
    scene = run_synth(out, SceneParams(image_size=400, image_lines=96, crater_count=5,
                                       boulder_count=0), sensor_models=tuple(paths))
    for name in scene.names:
        assert read_sensor(out / f"{name}.json").image_size == (96, 400)
        # the common footprint's centre is off both middle columns: windows moved inside
        line, sample = scene.sensors[name].ground_to_image(scene.placement.origin)
        assert abs(line - 48) <= 1.0 and abs(sample - 200) > 10
    assert scene.params.dem_size <= 200
    assert scene.params.spacing_m > 0.6  # coarser than half the ~1 m GSD
    # rendering in blocks of rows gives the rows of the whole rendering
    field = render.height_field(scene.dem.astype(np.float64), scene.dem_transform)
    camera = scene.sensors["view_01"]
    whole = render.view_geometry(field, scene.albedo.astype(np.float64), camera,
                                 scene.sun_vector, placement=scene.placement)
    part = render.view_geometry(field, scene.albedo.astype(np.float64), camera,
                                scene.sun_vector, placement=scene.placement, rows=(40, 57))
    np.testing.assert_array_equal(part.depth, whole.depth[40:57])
    assert render.row_blocks(96, 400, pixels=4000) == [(0, 10), (10, 20), (20, 30), (30, 40),
                                                       (40, 50), (50, 60), (60, 70), (70, 80),
                                                       (80, 90), (90, 96)]
    models = [scene.sensors[n] for n in scene.names]
    exact = maptruth.truth_map(field, scene.placement, models, scene.gsd_m)
    monkeypatch.setattr(maptruth, "LATTICE_MIN_CELLS", 0)
    monkeypatch.setattr(maptruth, "BLOCK_CELLS", 5000)
    fast = maptruth.truth_map(field, scene.placement, models, scene.gsd_m)
    assert fast.grid == exact.grid
    np.testing.assert_array_equal(np.isnan(fast.heights), np.isnan(exact.heights))
    np.testing.assert_allclose(fast.heights, exact.heights, atol=1e-4)
