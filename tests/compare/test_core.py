"""Tests of the compare core: grids, co-registration, ICP, statistics, summaries."""

import numpy as np
import pytest
from affine import Affine

from demtool.compare import compare_dems, coregister, summarize
from demtool.compare.coreg import nuth_kaab, vertical_offset
from demtool.compare.grids import Grid, resample_to_grid, sample_cubic, shift_dem
from demtool.compare.icp import (
    _euler_xyz_deg,
    apply_similarity,
    icp_point_to_plane,
    rotation_matrix,
)
from demtool.compare.stats import completeness, difference_statistics, slope_class_statistics
from demtool.errors import ParameterError, ProcessingError
from tests.helpers.compare import fourier_shift, fractal, wavy

TRUE_SHIFT = (1.3, -0.7, 2.0)  # how the DEM was displaced from the truth (x, y px; z m)


@pytest.fixture(scope="module")
def truth() -> np.ndarray:
    return fractal(160, relief=30.0, seed=3)


@pytest.fixture(scope="module")
def displaced(truth) -> np.ndarray:
    dx, dy, dz = TRUE_SHIFT
    noise = np.random.default_rng(4).normal(scale=0.02, size=truth.shape)
    return fourier_shift(truth, dx, dy) + dz + noise


# ----------------------------------------------------------------------------- grids


def test_cubic_shift_is_exact_on_quadratics_and_keeps_holes():
    rows, cols = np.indices((40, 50), dtype=float)

    def poly(r, c):
        # Keys' kernel (a = -1/2) reproduces polynomials up to degree 2 exactly
        return 0.01 * c**2 - 0.02 * r * c + 0.03 * r**2 + 0.5 * r + 3.0

    shifted = shift_dem(poly(rows, cols), 0.3, -1.6, 2.0, method="cubic")
    inner = np.s_[3:-3, 3:-3]
    np.testing.assert_allclose(shifted[inner], poly(rows + 1.6, cols - 0.3)[inner] + 2.0,
                               atol=1e-9)
    holed = poly(rows, cols)
    holed[20, 25] = np.nan
    shifted = shift_dem(holed, 0.5, 0.5, method="cubic")
    assert np.isnan(shifted[19:23, 24:28]).all()  # the 4x4 taps that see the hole
    assert np.isfinite(shifted[10, 10])
    np.testing.assert_array_equal(shift_dem(holed, 0.0, 0.0, method="cubic"), holed)


def test_lanczos_shift_is_close_to_the_band_limited_shift():
    surface = fractal(128, beta=4.0, relief=20.0, seed=8)
    exact = fourier_shift(surface, 2.4, -0.35)
    inner = np.s_[6:-6, 6:-6]
    lanczos = shift_dem(surface, 2.4, -0.35)[inner] - exact[inner]
    cubic = shift_dem(surface, 2.4, -0.35, method="cubic")[inner] - exact[inner]
    assert np.sqrt(np.mean(lanczos**2)) < 0.8 * np.sqrt(np.mean(cubic**2))
    assert np.sqrt(np.mean(lanczos**2)) < 2e-3 * 20.0
    holed = surface.copy()
    holed[60, 60] = np.nan
    grown = np.isnan(shift_dem(holed, 0.5, 0.5))
    assert grown[58:64, 58:64].all() and grown[8:-8, 8:-8].sum() == 36  # 6 x 6 taps


def test_resample_between_image_frame_grids_with_different_spacing():
    src = Grid((60, 80), Affine(1.0, 0, 0, 0, -1.0, 0))
    dst = Grid((20, 25), Affine(2.0, 0, 10.0, 0, -2.0, -4.0))
    rows, cols = np.indices(src.shape, dtype=float)
    values = 0.3 * cols - 0.2 * rows + 5.0  # a plane: bilinear is exact
    out = resample_to_grid(values, src, dst)
    dr, dc = np.indices(dst.shape, dtype=float)
    x, y = 10.0 + 2.0 * (dc + 0.5), -4.0 - 2.0 * (dr + 0.5)  # destination centres
    np.testing.assert_allclose(out, 0.3 * (x - 0.5) - 0.2 * (-y - 0.5) + 5.0, atol=1e-12)


