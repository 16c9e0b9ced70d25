"""demtool.sgm.prior: rays meeting a DEM, the predicted disparity, the warp."""

import numpy as np
import pytest

from demtool.sgm.prior import extend_nearest, intersect_dem, warp_right

RADIUS = 1_737_400.0


def _rays(count=50, seed=0):
    """Rays from 20 km above the sphere's north pole, within 3° of nadir."""
    rng = np.random.default_rng(seed)
    origin = np.array([0.0, 0.0, RADIUS + 20_000.0])
    tilt = np.radians(rng.uniform(-3, 3, (count, 2)))
    direction = np.column_stack([np.tan(tilt[:, 0]), np.tan(tilt[:, 1]), -np.ones(count)])
    return origin, direction / np.linalg.norm(direction, axis=1, keepdims=True)


def test_rays_meet_a_constant_height_on_its_sphere():
    origin, direction = _rays()
    points = intersect_dem(origin, direction, RADIUS, lambda xyz: np.full(len(xyz), 250.0))
    assert np.allclose(np.linalg.norm(points, axis=1), RADIUS + 250.0, atol=1e-6)
    # on the rays, in front of the camera
    along = (points - origin) @ direction.T
    assert np.all(np.diag(along) > 0)
    assert np.allclose(np.cross(points - origin, direction), 0.0, atol=1e-6)


def test_rays_meet_a_sloping_dem_where_its_height_holds():
    """A DEM whose height rises 0.2 m per metre east: the converged point lies on it."""
    origin, direction = _rays(seed=1)

    def heights(xyz):
        return 100.0 + 0.2 * xyz[:, 0]

    points = intersect_dem(origin, direction, RADIUS, heights)
    assert np.isfinite(points).all()
    assert np.allclose(np.linalg.norm(points, axis=1) - RADIUS, heights(points), atol=2e-3)


def test_off_the_dem_and_missing_rays_have_no_point():
    origin, direction = _rays(count=4)
    direction[0] = [0.0, 1.0, 0.0]  # parallel to the surface below: misses the sphere
    direction[0] /= np.linalg.norm(direction[0])

    def heights(xyz):
        return np.where(xyz[:, 0] > 0, np.nan, 0.0)  # no DEM east of the pole

    points = intersect_dem(origin, direction, RADIUS, heights)
    east = (origin + 20_000.0 * direction)[:, 0] > 0
    assert np.isnan(points[0]).all()
    assert np.isnan(points[1:][east[1:]]).all() and np.isfinite(points[1:][~east[1:]]).all()


def test_warp_right_moves_the_image_by_the_disparity_without_losing_its_rim():
    rng = np.random.default_rng(2)
    right = rng.random((40, 60)).astype(np.float32)
    right[:, :5] = np.nan  # outside the rectified image
    shift = np.full(right.shape, 3.0)
    warped = warp_right(right, shift)
    # warped(x) = right(x − 3): defined from column 8 on, exactly equal at integer shifts
    assert np.isnan(warped[:, :8]).all()
    assert np.allclose(warped[:, 8:], right[:, 5:-3], atol=1e-5)
    assert np.isnan(warp_right(right, np.full(right.shape, np.nan))).all()


def test_extend_nearest_fills_only_inside_the_mask():
    values = np.full((5, 5), np.nan)
    values[2, 2] = 7.0
    where = np.zeros((5, 5), dtype=bool)
    where[:, :3] = True
    out = extend_nearest(values, where)
    assert np.all(out[where] == 7.0) and np.isnan(out[~where]).all()
    assert np.isnan(extend_nearest(np.full((3, 3), np.nan), np.ones((3, 3), bool))).all()


@pytest.mark.parametrize("rows", [1, 300])
def test_prior_disparity_blocks_agree_with_one_block(rows, monkeypatch):
    """The row blocks bound memory and change nothing."""
    from demtool.rectify.calibrated import RectifiedGeometry
    from demtool.sgm import prior

    geometry = RectifiedGeometry(
        R_rect=np.diag([1.0, -1.0, -1.0]), f_px=2000.0, cx_left=20.0, cx_right=10.0, cy=15.0,
        size_rect=np.array([40, 30]),
        centers=np.array([[-3000.0, 0.0, RADIUS + 20_000.0], [3000.0, 0.0, RADIUS + 20_000.0]]))

    def heights(xyz):
        return 50.0 * np.sin(xyz[:, 0] / 300.0)

    whole = prior.prior_disparity(geometry, (30, 40), RADIUS, heights)
    monkeypatch.setattr(prior, "ROWS_PER_BLOCK", rows)
    assert np.isfinite(whole).all()
    np.testing.assert_array_equal(prior.prior_disparity(geometry, (30, 40), RADIUS, heights),
                                  whole)
    # B f / depth: 6 km × 2000 px / ~20 km, minus the principal points' 10 px
    assert np.all(np.abs(whole - (6000.0 * 2000.0 / 20_000.0 - 10.0)) < 30.0)
