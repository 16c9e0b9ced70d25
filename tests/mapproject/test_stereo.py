"""demtool.mapproject.stereo: the search range of two orthoimages from their matches, and the
cells of a map-grid disparity."""

import numpy as np
import pytest

from demtool.errors import InputError, ProcessingError
from demtool.mapproject.stereo import (
    disparity_cells,
    map_cells_xy,
    ortho_disparity_range,
    ortho_pair_matches,
)
from tests.helpers.texture import texture


def _pair(dx: int, dy: int, shape=(160, 200), seed=4):
    """Right = left moved by (−dx, +dy) cells: disparity x_left − x_right = dx."""
    big = texture((shape[0] + 40, shape[1] + 40), np.random.default_rng(seed),
                  blurs=(1.0, 3.0), weights=(1.0, 1.0), sigma=30.0, mean=120.0)
    left = big[20:20 + shape[0], 20:20 + shape[1]]
    right = big[20 - dy:20 - dy + shape[0], 20 + dx:20 + dx + shape[1]]
    return left.astype(np.float32), right.astype(np.float32)


def test_range_brackets_a_known_shift_and_aligned():
    left, right = _pair(dx=5, dy=0)
    found = ortho_disparity_range(left, right, margin=2.0)
    assert found.aligned
    assert found.matches >= 20
    assert abs(found.dy_median) < 0.1 and found.dy_spread < 0.3
    # every match says d = 5: the range is 5 ± the 2-cell margin
    assert 2.5 <= found.low <= 3.5 and 6.5 <= found.high <= 7.5


def test_north_south_offset_is_not_aligned():
    left, right = _pair(dx=3, dy=2)
    found = ortho_disparity_range(left, right)
    assert not found.aligned
    assert found.dy_median == pytest.approx(2.0, abs=0.2)


def test_textureless_pair_has_no_range():
    flat = np.full((64, 64), 100.0, dtype=np.float32)
    with pytest.raises(ProcessingError, match="keypoints"):
        ortho_disparity_range(flat, flat)


def test_disparity_cells_follow_the_middlebury_convention():
    d = np.full((3, 4), np.nan, dtype=np.float32)
    d[1, 2] = 1.5
    d[2, 0] = -2.0
    rows, left_cols, right_cols = disparity_cells(d)
    np.testing.assert_array_equal(rows, [1, 2])
    np.testing.assert_array_equal(left_cols, [2, 0])
    np.testing.assert_allclose(right_cols, [0.5, 2.0])


def test_map_cells_xy_is_the_cell_centre():
    from affine import Affine

    t = Affine(0.5, 0, -10.0, 0, -0.5, 20.0)
    x, y = map_cells_xy(t, np.array([0.0, 2.0]), np.array([0.0, 1.5]))
    np.testing.assert_allclose(x, [-9.75, -9.0])
    np.testing.assert_allclose(y, [19.75, 18.75])


def _ortho(name, data, transform=None):
    """A raster as read (what ortho_pair_matches looks at)."""
    from types import SimpleNamespace

    from affine import Affine

    return SimpleNamespace(path=name, data=data, crs="ESRI:103881",
                           transform=transform or Affine(0.5, 0, 0, 0, -0.5, 0))


def test_the_kept_matches_are_seeds_of_the_known_shift():
    left, right = _pair(dx=4, dy=0)
    found, source, stats = ortho_pair_matches(_ortho("l.tif", left), _ortho("r.tif", right),
                                              stage="match")
    assert found.points_left.shape == found.points_right.shape == (found.matches, 2)
    d = found.points_left - found.points_right
    assert np.median(d[:, 0]) == pytest.approx(4.0, abs=0.1)  # x_right = x_left - 4
    assert np.median(np.abs(d[:, 1])) < 0.1
    assert stats["ortho_matches"] == found.matches and str(found.matches) in source


def test_pair_offset_north_south_is_refused_naming_the_stage():
    left, right = _pair(dx=3, dy=2)
    with pytest.raises(InputError, match="north-south.*match searches along map x"):
        ortho_pair_matches(_ortho("l.tif", left), _ortho("r.tif", right), stage="match")


def test_pair_on_different_grids_is_refused():
    from affine import Affine

    left, right = _pair(dx=3, dy=0)
    moved = _ortho("r.tif", right, Affine(0.5, 0, 1.5, 0, -0.5, 0))
    with pytest.raises(InputError, match="r.tif.*different map grids.*--grid-like"):
        ortho_pair_matches(_ortho("l.tif", left), moved, stage="sgm")
    with pytest.raises(InputError, match="different map grids"):
        ortho_pair_matches(_ortho("l.tif", left), _ortho("r.tif", right[:-4]), stage="sgm")


def test_textureless_pair_is_refused_naming_both_files():
    flat = np.full((64, 64), 100.0, dtype=np.float32)
    with pytest.raises(ProcessingError, match="l.tif and r.tif: cannot set the search range"):
        ortho_pair_matches(_ortho("l.tif", flat), _ortho("r.tif", flat), stage="match")


def test_a_constant_cross_offset_is_shifted_out_for_sgm():
    """A pair's relative pointing error (a constant offset across map x, as an RPC pair's)
    is measured and handed to sgm as a row shift; match, which does not shift, refuses."""
    from demtool.mapproject.stereo import ROW_SHIFT_TAG, shift_rows

    left, right = _pair(dx=3, dy=1)
    found, _, stats = ortho_pair_matches(_ortho("l.tif", left), _ortho("r.tif", right),
                                         stage="sgm", allow_shift=True)
    assert stats[ROW_SHIFT_TAG] == pytest.approx(1.0, abs=0.2)
    # the shifted right image is the left one moved along x only
    shifted = shift_rows(right, 1.0)
    np.testing.assert_array_equal(shifted[:-1, :-3], left[:-1, 3:])
    assert np.isnan(shifted[-1:]).all()
    half = shift_rows(np.arange(12, dtype=np.float32).reshape(4, 3), 0.5)
    np.testing.assert_allclose(half[:3, 0], [1.5, 4.5, 7.5])
    left, right = _pair(dx=3, dy=3)  # beyond a pointing error (2 cells): refused
    with pytest.raises(InputError, match="north-south by 3.00 cells"):
        ortho_pair_matches(_ortho("l.tif", left), _ortho("r.tif", right), stage="sgm",
                           allow_shift=True)