def test_mismatched_crs_is_reprojected():
    from rasterio.crs import CRS

    utm = CRS.from_epsg(32633)
    # The same projection with the origin shifted 1 km east: the DEM's coordinates differ
    # from the reference's by +1000 m in x.
    shifted = CRS.from_proj4("+proj=tmerc +lat_0=0 +lon_0=15 +k=0.9996 +x_0=501000 +y_0=0 "
                             "+datum=WGS84 +units=m +no_defs")
    east, north, spacing = 400_000.0, 5_000_000.0, 2.0
    reference_grid = Grid((64, 64), Affine(spacing, 0, east, 0, -spacing, north), utm)
    dem_grid = Grid((80, 80), Affine(spacing, 0, east + 1000 - 20, 0, -spacing, north + 20),
                    shifted)
    rows, cols = np.indices((80, 80), dtype=float)
    dem = wavy(east - 20 + spacing * (cols + 0.5), north + 20 - spacing * (rows + 0.5))
    out = resample_to_grid(dem, dem_grid, reference_grid)
    rr, cc = np.indices((64, 64), dtype=float)
    expected = wavy(east + spacing * (cc + 0.5), north - spacing * (rr + 0.5))
    assert np.isfinite(out).all()
    np.testing.assert_allclose(out, expected, atol=0.01)  # bilinear on a smooth surface
    # ignoring the CRS would put the DEM 1 km off: no overlap at all
    with pytest.raises(ProcessingError, match="do not overlap"):
        resample_to_grid(dem, Grid(dem_grid.shape, dem_grid.transform, None),
                         Grid(reference_grid.shape, reference_grid.transform, None))


def test_no_overlap_is_a_clear_error():
    a = Grid((10, 10), Affine(1, 0, 0, 0, -1, 0))
    b = Grid((10, 10), Affine(1, 0, 100, 0, -1, 0))
    with pytest.raises(ProcessingError, match="do not overlap"):
        resample_to_grid(np.zeros((10, 10)), a, b)


# ----------------------------------------------------------------------- co-registration


def test_nuth_kaab_recovers_a_known_subpixel_shift(truth, displaced):
    result = nuth_kaab(displaced, truth)
    dx, dy, dz = TRUE_SHIFT
    # the shift that aligns the DEM is the opposite of its displacement
    assert result.dx_px == pytest.approx(-dx, abs=0.005)
    assert result.dy_px == pytest.approx(-dy, abs=0.005)
    assert result.dz == pytest.approx(-dz, abs=0.005)
    assert result.converged
    assert 0 < result.sigma_dx_px < 0.005 and 0 < result.sigma_dy_px < 0.005
    aligned = shift_dem(displaced, result.dx_px, result.dy_px, result.dz)
    residual = (aligned - truth)[8:-8, 8:-8]
    assert np.sqrt(np.nanmean(residual**2)) < 0.04  # noise 0.02 m + interpolation


def test_uncertainty_grows_on_flat_terrain_and_warns():
    rough = fractal(128, relief=30.0, seed=5)
    flat = rough / 30.0 * 0.05  # 5 cm of relief
    noise = np.random.default_rng(6).normal(scale=0.05, size=rough.shape)
    sigmas = []
    for surface in (rough, flat):
        _, alignment = coregister(fourier_shift(surface, 0.4, 0.3) + noise, surface)
        sigmas.append(alignment.shift_uncertainty["dx_px"])
        last = alignment
    assert sigmas[1] > 20 * sigmas[0]
    assert sigmas[1] > 0.1
    assert any("poorly constrained" in w for w in last.warnings)


def test_divergence_is_reported_and_compare_falls_back(truth):
    unrelated = fractal(160, relief=30.0, seed=99)
    with pytest.raises(ProcessingError, match="diverged"):
        nuth_kaab(unrelated, truth, max_iterations=8)
    report = compare_dems(unrelated, truth).report
    assert report["alignment"]["method"] == "none"
    assert any("diverged" in w for w in report["warnings"])


def test_vertical_offset_is_the_median():
    reference = np.zeros((20, 20))
    dem = np.full((20, 20), -3.0)
    dem[0, :5] = 100.0  # outliers do not move a median
    assert vertical_offset(dem, reference).dz == pytest.approx(3.0)


def test_identical_dems_give_zero_error_and_full_completeness(truth):
    for method in ("none", "offset", "nuth-kaab"):
        result = compare_dems(truth, truth.copy(), spacing=2.0, align=method)
        report = result.report
        assert report["completeness"] == 100.0
        assert report["count"] == truth.size
        assert report["rmse"] < 1e-9 and report["max"] - report["min"] < 1e-9
        assert abs(report["shift"]["dx_px"]) < 1e-6 and abs(report["shift"]["dz"]) < 1e-9
        assert report["effective_resolution"]["nyquist_limited"]
        assert report["effective_resolution"]["wavelength_m"] == pytest.approx(4.0)


