"""dem --mapprojected's two sides on two threads (demtool.dem.ortho_rays): the values of
one thread, to the bit (each strip and batch is computed as it would be alone)."""

from types import SimpleNamespace

import numba
import numpy as np
import pytest

from demtool.maps import map_to_lonlat
from tests.helpers.linescan import MOON, linescan_sensor, terrain


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="numba has one thread")
def test_ortho_rays_on_two_threads_are_the_values_of_one():
    from demtool.dem.ortho_rays import ortho_rays
    from demtool.maps.grids import grid_from_xyz

    left = linescan_sensor(lines=120, samples=100, roll_deg=-8.0, lon0=10.2324)
    right = linescan_sensor(lines=120, samples=100, roll_deg=8.0, lon0=9.7676)
    grid = grid_from_xyz(MOON, left.image_to_ground(np.array([0.5, 119.5, 0.5, 119.5]),
                                                    np.array([0.5, 0.5, 99.5, 99.5])), 1.0)

    def heights(x, y):
        return terrain(*map_to_lonlat(grid.crs, x, y))

    orthos = [SimpleNamespace(info=SimpleNamespace(transform=grid.transform), sensor=s,
                              heights=heights) for s in (left, right)]
    rows, cols = np.nonzero(np.ones(grid.shape, bool))
    rows, cols = rows.astype(np.float64), cols.astype(np.float64)
    r_cols = cols - np.random.default_rng(1).uniform(-2.0, 6.0, cols.size)
    found = {}
    for threads in (1, 2):
        previous = numba.get_num_threads()
        numba.set_num_threads(threads)
        try:
            found[threads] = ortho_rays(*orthos, grid.crs, rows, cols, rows, r_cols)
        finally:
            numba.set_num_threads(previous)
    one, two = found[1], found[2]
    assert one.seen.mean() > 0.5
    for a, b in ((one.left, two.left), (one.right, two.right)):
        for name in ("line", "sample", "origin"):
            assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True)
        assert (a.max_error_px, a.exact_points) == (b.max_error_px, b.exact_points)
    assert np.array_equal(one.ground_left, two.ground_left)
    assert np.array_equal(one.ground_right, two.ground_right)
    assert np.array_equal(one.seen, two.seen)
