"""Synthetic views through sensor models (demtool.synth.sensors, render, maptruth)."""

from __future__ import annotations

import numpy as np
import pytest

from demtool.errors import ParameterError
from demtool.maps import lonlat_height_to_xyz, map_to_lonlat
from demtool.sensors import sensor_from_isd
from demtool.sensors.isd import isd_from_sensor
from demtool.synth import SceneParams, make_scene, render
from demtool.synth.body import local_heights
from demtool.synth.maptruth import truth_map
from demtool.synth.sensors import convergence_deg

SMALL = dict(dem_size=128, n_views=3, image_size=64, gsd_m=1.0, crater_count=6,
             crater_max_diameter_m=20.0, boulder_count=10)


@pytest.fixture(scope="module")
def pinhole_scene():
    return make_scene(SceneParams(**SMALL))


@pytest.fixture(scope="module")
def frame_scene():
    return make_scene(SceneParams(sensor="frame", center_lon_deg=40.0, center_lat_deg=-30.0,
                                  **SMALL))


@pytest.fixture(scope="module")
def linescan_scene():
    return make_scene(SceneParams(sensor="linescan", **SMALL))


def field_of(scene):
    return render.height_field(scene.dem.astype(np.float64), scene.dem_transform)


def test_interface_rendering_equals_the_old_pinhole_renderer(pinhole_scene):
    """The old renderer's rays, R.T @ inv(K) @ (c, r, 1) from the camera centre, cast
    onto the same terrain hit where the interface's rays hit."""
    scene = pinhole_scene
    field = field_of(scene)
    for camera in scene.cameras.values():
        rows, cols = np.mgrid[0:camera.height, 0:camera.width]
        pixels = np.stack([cols.ravel(), rows.ravel(), np.ones(rows.size)], axis=1)
        old_rays = pixels @ (camera.R.T @ np.linalg.inv(camera.K)).T
        old_hits = render.intersect_rays(field, np.broadcast_to(camera.center, old_rays.shape),
                                         old_rays)
        geometry = render.view_geometry(field, scene.albedo.astype(np.float64), camera,
                                        scene.sun_vector)
        np.testing.assert_allclose(geometry.hit.reshape(-1, 3), old_hits, atol=1e-8)
        # depth stays the camera z of the hit
        np.testing.assert_allclose(geometry.depth.ravel(), camera.depth(old_hits), atol=1e-8)


def test_frame_scene_renders_the_pinhole_views(pinhole_scene, frame_scene):
    """A frame scene's sensors are the pinholes placed on the body: same hits, same DN."""
    for name in pinhole_scene.names:
        a, b = pinhole_scene.images[name], frame_scene.images[name]
        assert np.mean(a == b) > 0.999
    field = field_of(frame_scene)
    sensor = frame_scene.sensors[frame_scene.partner]
    camera = frame_scene.cameras[frame_scene.partner]
    pixels = np.array([[0.0, 0.0], [31.5, 12.25], [63.0, 63.0]])
    local = render.pixel_hits(field, camera, pixels)
    placed = render.pixel_hits(field, sensor, pixels, placement=frame_scene.placement)
    np.testing.assert_allclose(placed, local, atol=1e-6)
    # depths stay the camera z of the pinholes
    np.testing.assert_allclose(frame_scene.depths[frame_scene.partner],
                               pinhole_scene.depths[pinhole_scene.partner], atol=1e-5)


@pytest.mark.parametrize("fixture", ["frame_scene", "linescan_scene"])
def test_isds_round_trip_and_hits_project_to_their_pixels(request, fixture):
    """Each rendered pixel's hit, taken to the body, projects through the ISD read back
    onto that pixel (< 0.01 px); the read-back model equals the rendered one."""
    scene = request.getfixturevalue(fixture)
    field = field_of(scene)
    for name in (scene.target, scene.partner):
        model = scene.sensors[name]
        again = sensor_from_isd(isd_from_sensor(model))
        geometry = render.view_geometry(field, scene.albedo.astype(np.float64), model,
                                        scene.sun_vector, placement=scene.placement)
        rows, cols = np.mgrid[0:model.lines:5, 0:model.samples:5]
        ground = scene.placement.to_body(geometry.hit[rows, cols])
        line, sample = again.ground_to_image(ground)
        error = np.hypot(line - (rows + 0.5), sample - (cols + 0.5))
        assert np.max(error) < 0.01
        l1, s1 = model.ground_to_image(ground)
        assert np.max(np.hypot(l1 - line, s1 - sample)) < 1e-6