def test_nan_holes_reduce_completeness_by_their_share(truth):
    dem = truth.copy()
    dem[10:42, 20:60] = np.nan  # 32 x 40 = 1280 pixels
    dem[100, :] = np.nan  # 160 more
    share = 100.0 * (1280 + 160) / truth.size
    report = compare_dems(dem, truth, align="none").report
    assert report["completeness"] == pytest.approx(100.0 - share, abs=1e-9)
    reference = truth.copy()
    reference[:16, :] = np.nan  # the reference's own holes are not counted against the DEM
    expected = 100.0 * (1 - (1280 - 6 * 40 + 160) / (truth.size - 16 * 160))
    assert compare_dems(dem, reference, align="none").report["completeness"] == \
        pytest.approx(expected, abs=1e-9)


def _rotated_surface(angles_rad, translation, spacing, size):
    """Analytic surface moved by R = Rx Rz about the grid centre, sampled on the grid."""
    rows, cols = np.indices((size, size), dtype=float)
    gx, gy = cols * spacing, -rows * spacing
    centre = np.array([gx.mean(), gy.mean(), 0.0])
    rotation = rotation_matrix(np.array([angles_rad[0], 0, 0])) @ \
        rotation_matrix(np.array([0, 0, angles_rad[1]]))
    x, y = gx.copy(), gy.copy()
    for _ in range(60):  # find the surface point that lands on each grid node
        p = np.stack([x, y, wavy(x, y)], -1) - centre
        moved = p @ rotation.T + centre + translation
        x += gx - moved[..., 0]
        y += gy - moved[..., 1]
    p = np.stack([x, y, wavy(x, y)], -1) - centre
    return (p @ rotation.T + centre + translation)[..., 2], rows, cols, rotation


def test_icp_recovers_a_known_small_rotation():
    spacing, size = 2.0, 96
    tilt, yaw = np.radians(0.3), np.radians(0.5)
    dem, rows, cols, rotation = _rotated_surface((tilt, yaw), np.array([0.8, -0.5, 1.5]),
                                                 spacing, size)
    reference = wavy(cols * spacing, -rows * spacing)
    result = icp_point_to_plane(dem, reference, spacing=(spacing, spacing))
    assert result.converged
    np.testing.assert_allclose(result.rotation_deg, _euler_xyz_deg(rotation.T), atol=2e-3)
    assert result.rotation_deg[2] == pytest.approx(-0.5, abs=2e-3)
    assert np.all(result.sigma_rotation_deg < 1e-3)
    aligned = apply_similarity(dem, result, spacing=(spacing, spacing))
    assert np.nanmax(np.abs(aligned - reference)) < 5e-3
    assert np.isfinite(aligned).mean() > 0.9
    # with scale: no scale in the data, so it stays 1
    scaled = icp_point_to_plane(dem, reference, spacing=(spacing, spacing),
                                estimate_scale=True)
    assert scaled.scale == pytest.approx(1.0, abs=1e-4)


def test_chained_alignment_reports_the_total_shift(truth, displaced):
    aligned, alignment = coregister(displaced, truth, method="nuth-kaab+icp")
    assert [step["method"] for step in alignment.steps] == ["nuth-kaab", "icp"]
    assert alignment.shift["dx_px"] == pytest.approx(-TRUE_SHIFT[0], abs=0.01)
    assert alignment.shift["dy_px"] == pytest.approx(-TRUE_SHIFT[1], abs=0.01)
    assert alignment.shift["dz"] == pytest.approx(-TRUE_SHIFT[2], abs=0.01)
    assert np.sqrt(np.nanmean((aligned - truth)[8:-8, 8:-8] ** 2)) < 0.04


def test_icp_on_a_plane_is_degenerate_and_compare_falls_back_to_unaligned():
    plane = np.zeros((40, 40))
    with pytest.raises(ProcessingError, match="too flat"):
        icp_point_to_plane(plane + 1.0, plane)
    report = compare_dems(plane + 1.0, plane, align="icp").report
    assert report["alignment"]["method"] == "none"
    assert report["mean"] == pytest.approx(1.0)
    assert any("alignment 'icp' failed" in w and "too flat" in w for w in report["warnings"])


# ----------------------------------------------------------------------------- statistics


def test_statistics_of_known_values():
    values = np.array([[-1.0, 0.0, 1.0, 2.0, np.nan]])
    stats = difference_statistics(values)
    assert stats["count"] == 4
    assert stats["mean"] == pytest.approx(0.5)
    assert stats["median"] == pytest.approx(0.5)
    assert stats["rmse"] == pytest.approx(np.sqrt(1.5))
    assert stats["std"] == pytest.approx(np.sqrt(1.25))
    assert stats["nmad"] == pytest.approx(1.4826 * 1.0)
    assert stats["le90"] == pytest.approx(np.percentile([1, 0, 1, 2], 90))
    assert (stats["min"], stats["max"]) == (-1.0, 2.0)
    assert difference_statistics(np.full(3, np.nan))["count"] == 0


