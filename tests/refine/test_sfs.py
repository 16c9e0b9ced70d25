"""Tests of the shape-from-shading core (demtool.refine) on small scenes with known truth."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from demtool.errors import ParameterError, ProcessingError
from demtool.refine import (
    SfsParameters,
    cast_shadows,
    estimate_albedo,
    kernels,
    make_illumination,
    refine_heights,
    render_dem,
    shadow_mask,
    slopes,
    sun_from_angles,
)
from demtool.refine.filters import (
    BlockGaussianLowpass,
    border_taper,
    central_gradient,
    central_gradient_adjoint,
    dct2,
    gaussian_lowpass,
    idct2,
    masked_gaussian_lowpass,
    median_filter,
    neumann_laplacian_eigenvalues,
)
from demtool.refine.prepare import despike, prepare_dem
from demtool.refine.shading import reflectance_and_gradient, reflectance_map
from demtool.refine.shadow_lengths import ShadowSegments, correct_slope_step, shadow_segments
from tests.helpers.refine import hills_scene, render, rmse, slope_error, sun_vector

FAST = SfsParameters(iterations=60)


@pytest.fixture(scope="module")
def hills():
    """Paraboloid hills, sun 35° high from azimuth 120°, coarse DEM = truth ⊗ Gaussian(6 px)."""
    scene = hills_scene()
    result = refine_heights(scene.image, scene.coarse, spacing=(1.0, 1.0),
                            illumination=make_illumination(scene.sun), parameters=FAST)
    return scene, result


# -------------------------------------------------------------------------- accuracy


def test_plane_stays_a_plane():
    rows, cols = np.mgrid[0:64, 0:80].astype(float)
    plane = 3.0 + 0.15 * cols * 0.5 - 0.05 * rows * 0.5  # spacing 0.5 m
    sun = sun_vector(200.0, 40.0)
    image = render(plane, 0.5, sun) * 1000.0
    result = refine_heights(image, plane, spacing=(0.5, 0.5),
                            illumination=make_illumination(sun), parameters=FAST)
    assert np.abs(result.dem - plane).max() < 1e-3
    assert result.energies.total < 1e-8


def test_hills_recovered_better_than_the_smoothed_input(hills):
    scene, result = hills
    before, after = rmse(scene.coarse, scene.truth), rmse(result.dem, scene.truth)
    slope_before = slope_error(scene.coarse, scene.truth, scene.spacing)
    slope_after = slope_error(result.dem, scene.truth, scene.spacing)
    # measured: RMSE 0.45 → 0.15 m, slope error 0.153 → 0.051
    assert after < 0.45 * before
    assert slope_after < 0.45 * slope_before
    assert result.energies.total < result.initial_energies.total


def test_absolute_heights_kept(hills):
    scene, result = hills
    assert abs(result.dem.mean() - scene.coarse.mean()) < 1e-4
    # the low-passed heights stay those of the input
    low_in = ndimage.gaussian_filter(scene.coarse, 21)
    low_out = ndimage.gaussian_filter(result.dem.astype(float), 21)
    assert rmse(low_in, low_out) < 0.1 * rmse(scene.coarse, scene.truth)


def test_no_jump_at_the_border(hills):
    scene, result = hills
    error = result.dem - scene.truth
    edges = [error[0], error[-1], error[:, 0], error[:, -1]]
    inner = [error[12], error[-13], error[:, 12], error[:, -13]]
    edge_error = np.mean([np.abs(e).mean() for e in edges])
    inner_error = np.mean([np.abs(e).mean() for e in inner])
    input_edge_error = np.mean([np.abs(e).mean() for e in
                                (scene.coarse - scene.truth)[[0, -1]]])
    assert edge_error < 1.5 * inner_error
    assert edge_error < input_edge_error
    # the step between the outer two rows/columns is the truth's, not a jump
    steps = np.concatenate([np.abs(error[0] - error[1]), np.abs(error[-1] - error[-2]),
                            np.abs(error[:, 0] - error[:, 1]), np.abs(error[:, -1] - error[:, -2])])
    assert steps.mean() < 0.05


def test_energy_decreases_every_accepted_iteration(hills):
    _, result = hills
    totals = np.array([e.total for e in result.history])
    # the photometry (albedo, shadows) is re-estimated every 5 iterations, which may raise
    # the energy; within each block the energy never rises
    params = SfsParameters()
    for start in range(1, len(totals) - 1, params.update_every):
        block = totals[start:start + params.update_every]
        assert np.all(np.diff(block) <= 1e-9 * block[0])


def test_lambert_model_also_refines():
    rng = np.random.default_rng(0)
    scene = hills_scene(size=96, noise=0.0)
    sun = scene.sun
    dz_drow, dz_dcol = np.gradient(scene.truth)
    mu0 = (sun[2] + dz_dcol * -sun[0] + dz_drow * sun[1]) / np.sqrt(1 + dz_drow**2 + dz_dcol**2)
    image = (np.clip(mu0, 0, None) * 500 + rng.normal(0, 0.5, mu0.shape)).astype(np.float32)
    result = refine_heights(image, scene.coarse, spacing=(1.0, 1.0),
                            illumination=make_illumination(sun),
                            parameters=SfsParameters(model="lambert", iterations=40))
    assert rmse(result.dem, scene.truth) < 0.5 * rmse(scene.coarse, scene.truth)


# -------------------------------------------------------------------------- albedo


def test_albedo_recovers_a_smooth_field():
    scene = hills_scene(albedo_variation=0.25, noise=0.0)
    modelled = render_dem(scene.truth, (1.0, 1.0), make_illumination(scene.sun))
    albedo = estimate_albedo(scene.image, modelled, sigma=21.0)
    variation = scene.albedo / scene.albedo.mean() - 1
    assert np.abs(variation).max() > 0.15  # a constant estimate would be off by 15%
    # the estimate is the albedo seen through the σ_ρ low-pass ...
    smoothed = gaussian_lowpass(scene.albedo, 21.0)
    inner = (slice(21, -21), slice(21, -21))
    assert np.abs(albedo / smoothed - 1)[inner].max() < 0.01
    # ... which is the albedo itself to a few percent for a field this smooth (the
    # low-pass flattens its extremes; within σ_ρ of the border the mirror biases it)
    error = albedo / scene.albedo - 1
    assert np.sqrt(np.mean(error[inner] ** 2)) < 0.25 * np.sqrt(np.mean(variation**2))
    assert np.abs(error).max() < 0.1


def test_refine_recovers_albedo_and_heights_together():
    scene = hills_scene(albedo_variation=0.25)
    result = refine_heights(scene.image, scene.coarse, spacing=(1.0, 1.0),
                            illumination=make_illumination(scene.sun), parameters=FAST)
    error = (result.albedo / scene.albedo - 1)[21:-21, 21:-21]
    assert np.abs(error).max() < 0.03
    assert rmse(result.dem, scene.truth) < 0.5 * rmse(scene.coarse, scene.truth)


# -------------------------------------------------------------------------- shadows


def test_cast_shadow_length_of_a_wall():
    dem = np.zeros((40, 60))
    dem[:, 10:12] = 5.0  # a north-south wall 5 m high, 1 m cells
    sun = sun_from_angles(270.0, 30.0)  # sun in the west (−x): shadow to the east
    shadow = cast_shadows(dem, (1.0, 1.0), make_illumination(sun))
    length = shadow[20, 12:].sum()
    assert abs(length - 5.0 / np.tan(np.radians(30.0))) <= 1.0  # 8.7 m
    assert not shadow[20, :10].any()  # lit side


def test_cast_shadows_only_where_asked():
    dem = np.zeros((40, 60))
    dem[:, 10:12] = 5.0
    illumination = make_illumination(sun_from_angles(270.0, 30.0))
    full = cast_shadows(dem, (1.0, 1.0), illumination)
    candidates = np.zeros(dem.shape, bool)
    candidates[15:25] = True
    part = cast_shadows(dem, (1.0, 1.0), illumination, candidates=candidates)
    assert np.array_equal(part[candidates], full[candidates]) and part[15:25].any()
    attached = cast_shadows(dem, (1.0, 1.0), illumination, candidates=~np.ones_like(candidates))
    assert np.array_equal(part[~candidates], attached[~candidates])
    assert attached.sum() < 0.3 * full.sum()  # the wall's far face only, not its shadow


def test_cast_shadows_respect_anisotropic_spacing():
    dem = np.zeros((60, 40))
    dem[10:12, :] = 4.0  # an east-west wall; sun from image up (+y, north)
    sun = sun_from_angles(0.0, 45.0)
    shadow = cast_shadows(dem, (1.0, 0.5), make_illumination(sun))  # rows 0.5 m apart
    assert abs(shadow[12:, 20].sum() - 4.0 / 0.5) <= 1.0


def test_shadows_are_excluded_and_follow_the_coarse_dem():
    scene = hills_scene(size=96, elevation=25.0, azimuth=90.0)
    truth = scene.truth.copy()
    truth[40:56, 30:34] += 6.0  # a block; the sun is east, its shadow ~13 px long to the west
    sun = scene.sun
    illumination = make_illumination(sun)
    image = render(truth, 1.0, sun) * 800.0
    shadow_true = cast_shadows(truth, (1.0, 1.0), illumination)
    image[shadow_true] = 2.0  # nearly black
    coarse = ndimage.gaussian_filter(truth, 6.0)
    mask = shadow_mask(coarse, image, (1.0, 1.0), illumination, threshold=0.05)
    assert mask[shadow_true].mean() > 0.95
    with_shadows = refine_heights(image, coarse, spacing=(1.0, 1.0), illumination=illumination,
                                  parameters=SfsParameters(iterations=60, shadow_weight=0.0))
    without = refine_heights(image, coarse, spacing=(1.0, 1.0), illumination=illumination,
                             parameters=SfsParameters(iterations=60, shadow_threshold=0.0,
                                                      cast_shadows=False, shadow_weight=0.0))
    with_lengths = refine_heights(image, coarse, spacing=(1.0, 1.0),
                                  illumination=illumination, parameters=FAST)
    assert with_shadows.shadow[shadow_true].all()
    assert with_shadows.shadow.mean() < 0.1  # and not much more
    core = ndimage.binary_erosion(shadow_true) & (truth < 3)  # the shadow on the ground
    # measured: deviation from the coarse DEM 0.79 m with shadows vs 1.49 m without,
    # error vs truth 1.19 m vs 1.80 m
    deviation_with = rmse(with_shadows.dem[core], coarse[core])
    deviation_without = rmse(without.dem[core], coarse[core])
    assert deviation_with < 0.65 * deviation_without
    assert rmse(with_shadows.dem[core], truth[core]) < 0.8 * rmse(without.dem[core], truth[core])
    # a wall's shadow fixes the total drop, not where it happens (spread over the shadow)
    assert rmse(with_lengths.dem[core], truth[core]) < 0.8 * rmse(without.dem[core],
                                                                  truth[core])


def crater_scene(elevation: float):
    """Rough ground with three rimmed bowls (5 and 2.5 m deep), sun from the east."""
    size = 96
    rows, cols = np.mgrid[0:size, 0:size].astype(float)
    rng = np.random.default_rng(1)
    truth = ndimage.gaussian_filter(rng.normal(0, 1, (size, size)), 4) * 2
    for r0, c0, radius, depth in ((48, 48, 18, 5.0), (20, 75, 9, 2.5), (75, 20, 10, 2.5)):
        r2 = ((rows - r0) ** 2 + (cols - c0) ** 2) / radius**2
        truth += np.where(r2 < 1, -depth * (1 - r2), 0) \
            + 0.6 * depth * np.exp(-((np.sqrt(r2) - 1) ** 2) / 0.02)
    truth = ndimage.gaussian_filter(truth, 1.0)
    illumination = make_illumination(sun_vector(90.0, elevation))
    image = render(truth, 1.0, illumination.sun) * 800.0
    shadow = cast_shadows(truth, (1.0, 1.0), illumination)
    image[shadow] = 2.0
    return truth, image, shadow, illumination, ndimage.gaussian_filter(truth, 6.0)


def test_shadow_lengths_recover_crater_depths():
    truth, image, shadow, illumination, coarse = crater_scene(15.0)
    assert 0.1 < shadow.mean() < 0.2
    none = refine_heights(image, coarse, spacing=(1.0, 1.0), illumination=illumination,
                          parameters=SfsParameters(shadow_weight=0.0))
    lengths = refine_heights(image, coarse, spacing=(1.0, 1.0), illumination=illumination)
    core = ndimage.binary_erosion(shadow)
    # measured: RMSE 0.46 → 0.38 m overall, 0.97 → 0.87 m inside the shadows
    assert rmse(lengths.dem, truth) < 0.9 * rmse(none.dem, truth)
    assert rmse(lengths.dem[core], truth[core]) < 0.95 * rmse(none.dem[core], truth[core])
    assert lengths.energies.shadow > 0 and none.energies.shadow == 0


def test_shadow_segments_trace_crossings_toward_the_sun():
    dark = np.zeros((20, 40), bool)
    dark[5:15, 20:30] = True
    usable = np.ones_like(dark)
    usable[14, 25] = False  # a crossing through a pixel without data is dropped
    east = make_illumination(sun_from_angles(90.0, 30.0))
    segments = shadow_segments(dark & usable, usable, (1.0, 1.0), east)
    assert segments.count == 9
    first = slice(segments.starts[0], segments.starts[1])
    assert segments.rows[first].tolist() == [5] * 12
    assert segments.cols[first].tolist() == list(range(19, 31))  # A, the shadow, E
    assert segments.coef_p[first].tolist() == [0.5] + [1.0] * 10 + [0.5]
    assert np.allclose(segments.coef_q, 0.0, atol=1e-12)
    assert segments.target == pytest.approx(11 * np.tan(np.radians(30.0)), rel=1e-6)
    # the sun in the north-east over rows twice as far apart: diagonal crossings
    north_east = make_illumination(sun_from_angles(45.0, 30.0))
    diagonal = shadow_segments(dark, usable, (1.0, 2.0), north_east)
    steps = np.diff(diagonal.starts) - 1
    lengths_m = steps * np.hypot(1.0, 1.0)  # one column (1 m) and half a row (1 m) a step
    assert diagonal.count > 0
    assert diagonal.target == pytest.approx(lengths_m * np.tan(np.radians(30.0)), rel=1e-5)
    assert diagonal.rows.min() >= 0 and diagonal.cols.max() < 40
    overhead = make_illumination([0.0, 0.0, 1.0])
    assert shadow_segments(dark, usable, (1.0, 1.0), overhead).count == 0


def test_shadow_step_is_the_exact_solve():
    rng = np.random.default_rng(9)
    shape = (1, 6)
    p, q, Rp, Rq = (rng.normal(size=shape).astype(np.float32) for _ in range(4))
    weight = np.array([[1.0, 0.0, 0.0, 0.0, 0.5, 1.0]], np.float32)
    c, omega = 0.3, 0.7
    b0 = rng.normal(size=(6, 2))
    blocks = [c * np.eye(2) + weight[0, j] * np.outer([Rp[0, j], Rq[0, j]],
                                                     [Rp[0, j], Rq[0, j]]) for j in range(6)]
    step0 = np.array([np.linalg.solve(blocks[j], b0[j]) for j in range(6)])
    p_new = (p + step0[:, 0]).astype(np.float32)
    q_new = (q + step0[:, 1]).astype(np.float32)
    a = rng.normal(size=(6, 2)).astype(np.float32)
    segments = ShadowSegments(np.array([0, 6]), np.zeros(6, np.int64), np.arange(6),
                              a[:, 0].copy(), a[:, 1].copy(), np.array([0.4], np.float32))
    residual = float(np.sum(a[:, 0] * p[0] + a[:, 1] * q[0]) - 0.4)
    correct_slope_step(p, q, p_new, q_new, Rp, Rq, weight, c, omega, segments)
    matrix = np.zeros((12, 12))
    for j in range(6):
        matrix[2 * j:2 * j + 2, 2 * j:2 * j + 2] = blocks[j]
    flat_a = a.astype(float).reshape(-1)
    matrix += omega * np.outer(flat_a, flat_a)
    expected = np.linalg.solve(matrix, b0.reshape(-1) - omega * flat_a * residual)
    assert np.allclose(p_new[0] - p[0], expected[0::2], atol=1e-5)
    assert np.allclose(q_new[0] - q[0], expected[1::2], atol=1e-5)


# -------------------------------------------------------------------------- pieces


def test_reflectance_gradient_matches_finite_differences():
    rng = np.random.default_rng(1)
    p = rng.uniform(-0.4, 0.4, (20, 20)).astype(np.float32)
    q = rng.uniform(-0.4, 0.4, (20, 20)).astype(np.float32)
    illumination = make_illumination(sun_vector(60.0, 40.0), (0.1, -0.05, 1.0))
    for model in ("lunar-lambert", "lambert"):
        R, Rp, Rq = reflectance_and_gradient(p, q, illumination, model)
        h = 1e-3
        p64, q64 = p.astype(float), q.astype(float)
        num_p = (reflectance_map(p64 + h, q64, illumination, model)
                 - reflectance_map(p64 - h, q64, illumination, model)) / (2 * h)
        num_q = (reflectance_map(p64, q64 + h, illumination, model)
                 - reflectance_map(p64, q64 - h, illumination, model)) / (2 * h)
        assert np.allclose(R, reflectance_map(p, q, illumination, model), atol=1e-6)
        assert np.allclose(Rp, num_p, atol=2e-3)
        assert np.allclose(Rq, num_q, atol=2e-3)


def test_slopes_sign_convention():
    rows, cols = np.mgrid[0:10, 0:12].astype(float)
    dem = 2.0 * cols * 0.5 + 3.0 * (-rows) * 0.25  # z = 2 x + 3 y, y up
    p, q = slopes(dem, (0.5, 0.25))
    assert np.allclose(p[:, 1:-1], 2.0) and np.allclose(q[1:-1], 3.0)


def test_gradient_adjoint_and_majorisation():
    rng = np.random.default_rng(2)
    z, ex, ey = (rng.normal(size=(17, 23)).astype(np.float64) for _ in range(3))
    gx, gy = central_gradient(z, 0.8)
    lhs = np.sum(gx * ex + gy * ey)
    rhs = np.sum(z * central_gradient_adjoint(ex, ey, 0.8))
    assert lhs == pytest.approx(rhs, rel=1e-10)
    # |G z|² ≤ zᵀ DᵀD z: the DCT Laplacian majorises the central-difference operator
    laplacian = neumann_laplacian_eigenvalues(z.shape, 0.8)
    assert np.sum(gx**2 + gy**2) <= np.sum(laplacian * dct2(z) ** 2) * (1 + 1e-6)


def test_dct_laplacian_eigenvalues():
    rng = np.random.default_rng(3)
    z = rng.normal(size=(12, 9))
    padded = np.pad(z, 1, mode="edge")
    laplacian = (4 * z - padded[:-2, 1:-1] - padded[2:, 1:-1] - padded[1:-1, :-2]
                 - padded[1:-1, 2:])
    assert np.allclose(idct2(neumann_laplacian_eigenvalues(z.shape) * dct2(z)), laplacian,
                       atol=1e-5)


def test_lowpass_filters():
    rng = np.random.default_rng(4)
    noise = rng.normal(size=(64, 64)).astype(np.float32)
    assert np.allclose(gaussian_lowpass(np.full((30, 40), 7.0), 5.0), 7.0, atol=1e-5)
    reference = ndimage.gaussian_filter(noise.astype(float), 3.0, mode="reflect")
    assert np.abs(gaussian_lowpass(noise, 3.0) - reference).max() < 0.02
    weight = np.ones((64, 64), np.float32)
    weight[20:30, 20:30] = 0
    values = np.where(weight > 0, 5.0, 1e6)
    assert np.allclose(masked_gaussian_lowpass(values, weight, 4.0), 5.0, atol=1e-3)


def test_median_filter_equals_scipy():
    rng = np.random.default_rng(5)
    values = rng.normal(size=(41, 37)).astype(np.float32)
    ties = np.round(rng.normal(size=(50, 70)) * 2).astype(np.float32)  # many equal values
    small = rng.normal(size=(7, 9)).astype(np.float32)  # window wider than the grid
    ramp = np.add.outer(np.arange(300.0), np.arange(40.0)).astype(np.float32)  # >1024 ranks
    for array in (values, ties, small, ramp):
        for size in (3, 15):
            expected = ndimage.median_filter(array, size=size, mode="reflect")
            assert np.array_equal(median_filter(array, size), expected)
    assert np.array_equal(median_filter(values, 0), values)
    with pytest.raises(ValueError, match="odd"):
        median_filter(values, 4)


def test_border_taper():
    taper = border_taper((20, 30), 5.0)
    assert taper[0].max() == 0 and taper[:, -1].max() == 0
    assert taper[10, 15] == 1.0 and 0 < taper[2, 15] < 1


# -------------------------------------------------------------------------- bad input


def test_sun_below_the_horizon_is_refused():
    with pytest.raises(ParameterError, match="below the horizon"):
        make_illumination([0.5, 0.2, -0.1])
    with pytest.raises(ParameterError, match="below the horizon"):
        make_illumination([0.5, 0.2, 0.8], [0.0, 0.3, -1.0])
    with pytest.raises(ParameterError, match="zero length"):
        make_illumination([0.0, 0.0, 0.0])


def test_bad_arrays_are_refused():
    illumination = make_illumination(sun_vector(0.0, 45.0))
    dem = np.zeros((32, 32))
    with pytest.raises(ProcessingError, match="same grid"):
        refine_heights(np.ones((32, 31)), dem, spacing=(1, 1), illumination=illumination)
    bad = dem.copy()
    bad[3, 3] = np.nan
    with pytest.raises(ProcessingError, match="non-finite"):
        refine_heights(np.ones((32, 32)), bad, spacing=(1, 1), illumination=illumination)
    with pytest.raises(ProcessingError, match="lit"):
        refine_heights(np.full((32, 32), np.nan), dem, spacing=(1, 1),
                       illumination=illumination)
    with pytest.raises(ParameterError, match="gamma"):
        refine_heights(np.ones((32, 32)), dem, spacing=(1, 1), illumination=illumination,
                       parameters=SfsParameters(gamma=0.0))
    with pytest.raises(ParameterError, match="unknown reflectance model"):
        SfsParameters(model="hapke").check()


def test_prepare_dem_refuses_nan_only_and_too_many_gaps():
    with pytest.raises(ProcessingError, match="no finite height"):
        prepare_dem(np.full((20, 20), np.nan))
    dem = np.zeros((20, 20))
    dem[:10] = np.nan
    with pytest.raises(ProcessingError, match="50.0% of the DEM is NaN"):
        prepare_dem(dem, max_nan_fraction=0.2)


def test_prepare_dem_median_removes_spikes():
    dem = np.zeros((40, 40), np.float32)
    dem[10, 10] = 50.0
    dem[30, 25] = -50.0
    prepared = prepare_dem(dem, median_size=15)
    assert np.abs(prepared.dem).max() == 0.0
    assert prepare_dem(dem, median_size=0).dem.max() == 50.0


def test_despike_keeps_relief_and_finds_blunders():
    rng = np.random.default_rng(6)
    rows, cols = np.mgrid[0:80, 0:80].astype(float)
    bowl = 3.0 * np.exp(-((rows - 40) ** 2 + (cols - 40) ** 2) / (2 * 6.0**2))  # 12 px wide
    dem = (-bowl + rng.normal(0, 0.05, bowl.shape)).astype(np.float32)
    dem[10, 60] += 5.0
    dem[65:67, 15:17] -= 4.0
    prepared = prepare_dem(dem, median_size=15)
    assert prepared.spikes[10, 60] and prepared.spikes[65:67, 15:17].all()
    assert prepared.spikes.sum() < 20
    # the anchor keeps the bowl the median flattens; the start surface is it smoothed
    assert prepared.dem[40, 40] < -2.8 and median_filter(dem, 15)[40, 40] > -2.5
    assert np.allclose(prepared.initial, gaussian_lowpass(prepared.dem, 2.0))
    assert prepared.initial[40, 40] < -2.7 and np.std(prepared.initial[:20, :20]) < 0.02
    everywhere = prepare_dem(dem, median_size=15, spike_threshold=0.0, start_sigma=0.0)
    assert everywhere.spikes.all() and np.array_equal(everywhere.dem, median_filter(dem, 15))
    assert np.array_equal(everywhere.initial, everywhere.dem)
    off = prepare_dem(dem, median_size=0, start_sigma=0.0)
    assert np.array_equal(off.dem, dem) and not off.spikes.any()
    assert not despike(dem, dem, 4.0, 15).any()


def test_refine_starts_from_the_initial_surface():
    scene = hills_scene(size=64)
    illumination = make_illumination(scene.sun)
    shifted = scene.coarse + 5.0  # the mean height always comes from the DEM
    short = SfsParameters(iterations=1)
    a = refine_heights(scene.image, scene.coarse, spacing=(1.0, 1.0),
                       illumination=illumination, parameters=short, initial=shifted)
    b = refine_heights(scene.image, scene.coarse, spacing=(1.0, 1.0),
                       illumination=illumination, parameters=short)
    assert abs(a.dem.mean() - scene.coarse.mean()) < 1e-4
    assert np.allclose(a.dem, b.dem, atol=1e-4)
    flat = np.full_like(scene.coarse, scene.coarse.mean())
    c = refine_heights(scene.image, scene.coarse, spacing=(1.0, 1.0),
                       illumination=illumination, parameters=short, initial=flat)
    assert rmse(c.dem, flat) < 0.9 * rmse(b.dem, flat)  # measured 0.61 vs 0.76
    with pytest.raises(ProcessingError, match="initial heights"):
        refine_heights(scene.image, scene.coarse, spacing=(1.0, 1.0),
                       illumination=illumination, initial=flat[:-1])


# -------------------------------------------------------------------------- kernels


def test_kernels_match_the_numpy_operators():
    rng = np.random.default_rng(7)
    shape = (23, 31)
    p, q, gx, gy, other = (rng.uniform(-0.4, 0.4, shape).astype(np.float32)
                           for _ in range(5))
    aspect = 0.8
    out_x, out_y = np.empty_like(p), np.empty_like(p)
    kernels.central_gradient(p, aspect, out_x, out_y)
    ref_x, ref_y = central_gradient(p, aspect)
    assert np.allclose(out_x, ref_x, atol=1e-6) and np.allclose(out_y, ref_y, atol=1e-6)
    adjoint = np.empty_like(p)
    kernels.integrability_adjoint(p, q, gx, gy, aspect, adjoint)
    assert np.allclose(adjoint, central_gradient_adjoint(p - gx, q - gy, aspect), atol=1e-6)
    illumination = make_illumination(sun_vector(60.0, 40.0), (0.1, -0.05, 1.0))
    from demtool.imaging.reflectance import mcewen_L

    for model, code in kernels.COMPILED_MODELS.items():
        R, Rp, Rq = (np.empty_like(p) for _ in range(3))
        kernels.reflectance_partials(p, q, illumination.sun, illumination.view,
                                     float(mcewen_L(illumination.phase_deg)), code, R, Rp, Rq)
        for got, expected in zip((R, Rp, Rq), reflectance_and_gradient(p, q, illumination,
                                                                       model), strict=True):
            assert np.allclose(got, expected, atol=1e-5)
    weight = rng.uniform(0, 1, shape).astype(np.float32)
    sums = kernels.energy_sums(p, q, gx, gy, other, other, gx, gy, q, p, weight)
    expected = (np.sum(weight * (p - q) ** 2.0), np.sum((p - other) * gx + (q - other) * gy),
                np.sum((p - gx) ** 2.0 + (q - gy) ** 2.0))
    assert np.allclose(sums, expected, rtol=1e-5)


def test_gradient_lowpass_is_the_gaussian_and_symmetric():
    rng = np.random.default_rng(8)
    shape = (152, 132)
    lowpass = BlockGaussianLowpass(shape, 21.0)
    assert lowpass.block == 4
    assert BlockGaussianLowpass((150, 130), 21.0).block == 2  # the largest common divisor ≤ 4
    assert BlockGaussianLowpass((97, 130), 21.0).block == 1
    x, y = (rng.normal(size=shape).astype(np.float32) for _ in range(2))
    zero = np.zeros(shape, np.float32)
    fx, fy = lowpass.apply(x, zero), lowpass.apply(y, zero)
    # self-adjoint and positive, norm ≤ 1 (the slope step majorises it by δ I)
    assert np.sum(fx * y, dtype=float) == pytest.approx(np.sum(x * fy, dtype=float), rel=1e-4)
    assert 0 <= np.sum(fx * x, dtype=float) <= np.sum(x * x, dtype=float)
    # on a smooth field it is the Gaussian σ = 21 px applied twice (fᵀf), per 4 × 4 block
    rows, cols = np.mgrid[0:152, 0:132]
    smooth = np.sin(2 * np.pi * cols / 90.0 + 0.3) * np.cos(2 * np.pi * rows / 110.0)
    smooth = smooth.astype(np.float32)
    expected = gaussian_lowpass(gaussian_lowpass(smooth, 21.0), 21.0)
    expected_blocks = expected.reshape(38, 4, 33, 4).mean(axis=(1, 3))
    got = lowpass.apply(smooth, zero)
    assert np.abs(got[::4, ::4] - expected_blocks).max() < 0.02 * np.abs(expected).max()
    assert np.allclose(lowpass.apply(smooth + 1.0, zero + 1.0), got, atol=1e-5)


def test_prepare_dem_fills_gaps():
    pytest.importorskip("demtool.imaging.interpolate")
    rows, cols = np.mgrid[0:40, 0:40].astype(np.float32)
    plane = 0.5 * cols - 0.25 * rows
    dem = plane.copy()
    dem[15:20, 12:18] = np.nan
    prepared = prepare_dem(dem, median_size=0)
    assert prepared.filled.sum() == 30
    assert np.abs(prepared.dem - plane).max() < 0.05


def test_the_stop_is_logged_once_without_repeating_the_count(caplog):
    """One line per stop: "reached 3 iterations", never "... after 3 iterations"."""
    import logging

    rows, cols = np.mgrid[0:32, 0:40].astype(float)
    plane = 3.0 + 0.1 * cols - 0.05 * rows
    sun = sun_vector(200.0, 40.0)
    image = render(plane + 0.3 * np.sin(cols / 4.0), 1.0, sun) * 1000.0
    with caplog.at_level(logging.INFO, logger="demtool"):
        result = refine_heights(image, plane, spacing=(1.0, 1.0),
                                illumination=make_illumination(sun),
                                parameters=SfsParameters(iterations=3, tolerance=0.0))
    stops = [r.getMessage() for r in caplog.records if result.stop_reason in r.getMessage()]
    assert len(stops) == 1 and "after" not in stops[0]
