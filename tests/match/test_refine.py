"""Tests of the sub-pixel refinement of `match` (demtool.match.between) and its effect."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from demtool.match import lsm_match, match
from demtool.match.between import between_nodes, refine_translation, spread_nodes
from demtool.match.lsm_base import CONVERGED
from tests.helpers.match import texture, textured_pair

AFFINE = np.array([[1.08, 0.06], [0.03, 0.95]])  # right = left under x' = A u + t
SHIFT = np.array([0.37, -0.21])


def _affine_pair(size: int = 120, seed: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """A texture and its affine-warped copy (gain 0.8, offset 1): the centre maps to
    (c + 0.37, c − 0.21) and a template offset (u, v) to ``AFFINE @ (u, v)``."""
    tex = texture(size, size, seed=seed)
    centre = size // 2
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    rel = np.stack([xx - centre - SHIFT[0], yy - centre - SHIFT[1]])
    uv = np.einsum("ij,jhw->ihw", np.linalg.inv(AFFINE), rel)
    right = 0.8 * ndimage.map_coordinates(tex, [centre + uv[1], centre + uv[0]], order=3) + 1.0
    return tex, right


def test_lsm_returns_the_affine_shape_it_solved():
    tex, right = _affine_pair()
    result = lsm_match(tex, right, np.array([60]), np.array([60]), np.array([60.0]),
                       np.array([60.0]), template=21)
    assert result.status[0] == CONVERGED
    np.testing.assert_allclose(result.affine[0], AFFINE.ravel(), atol=0.01)


@pytest.mark.parametrize("weighting", [0.0, 3.0])
def test_refinement_recovers_the_position_with_the_right_shape(weighting):
    tex, right = _affine_pair()
    rows = np.array([60, 60, 60, 60])
    cols = np.array([60, 60, 60, 60])
    # starts up to 0.35 px off the truth (60.37, 59.79)
    x0 = np.array([60.37, 60.02, 60.6, 60.2])
    y0 = np.array([59.79, 59.79, 60.0, 59.6])
    shape = np.tile(AFFINE.ravel(), (4, 1))
    found = refine_translation(tex, right, rows, cols, x0, y0, shape, template=21,
                               weighting=weighting, iterations=3)
    assert found.ok.all()
    np.testing.assert_allclose(found.x_right, 60 + SHIFT[0], atol=0.01)
    np.testing.assert_allclose(found.y_right, 60 + SHIFT[1], atol=0.01)
    assert np.all(found.correlation > 0.99)
    # one iteration already removes most of a 0.35 px start error
    one = refine_translation(tex, right, rows, cols, x0, y0, shape, template=21,
                             weighting=weighting, iterations=1)
    assert np.all(np.abs(one.x_right - (60 + SHIFT[0])) < 0.06)
    # with the shape wrong (identity) the position is biased: the shape matters
    wrong = refine_translation(tex, right, rows, cols, x0, y0,
                               np.tile([1.0, 0.0, 0.0, 1.0], (4, 1)), template=21,
                               weighting=weighting, iterations=3)
    assert np.all(wrong.correlation < found.correlation)


def test_refinement_refuses_nodata_borders_and_flat_templates():
    tex, right = _affine_pair()
    left = tex.copy()
    left[10, 12] = np.nan  # inside the first template
    right_hole = right.copy()
    right_hole[80, 82] = np.nan  # inside the second template's window
    flat = left.copy()
    flat[90:115, 20:45] = 1.0  # the third template is textureless
    shape = np.tile([1.0, 0.0, 0.0, 1.0], (5, 1))
    rows = np.array([12, 80, 102, 60, 3])
    cols = np.array([12, 80, 32, 60, 60])
    x0 = cols.astype(float) + np.array([0.0, 0.0, 0.0, 0.0, 0.0])
    x0[3] = 115.0  # the fourth window leaves the right image
    for left_image, right_image, bad in ((left, right, 0), (tex, right_hole, 1),
                                         (flat, right, 2)):
        found = refine_translation(left_image, right_image, rows, cols, x0,
                                   rows.astype(float), shape, template=11, weighting=0.0)
        assert not found.ok[bad] and np.isnan(found.correlation[bad])
        assert found.x_right[bad] == x0[bad]  # the start is kept
        assert not found.ok[3] and not found.ok[4]  # off the right image / template border
    with pytest.raises(ValueError, match="iterations"):
        refine_translation(tex, right, rows, cols, x0, rows.astype(float), shape, template=11,
                           weighting=0.0, iterations=0)
    with pytest.raises(ValueError, match="template"):
        refine_translation(tex, right, rows, cols, x0, rows.astype(float), shape, template=10,
                           weighting=0.0)


def test_spread_nodes_interpolates_planes_and_vectors_bilinearly():
    yy, xx = np.mgrid[0:9, 0:11].astype(np.float64)  # nodes every 3 px of a 25 x 31 image
    plane = 0.5 + 0.1 * (3 * xx) - 0.2 * (3 * yy)
    nodes = np.stack([plane, 2 * plane], axis=-1)
    nodes[4, 5] = np.nan  # a rejected node: its four cells are not smooth
    weights, corners, smooth, _ = between_nodes(nodes[..., 0], (25, 31), 3, 1.0)
    out = spread_nodes(nodes, weights, corners, smooth)
    assert out.shape == (25, 31, 2)
    rows, cols = np.mgrid[0:25, 0:31]
    truth = 0.5 + 0.1 * cols - 0.2 * rows
    np.testing.assert_allclose(out[..., 0][smooth], truth[smooth], atol=1e-12)
    np.testing.assert_allclose(out[..., 1][smooth], 2 * truth[smooth], atol=1e-12)
    assert np.isnan(out[13, 16]).all() and not smooth[13, 16]  # next to the rejected node


@pytest.fixture(scope="module")
def fine_relief():
    """A pair whose disparity has relief of a few template widths (curved at 2 px)."""
    def bumpy(x, y):
        return 6.0 + 1.5 * np.sin(x / 10.0) * np.cos(y / 12.0)

    return textured_pair(112, 144, seed=7, noise=0.01, disparity=bumpy)


def test_refinement_makes_grid_spacing_2_more_accurate_at_no_loss_of_completeness(fine_relief):
    left, right, truth = fine_relief
    plain = match(left, right, template=13, threshold=0.9, grid_spacing=2, refine=0)
    refined = match(left, right, template=13, threshold=0.9, grid_spacing=2)
    every = match(left, right, template=13, threshold=0.9, grid_spacing=1, refine=0)
    both = np.isfinite(plain.disparity) & np.isfinite(refined.disparity)
    assert refined.completeness == pytest.approx(plain.completeness, abs=1e-9)

    def rmse(result):
        return float(np.sqrt(np.mean((result.disparity[both] - truth[both]) ** 2)))

    # the refined grid beats the interpolated one (0.046 against 0.049 px) and is at
    # least as good as matching every pixel with Grün's LSM (0.0465 px)
    assert rmse(refined) < 0.97 * rmse(plain)
    assert rmse(refined) <= rmse(every)
    assert rmse(refined) < 0.05
    stats = refined.summary["refined"]
    assert stats["refined"] > 0.95 * stats["tried"]
    assert plain.summary["refined"] is None
    ok = np.isfinite(refined.disparity)
    assert np.all(refined.correlation[ok] >= 0.9)


def test_negative_refine_is_a_parameter_error():
    from click.testing import CliRunner

    from demtool.cli import cli
    from demtool.errors import ParameterError

    left, right, _ = textured_pair(64, 80, seed=1)
    with pytest.raises(ParameterError, match="refine must be >= 0"):
        match(left, right, template=13, refine=-1)
    result = CliRunner().invoke(cli, ["match", "l.tif", "r.tif", "--out", "d.tif",
                                      "--refine", "-1"])
    assert result.exit_code == 2 and "x>=0" in result.output