def test_statistics_are_the_textbook_formulas_to_the_bit():
    """difference_statistics computes its order statistics and squares in one scratch
    array, overwritten in turn: the numbers of the formulas written out (odd and even
    counts, heavy tails, holes)."""
    from demtool.imaging.robust import NMAD_FACTOR

    rng = np.random.default_rng(1)
    for size in (1, 2, 3, 10, 11, 1001, 20000):
        values = rng.standard_t(3, size=size) * 0.3 + 0.1
        if size > 5:
            values[::7] = np.nan
        x = values[np.isfinite(values)]
        median = float(np.median(x))
        assert difference_statistics(values) == {
            "count": x.size, "mean": float(x.mean()), "median": median,
            "std": float(x.std()), "rmse": float(np.sqrt(np.mean(x * x))),
            "nmad": float(NMAD_FACTOR * np.median(np.abs(x - median))),
            "le90": float(np.percentile(np.abs(x), 90)), "min": float(x.min()),
            "max": float(x.max())}


def test_slope_in_place_is_the_formula_to_the_bit():
    from demtool.compare.stats import slope_degrees

    rng = np.random.default_rng(2)
    dem = rng.normal(size=(50, 60)).cumsum(axis=0)
    dem[5:9, 3:7] = np.nan
    grad_row, grad_col = np.gradient(dem)
    expected = np.degrees(np.arctan(np.hypot(grad_col / 2.0, grad_row / 0.5)))
    assert np.array_equal(slope_degrees(dem, (2.0, 0.5)), expected, equal_nan=True)
    assert np.isfinite(expected).mean() > 0.9


def test_slope_classes_partition_the_pixels():
    difference = np.arange(6.0)
    slope = np.array([1.0, 4.0, 5.0, 12.0, 90.0, np.nan])
    classes = slope_class_statistics(difference, slope, [0, 5, 10, 90])
    assert [c["count"] for c in classes] == [2, 1, 2]
    assert classes[2]["max"] == 4.0  # 90 is in the last class


def test_completeness_map():
    reference = np.ones((2, 3))
    reference[0, 0] = np.nan
    dem = np.ones((2, 3))
    dem[1, 1] = np.nan
    percent, coverage = completeness(dem, reference)
    assert percent == pytest.approx(80.0)
    np.testing.assert_array_equal(coverage, [[np.nan, 1, 1], [1, 0, 1]])


def test_summarize_gives_the_table_row(truth, displaced):
    row = summarize(displaced, truth, spacing=2.0)
    assert row["rmse"] < 0.04 and row["completeness"] > 95
    assert row["dx_px"] == pytest.approx(-TRUE_SHIFT[0], abs=0.005)
    assert row["wavelength_m"] is not None and row["wavelength_m"] >= 4.0
    assert row["coherent_frequency_per_m"] == pytest.approx(1.0 / row["wavelength_m"])


def test_bad_parameters(truth):
    with pytest.raises(ParameterError, match="unknown alignment 'icpp'"):
        compare_dems(truth, truth, align="icpp")
    with pytest.raises(ParameterError, match="slope bins"):
        compare_dems(truth, truth, slope_bins=[10, 5])
    with pytest.raises(ProcessingError, match="no common valid pixel"):
        compare_dems(np.full(truth.shape, np.nan), truth)


def test_cubic_sampler_returns_nan_outside():
    values = np.ones((5, 5))
    out = sample_cubic(values, np.array([2.0, -0.5, 2.0]), np.array([2.0, 2.0, 4.5]))
    assert out[0] == 1.0 and np.isnan(out[1:]).all()


def test_threaded_comparison_gives_the_one_thread_numbers(truth, displaced, monkeypatch):
    import json

    from demtool.compare import threads as compare_threads
    from demtool.tiling.distributed import threads_limited

    holed = displaced.copy()
    holed[40:60, 70:75] = np.nan
    mask = np.ones(truth.shape, dtype=bool)
    mask[:, :8] = False
    monkeypatch.setattr(compare_threads, "THREADED_CELLS", 64)  # the 160² grid, 2 threads
    runs = []
    for threads in (1, 2):
        with threads_limited(threads):
            assert compare_threads.threaded(truth.size) == (threads == 2)
            runs.append(compare_dems(holed, truth, spacing=2.0, mask=mask))
    one, two = runs
    assert json.dumps(one.report, sort_keys=True) == json.dumps(two.report, sort_keys=True)
    for name in ("aligned", "difference", "coverage", "slope"):
        np.testing.assert_array_equal(getattr(two, name), getattr(one, name))
    assert one.report["count"] > 0.85 * truth.size  # the mask, the hole, the shifted border
