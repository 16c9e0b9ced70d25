"""Tests of the `match` core: LSM, NCC, triangles, seeds and the dense matcher."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from demtool.errors import ParameterError, ProcessingError
from demtool.match import (
    SeedTriangulation,
    check_seed_points,
    lsm_match,
    match,
    ncc_search,
)
from demtool.match.lsm_base import CONVERGED, SINGULAR
from demtool.match.seeds import forstner_points, remove_blunders
from tests.helpers.match import texture, textured_pair

# ------------------------------------------------------------------------------ LSM


def _shifted(image: np.ndarray, dx: float, dy: float = 0.0) -> np.ndarray:
    """``image`` resampled at (x + dx, y + dy): a point at x in ``image`` is at x − dx."""
    yy, xx = np.mgrid[0:image.shape[0], 0:image.shape[1]].astype(np.float64)
    return ndimage.map_coordinates(image, [yy + dy, xx + dx], order=3, mode="reflect")


@pytest.mark.parametrize("weighting", [0.0, 3.0])
def test_lsm_recovers_a_pure_subpixel_shift(weighting):
    tex = texture(90, 90, seed=1)
    left = tex
    right = 1.7 * _shifted(tex, 0.3) - 4.0  # d = 0.3 px, with gain and offset
    rows, cols = np.meshgrid(np.arange(25, 66, 8), np.arange(25, 66, 8), indexing="ij")
    rows, cols = rows.ravel(), cols.ravel()
    result = lsm_match(left, right, rows, cols, cols.astype(float), rows.astype(float),
                       template=17, weighting=weighting)
    assert np.all(result.status == CONVERGED)
    disparity = cols - result.x_right
    assert np.max(np.abs(disparity - 0.3)) < 0.05
    assert np.max(np.abs(result.y_right - rows)) < 0.05
    assert np.all(result.correlation > 0.99)
    assert np.all((result.sigma_x > 0) & (result.sigma_x < 0.05))


def test_lsm_recovers_an_affine_warped_patch():
    tex = texture(120, 120, seed=2)
    # right = left under x' = 60 + 0.37 + 1.08 u + 0.06 v, y' = 60 - 0.21 + 0.03 u + 0.95 v
    affine = np.array([[1.08, 0.06], [0.03, 0.95]])
    shift = np.array([0.37, -0.21])
    inverse = np.linalg.inv(affine)
    yy, xx = np.mgrid[0:120, 0:120].astype(np.float64)
    rel = np.stack([xx - 60 - shift[0], yy - 60 - shift[1]])
    uv = np.einsum("ij,jhw->ihw", inverse, rel)
    right = 0.8 * ndimage.map_coordinates(tex, [60 + uv[1], 60 + uv[0]], order=3) + 1.0
    result = lsm_match(tex, right, np.array([60]), np.array([60]), np.array([60.0]),
                       np.array([60.0]), template=21)
    assert result.status[0] == CONVERGED
    assert abs(result.x_right[0] - (60 + shift[0])) < 0.05
    assert abs(result.y_right[0] - (60 + shift[1])) < 0.05
    assert result.correlation[0] > 0.99
    # a shift-only NCC could not reach this: the patch is sheared and scaled
    assert abs((60 - result.x_right[0]) - (-shift[0])) < 0.05


def test_lsm_sigma_matches_the_scatter_of_noisy_matches():
    tex = texture(160, 160, seed=3)
    rng = np.random.default_rng(4)
    noise = 0.15
    left = tex + rng.normal(scale=noise, size=tex.shape)
    right = _shifted(tex, 0.6) + rng.normal(scale=noise, size=tex.shape)
    rows, cols = np.meshgrid(np.arange(20, 141, 6), np.arange(20, 141, 6), indexing="ij")
    rows, cols = rows.ravel(), cols.ravel()
    result = lsm_match(left, right, rows, cols, cols - 1.0, rows.astype(float), template=13)
    ok = result.status == CONVERGED
    assert ok.mean() > 0.95
    errors = (cols - result.x_right)[ok] - 0.6
    # small bias toward the half pixel: resampling smooths the right image's noise most
    # there ("pixel locking"), a known property of LSM with noisy search images
    assert abs(errors.mean()) < 0.035
    # the formal σ (Grün 1985, eq. 15) agrees with the empirical scatter within 50 %
    ratio = errors.std() / np.sqrt(np.mean(result.sigma_x[ok] ** 2))
    assert 0.67 < ratio < 1.5


def test_lsm_fails_cleanly_on_a_flat_template():
    flat = np.full((60, 60), 5.0)
    result = lsm_match(flat, flat, np.array([30]), np.array([30]), np.array([30.0]),
                       np.array([30.0]), template=13)
    assert result.status[0] == SINGULAR
    assert np.isnan(result.x_right[0]) and np.isnan(result.correlation[0])


# ------------------------------------------------------------------------------ NCC


def test_ncc_finds_the_integer_shift_and_its_subpixel_part():
    tex = texture(80, 120, seed=5)
    right = _shifted(tex, 4.25)  # d = 4.25
    rows = np.full(10, 40)
    cols = np.arange(30, 100, 7)
    result = ncc_search(tex, right, rows, cols, np.zeros(10, int), np.full(10, 10), template=15)
    assert np.all(np.abs(result.disparity - 4.25) < 0.15)
    assert np.all(result.correlation > 0.9)


def test_ncc_skips_templates_touching_nodata():
    tex = texture(60, 60, seed=6)
    left = tex.copy()
    left[28:32, 28:32] = np.nan
    result = ncc_search(left, tex, np.array([30, 30]), np.array([30, 50]), np.array([-2, -2]),
                        np.array([2, 2]), template=9)
    assert np.isnan(result.disparity[0])
    assert abs(result.disparity[1]) < 0.1


# ------------------------------------------------------------------------ triangles


def test_triangles_interpolate_a_plane_and_bound_by_vertices():
    rng = np.random.default_rng(7)
    points = rng.uniform(0, 100, size=(30, 2))
    plane = 2.0 + 0.05 * points[:, 0] - 0.03 * points[:, 1]
    tri = SeedTriangulation(points, plane)
    qx, qy = rng.uniform(20, 80, 200), rng.uniform(20, 80, 200)
    bounds = tri.evaluate(qx, qy)
    inside = bounds.inside
    assert inside.mean() > 0.9
    expected = 2.0 + 0.05 * qx - 0.03 * qy
    np.testing.assert_allclose(bounds.disparity[inside], expected[inside], atol=1e-9)
    assert np.all(bounds.low <= bounds.disparity + 1e-9)
    assert np.all(bounds.high >= bounds.disparity - 1e-9)
    far = tri.evaluate(np.array([500.0]), np.array([500.0]))
    assert not far.inside[0]
    assert plane.min() <= far.disparity[0] <= plane.max()


def test_triangles_need_three_non_collinear_seeds():
    with pytest.raises(ProcessingError, match="at least 3"):
        SeedTriangulation(np.array([[0.0, 0.0], [1.0, 1.0]]), np.array([1.0, 2.0]))
    with pytest.raises(ProcessingError, match="collinear"):
        SeedTriangulation(np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]]),
                          np.zeros(4))


def test_blunders_are_removed_from_the_seeds():
    rng = np.random.default_rng(8)
    points = rng.uniform(0, 200, size=(80, 2))
    disparity = 5.0 + 0.01 * points[:, 0]
    disparity[[3, 17, 40]] += np.array([15.0, -12.0, 9.0])
    keep = remove_blunders(points, disparity)
    assert not keep[[3, 17, 40]].any()
    assert keep.sum() >= 74


def test_forstner_points_are_spread_and_inside_valid_data():
    tex = texture(100, 100, seed=9)
    tex[:, :30] = np.nan
    pts = forstner_points(tex, spacing=20, border=9)
    assert len(pts) >= 8
    assert np.all(pts[:, 0] >= 30 + 9)
    cells = {(x // 20, y // 20) for x, y in pts}
    assert len(cells) == len(pts)


def test_seed_points_outside_the_image_are_an_error():
    left = np.array([[10.0, 10.0], [130.0, 20.0]])
    right = np.array([[5.0, 10.0], [125.0, 20.0]])
    with pytest.raises(ParameterError, match="1 of 2 left seed points lie outside the 128 x 96"):
        check_seed_points(left, right, (96, 128), (96, 128), what="seeds.npz")
    with pytest.raises(ParameterError, match="NaN"):
        check_seed_points(np.array([[np.nan, 1.0]]), np.array([[1.0, 1.0]]), (9, 9), (9, 9))


# ---------------------------------------------------------------------- dense match


@pytest.fixture(scope="module")
def pair():
    return textured_pair(96, 128, seed=0)


@pytest.fixture(scope="module")
def matched(pair):
    left, right, _ = pair
    return match(left, right, template=15, threshold=0.9)


def test_match_recovers_a_smooth_disparity(pair, matched):
    _, _, truth = pair
    disparity = matched.disparity
    assert disparity.dtype == np.float32 and disparity.shape == truth.shape
    ok = np.isfinite(disparity)
    errors = np.abs(disparity[ok] - truth[ok])
    assert errors.mean() < 0.05
    assert np.percentile(errors, 99) < 0.2
    # completeness: all but the border strips a template cannot cover
    half = 7
    interior = np.zeros_like(ok)
    interior[half:-half, half + 12:-half] = True
    assert ok[interior].mean() > 0.9
    assert matched.summary["completeness_percent"] == pytest.approx(100 * ok.mean(), abs=0.01)
    # correlation raster: accepted pixels reach the threshold; sigma where accepted
    assert np.all(matched.correlation[ok] >= 0.9)
    assert np.all(np.isfinite(matched.sigma[ok])) and np.all(np.isnan(matched.sigma[~ok]))
    assert np.nanmedian(matched.sigma) < 0.05


def test_match_threshold_rejects_a_textureless_region():
    left, right, truth = textured_pair(96, 128, seed=1)
    rng = np.random.default_rng(2)
    # a flat patch (with faint independent noise) in both images at the same place
    left[30:70, 50:95] = 0.0 + rng.normal(scale=0.01, size=(40, 45))
    right[30:70, 44:89] = 0.2 + rng.normal(scale=0.01, size=(40, 45))
    result = match(left, right, template=13, threshold=0.9)
    core = result.disparity[38:62, 58:87]  # templates entirely inside the flat patch
    assert np.isnan(core).all()
    # LSM either was not tried (NCC far below the threshold) or stayed below it
    assert not (result.correlation[38:62, 58:87] >= 0.9).any()
    ok = np.isfinite(result.disparity)
    assert ok.mean() > 0.3
    assert np.abs(result.disparity[ok] - truth[ok]).mean() < 0.1


def test_match_never_matches_nodata_and_handles_grid_spacing(pair):
    left, right, truth = pair
    left = left.copy()
    left[40:56, 60:80] = np.nan
    result = match(left, right, template=15, threshold=0.9, grid_spacing=3)
    assert np.isnan(result.disparity[40:56, 60:80]).all()
    ok = np.isfinite(result.disparity)
    assert ok.mean() > 0.4
    assert np.abs(result.disparity[ok] - truth[ok]).mean() < 0.06
    assert result.summary["grid_nodes"] == 32 * 43


def test_match_with_prior_seeds_only(pair):
    left, right, truth = pair
    yy, xx = np.mgrid[12:90:15, 20:120:15]
    pts_left = np.column_stack([xx.ravel(), yy.ravel()]).astype(float)
    pts_right = pts_left - np.column_stack([truth[yy, xx].ravel(), np.zeros(yy.size)])
    result = match(left, right, template=15, seed_points=(pts_left, pts_right), use_sift=False)
    assert result.seeds.counts["prior"] == len(pts_left)
    assert "sift" not in result.seeds.counts
    ok = np.isfinite(result.disparity)
    assert ok.mean() > 0.5
    assert np.abs(result.disparity[ok] - truth[ok]).mean() < 0.05


def test_match_without_seeds_is_an_error():
    flat = np.full((64, 80), 3.0, dtype=np.float32)
    ramp = flat + np.linspace(0, 1, 80, dtype=np.float32)[None, :]
    with pytest.raises(ProcessingError, match="seed match"):
        match(ramp, ramp, template=13)


def test_match_rejects_bad_inputs(pair):
    left, right, _ = pair
    with pytest.raises(ParameterError, match="differ in size"):
        match(left, right[:, :100])
    with pytest.raises(ParameterError, match="template"):
        match(left, right, template=16)
    with pytest.raises(ParameterError, match="template"):
        match(left, right, template=27)
    with pytest.raises(ParameterError, match="threshold"):
        match(left, right, threshold=1.0)
    with pytest.raises(ParameterError, match="grid spacing"):
        match(left, right, grid_spacing=0)
    with pytest.raises(ParameterError, match="weighting"):
        match(left, right, weighting=-1.0)
    with pytest.raises(ProcessingError, match="no valid"):
        match(np.full_like(left, np.nan), right)
    with pytest.raises(ParameterError, match="outside"):
        match(left, right, seed_points=(np.array([[500.0, 10.0]]), np.array([[495.0, 10.0]])))
    with pytest.raises(ParameterError, match="too small"):
        match(left[:20, :20], right[:20, :20], template=17)
