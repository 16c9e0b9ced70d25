"""Triangulation through sensor models and DEMs on the body's map (demtool.dem.sensors)."""

import numpy as np
import pytest

from demtool.dem.sensors import (
    default_max_ray_gap,
    dem_on_map,
    intersect_rays,
    overlap_mask,
    triangulate_sensors,
)
from demtool.maps import body_by_name
from demtool.maps.grids import grid_xyz
from demtool.sensors.arrays import rotate_pointing, rotation_vector_matrix
from tests.helpers.frame_scene import make_frame_scene


@pytest.fixture(scope="module")
def scene():
    return make_frame_scene(size=96, seed=2)


def test_intersect_rays_closed_form():
    a = np.array([[0.0, 0, 0], [0, 0, 0], [0, 0, 0]])
    u = np.array([[1.0, 0, 0], [1.0, 0, 0], [-1.0, 0, 0]])
    b = np.array([[2.0, -1, 1], [2.0, -1, 1], [2.0, -1, 1]])
    v = np.array([[0.0, 1, 0], [0.0, 1, 0], [0.0, 1, 0]])
    t = intersect_rays(a, u, b, v)
    np.testing.assert_allclose(t.xyz[0], [2.0, 0, 0.5])
    np.testing.assert_allclose(t.gap, 1.0)
    np.testing.assert_allclose(t.range_left[:2], 2.0)
    assert t.in_front[0] and not t.in_front[2]  # behind the first ray's origin


def test_triangulate_sensors_recovers_ground_points(scene):
    rng = np.random.default_rng(0)
    lines = rng.uniform(20, 76, 300)
    samples = rng.uniform(20, 76, 300)
    xyz = scene.left.image_to_ground(lines, samples, height=rng.uniform(-30, 40, 300))
    r_line, r_sample = scene.right.ground_to_image(xyz)
    tri = triangulate_sensors(scene.left, scene.right, lines, samples, r_line, r_sample)
    np.testing.assert_allclose(tri.xyz, xyz, atol=1e-4)
    assert tri.gap.max() < 1e-4 and tri.in_front.all()
    # a pointing error of the right camera: rays miss by about range × angle, systematically
    turned = rotate_pointing(scene.right, rotation_vector_matrix([0, 1e-3, 0]))
    off = triangulate_sensors(scene.left, turned, lines, samples, r_line, r_sample)
    assert 5 < np.median(off.gap) < 25
    limit = default_max_ray_gap(off.gap, gsd_m=5.0)
    assert (off.gap <= limit).mean() > 0.95  # the systematic gap does not reject the pair


def test_default_max_ray_gap():
    gaps = np.r_[np.full(90, 2.0) + np.linspace(-0.1, 0.1, 90), np.full(10, 500.0)]
    limit = default_max_ray_gap(gaps, gsd_m=1.0)
    assert 3.9 < limit < 4.1  # median + 2 GSD (the NMAD term is smaller)
    assert default_max_ray_gap(np.array([np.nan]), 1.0) == np.inf
    # the caller's median of the gaps (screen_ray_gaps has it) gives the same threshold;
    # with a NaN among them it is not the finite ones' median and is not used
    assert default_max_ray_gap(gaps, 1.0, median=float(np.median(gaps))) == limit
    with_nan = np.r_[gaps, np.nan]
    assert default_max_ray_gap(with_nan, 1.0, median=-7.0) == limit


def test_dem_on_map_grids_heights_above_the_sphere(scene):
    moon = body_by_name("Moon")
    rng = np.random.default_rng(1)
    lines = rng.uniform(0, 96, 60000)
    samples = rng.uniform(0, 96, 60000)
    ground = scene.left.image_to_ground(lines, samples)
    # points on a known surface: h = 10 m + a tilt, at those directions
    unit = ground / np.linalg.norm(ground, axis=1, keepdims=True)
    heights = 10.0 + 2e-3 * (ground[:, 1] - ground[:, 1].mean())
    xyz = unit * (moon.radius + heights)[:, None]
    gap = np.full(len(xyz), 0.5)
    result = dem_on_map(xyz, gap, moon, gsd_m=5.0, left=scene.left, right=scene.right)
    assert "Moon" in result.grid.crs.name and result.grid.gsd == (5.0, 5.0)
    truth_xyz = grid_xyz(result.grid, 0.0)
    cell_unit = truth_xyz / np.linalg.norm(truth_xyz, axis=-1, keepdims=True)
    truth = 10.0 + 2e-3 * (cell_unit[..., 1] * moon.radius - ground[:, 1].mean())
    ok = np.isfinite(result.dem)
    assert ok.mean() > 0.5
    assert np.abs(result.dem[ok] - truth[ok]).max() < 0.05
    np.testing.assert_allclose(result.error[np.isfinite(result.error)], 0.5)
    assert not result.filled[~result.overlap].any()
    assert np.isnan(result.dem[~result.overlap]).all()


def test_overlap_mask(scene):
    moon = body_by_name("Moon")
    xyz = scene.left.image_to_ground(np.array([1.0, 95.0, 1.0, 95.0]),
                                     np.array([1.0, 1.0, 95.0, 95.0]))
    from demtool.maps.grids import grid_from_xyz

    grid = grid_from_xyz(moon, xyz, 5.0)
    mask = overlap_mask(grid, scene.left, scene.right, 0.0)
    assert 0.5 < mask.mean() <= 1.0


def test_dem_on_map_same_bits_on_one_thread(scene, monkeypatch):
    """The heights' medians and fill beside the overlap and the gaps' medians, and the
    numpy steps on row parts (demtool.dem.map_parts), give one thread's grid."""
    from demtool.dem import map_parts
    from demtool.tiling.tasks import numba_threads_at_most, threads_limited

    monkeypatch.setattr(map_parts, "MIN_PART_ELEMENTS", 256)
    moon = body_by_name("Moon")
    rng = np.random.default_rng(5)
    lines, samples = rng.uniform(0, 96, 8000), rng.uniform(0, 96, 8000)
    keep = ~((lines > 30) & (lines < 50) & (samples > 40) & (samples < 60))  # a hole
    ground = scene.left.image_to_ground(lines[keep], samples[keep])
    unit = ground / np.linalg.norm(ground, axis=1, keepdims=True)
    xyz = unit * (moon.radius + rng.normal(10.0, 1.0, len(unit)))[:, None]
    gap = rng.random(len(xyz))
    found = [dem_on_map(xyz, gap, moon, gsd_m=4.0, left=scene.left, right=scene.right)]
    with threads_limited(1), numba_threads_at_most(1):
        found.append(dem_on_map(xyz, gap, moon, gsd_m=4.0, left=scene.left,
                                right=scene.right))
    many, one = found
    assert many.filled.any() and np.isnan(many.dem).any()
    for name in ("dem", "error", "filled", "overlap", "points", "point_gaps", "point_index"):
        a, b = getattr(many, name), getattr(one, name)
        np.testing.assert_array_equal(a.view(np.uint8), b.view(np.uint8), err_msg=name)
    assert many.report == one.report and many.grid == one.grid
