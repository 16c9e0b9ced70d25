"""Tests of image selection (demtool.select.core, demtool select)."""

from __future__ import annotations

import numpy as np
import pytest

from demtool.errors import ParameterError
from demtool.imaging import features
from demtool.select import core as selection
from demtool.sensors.pinhole import PinholeCamera, look_at


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


def test_view_geometry_through_body_fixed_sensor_models():
    """On a line-scan scene on the Moon the angles come from the models alone: the pair's
    convergence, the sun's incidence and azimuth of the scene, emission = the roll."""
    from demtool.synth import SceneParams, make_scene

    scene = make_scene(SceneParams(sensor="linescan", dem_size=128, n_views=2, image_size=64,
                                   gsd_m=1.0, crater_count=0, boulder_count=0,
                                   center_lon_deg=20.0, center_lat_deg=-40.0))
    target, partner = (scene.sensors[n] for n in scene.names)
    point = selection.surface_point(target, np.array([31.5, 31.5]))
    assert np.linalg.norm(point) == pytest.approx(scene.placement.radius, abs=1e-6)
    sun = scene.placement.sun_position(scene.sun_vector) - point
    geometry = selection.view_geometry(target, partner, point, sun / np.linalg.norm(sun))
    assert geometry.convergence_deg == pytest.approx(25.0, abs=0.1)
    assert geometry.incidence_deg == pytest.approx(scene.params.sun_incidence_deg, abs=0.01)
    assert geometry.sun_azimuth_deg == pytest.approx(scene.params.sun_azimuth_deg, abs=0.01)
    assert geometry.emission_deg == pytest.approx(12.5, abs=0.1)


def test_camera_from_tags_reads_the_sensor_model_beside_the_image(tmp_path):
    from click.testing import CliRunner

    from demtool import io
    from demtool.cli import cli
    from demtool.select.run import _camera_from_tags, _sun_from_tags

    out = tmp_path / "scene"
    result = CliRunner().invoke(cli, ["synth", "--out", str(out), "--sensor", "linescan",
                                      "--size", "128", "--image-size", "64", "--gsd", "1",
                                      "--craters", "0", "--boulders", "0"])
    assert result.exit_code == 0, result.output
    raster = io.read_image(out / "view_01.tif", what="image")
    model = _camera_from_tags(raster, out / "view_01.tif")
    assert model.kind == "linescan" and model.image_size == (64, 64)
    point = selection.surface_point(model, np.array([31.5, 31.5]))
    sun = _sun_from_tags(raster, None, model, point)
    # the sun is 60° from the local vertical (the default incidence)
    assert np.degrees(np.arccos(sun @ point / np.linalg.norm(point))) == pytest.approx(
        60.0, abs=0.01)
