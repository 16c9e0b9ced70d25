"""dem --mapprojected's two sides on two threads (demtool.dem.ortho_rays): the values of
one thread, to the bit (each strip and batch is computed as it would be alone)."""

import numba
import numpy as np
import pytest

from tests.helpers.linescan import ortho_ray_case


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="numba has one thread")
def test_ortho_rays_on_two_threads_are_the_values_of_one():
    from demtool.dem.ortho_rays import ortho_rays

    _, _, grid, orthos, _, rows, cols, r_cols = ortho_ray_case(120, 100)
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