@pytest.mark.parametrize("fixture", ["frame_scene", "linescan_scene"])
def test_isd_sun_is_the_scene_sun(request, fixture):
    scene = request.getfixturevalue(fixture)
    model = sensor_from_isd(isd_from_sensor(scene.sensors[scene.target]))
    sun = model.sun_position(np.array(0.5 * model.lines)) - scene.placement.origin
    local = scene.placement.directions_to_local(sun / np.linalg.norm(sun))
    np.testing.assert_allclose(local, scene.sun_vector, atol=1e-12)


@pytest.mark.parametrize("fixture", ["frame_scene", "linescan_scene"])
def test_truth_map_agrees_with_the_local_truth(request, fixture):
    scene = request.getfixturevalue(fixture)
    field = field_of(scene)
    pair = [scene.sensors[scene.target], scene.sensors[scene.partner]]
    truth = truth_map(field, scene.placement, pair, scene.gsd_m)
    assert truth.grid.gsd == pytest.approx((scene.gsd_m, scene.gsd_m))
    assert "Moon" in truth.grid.crs.name
    valid = np.isfinite(truth.heights)
    assert valid.mean() > 0.9
    x, y = truth.grid.cell_centers()
    lon, lat = map_to_lonlat(truth.grid.crs, x, y)
    xyz = lonlat_height_to_xyz(lon[valid], lat[valid], truth.heights[valid].astype(np.float64),
                               radii=scene.placement.radius)
    local = scene.placement.to_local(xyz)
    # the map's points lie on the local terrain (< 1 mm), ...
    np.testing.assert_allclose(local[:, 2], local_heights(field, local[:, 0], local[:, 1]),
                               atol=1e-3)
    # ... heights above the sphere include the tangent plane's rise d²/2R
    d2 = local[:, 0] ** 2 + local[:, 1] ** 2
    rise = truth.heights[valid] - local[:, 2]
    np.testing.assert_allclose(rise, d2 / (2 * scene.placement.radius), atol=1e-4)
    # every valid cell is seen by both images
    for model in pair:
        line, sample = model.ground_to_image(xyz)
        assert np.all((line >= 0) & (line <= model.lines) & (sample >= 0)
                      & (sample <= model.samples))


def test_linescan_pair_geometry(linescan_scene):
    scene = linescan_scene
    first, second = (scene.sensors[n] for n in scene.names)
    assert len(scene.names) == 2 and first.kind == second.kind == "linescan"
    assert 20.0 <= convergence_deg(first, second, scene.placement) <= 30.0
    for model in (first, second):
        # ground speed of the sub-spacecraft point on the sphere, 1.0–1.7 km/s
        t = model.line_time(np.array([0.5, model.lines - 0.5]))
        p = model.position_at(t)
        angle = np.arccos(p[0] @ p[1] / np.linalg.norm(p, axis=1).prod())
        speed = angle * scene.placement.radius / (t[1] - t[0])
        assert 1000.0 <= speed <= 1700.0
        # pixels about square on the ground at the centre
        c = 0.5 * model.lines
        pts = model.image_to_ground(np.array([c, c + 1, c]), np.array([c, c, c + 1]))
        along, across = np.linalg.norm(pts[1] - pts[0]), np.linalg.norm(pts[2] - pts[0])
        assert along == pytest.approx(scene.gsd_m, rel=0.03)
        assert across == pytest.approx(scene.gsd_m, rel=0.03)
        assert not np.isnan(scene.images[model.name]).any()


def test_linescan_views_overlap(linescan_scene):
    scene = linescan_scene
    pair = [scene.sensors[n] for n in scene.names]
    truth = truth_map(field_of(scene), scene.placement, pair, scene.gsd_m)
    # the common footprint covers most of one image's ground area
    area = np.isfinite(truth.heights).sum() * scene.gsd_m ** 2
    assert area > 0.8 * (scene.params.image_size * scene.gsd_m) ** 2


def test_linescan_beyond_the_dem_is_refused():
    with pytest.raises(ParameterError, match="sees ground up to"):
        make_scene(SceneParams(sensor="linescan", **{**SMALL, "image_size": 120}))


def test_unknown_body_names_the_option():
    with pytest.raises(ParameterError, match="--body"):
        make_scene(SceneParams(sensor="frame", body="Vulcan", **SMALL))
