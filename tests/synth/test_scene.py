"""The synthetic scene core (demtool.synth): terrain, geometry, rendering, truth."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from demtool.errors import ParameterError
from demtool.synth import (
    SceneParams,
    make_scene,
    rectified_correspondence,
    target_points,
    terrain,
    truth_disparity,
)

# A tiny scene (renders in well under a second) for determinism and parameter tests.
TINY = dict(dem_size=96, n_views=3, image_size=64, crater_count=8, crater_max_diameter_m=20.0,
            boulder_count=20)
# Featureless: a plane of uniform albedo, noise off (for closed-form checks).
PLANE = dict(dem_size=128, n_views=3, image_size=96, fractal_rms_m=0.0, crater_count=0,
             boulder_count=0, albedo_variation=0.0, noise=False)


def dem_height(scene, points: np.ndarray) -> np.ndarray:
    """Bilinear truth-DEM height at world (x, y), computed independently of the renderer."""
    t = scene.dem_transform
    cols = (points[:, 0] - t.c) / t.a - 0.5
    rows = (points[:, 1] - t.f) / t.e - 0.5
    return map_coordinates(scene.dem.astype(np.float64), [rows, cols], order=1, mode="nearest")


def lunar_lambert_closed_form(mu0, mu, phase_deg, albedo):
    """R = ρ (2L μ0/(μ0+μ) + (1−L) μ0), L(α) from McEwen (1991) — written out here."""
    a = phase_deg
    L = 1.0 - 0.019 * a + 2.42e-4 * a**2 - 1.46e-6 * a**3
    return albedo * (2.0 * L * mu0 / (mu0 + mu) + (1.0 - L) * mu0)


# ---------------------------------------------------------------------------------------
# Terrain
# ---------------------------------------------------------------------------------------


def test_crater_diameters_follow_the_cumulative_power_law():
    rng = np.random.default_rng(1)
    d = terrain.crater_diameters(40000, min_diameter_m=5.0, max_diameter_m=500.0, exponent=2.0,
                                 rng=rng)
    assert d.min() >= 5.0 and d.max() <= 500.0
    assert np.all(np.diff(d) <= 0)  # largest first
    for size in (10.0, 20.0, 50.0):
        expected = (size**-2 - 500.0**-2) / (5.0**-2 - 500.0**-2)  # N(>D)/N
        assert np.mean(d > size) == pytest.approx(expected, rel=0.05)


def test_crater_profile_has_floor_rim_and_ejecta_falloff():
    rho = np.array([0.0, 0.5, 1.0, 2.0, 3.0, 4.0])
    z = terrain.crater_profile(rho, depth_ratio=0.2, rim_ratio=0.04, diameter_m=50.0)
    assert z[0] == pytest.approx(2.0 - 10.0)  # rim 2 m, 10 m below the rim crest
    assert z[2] == pytest.approx(2.0)
    assert z[0] < z[1] < z[2] and z[2] > z[3] > z[4]
    assert z[4] == pytest.approx(0.0) and z[5] == 0.0


def test_fractal_surface_has_requested_rms_and_spectral_slope():
    rng = np.random.default_rng(3)
    z = terrain.fractal_surface(256, 1.0, spectral_exponent=3.0, rms_m=2.5, rng=rng)
    assert z.mean() == pytest.approx(0.0, abs=1e-9)
    assert z.std() == pytest.approx(2.5)
    power = np.abs(np.fft.fft2(z)) ** 2
    f = np.fft.fftfreq(256)
    k = np.hypot(f[:, None], f[None, :])
    band = (k > 0.02) & (k < 0.3)
    slope = np.polyfit(np.log(k[band]), np.log(power[band]), 1)[0]
    assert slope == pytest.approx(-3.0, abs=0.15)


def test_albedo_spans_exactly_mean_plus_minus_variation():
    rng = np.random.default_rng(4)
    a = terrain.albedo_map(128, 1.0, mean=0.2, variation=0.1, correlation_m=20.0, rng=rng)
    assert max(a.max() - 0.2, 0.2 - a.min()) == pytest.approx(0.02)
    assert a.min() >= 0.18 - 1e-12 and a.max() <= 0.22 + 1e-12


def test_scene_terrain_has_zero_mean(small_scene):
    assert float(np.mean(small_scene.dem, dtype=np.float64)) == pytest.approx(0.0, abs=1e-4)
    assert small_scene.dem.dtype == np.float32 and small_scene.albedo.dtype == np.float32
    assert small_scene.dem.max() - small_scene.dem.min() > 5.0  # craters give real relief


# ---------------------------------------------------------------------------------------
# Cameras and geometry
# ---------------------------------------------------------------------------------------


def test_target_is_exactly_nadir_with_north_up_and_partner_along_image_x(small_scene):
    target = small_scene.cameras[small_scene.target]
    np.testing.assert_allclose(target.R, np.diag([1.0, -1.0, -1.0]), atol=1e-15)
    np.testing.assert_allclose(target.center, [0, 0, small_scene.distance_m])
    assert small_scene.names == ("view_00", "view_01", "view_02", "view_03")
    assert (small_scene.target, small_scene.partner) == ("view_00", "view_01")
    partner = small_scene.cameras[small_scene.partner]
    baseline = partner.center - target.center
    assert baseline[0] / small_scene.distance_m == pytest.approx(0.3)  # east = image right
    assert baseline[1] == pytest.approx(0.0) and baseline[2] == pytest.approx(0.0)
    # gsd of the target at the mean surface
    assert small_scene.distance_m / target.focal_px == pytest.approx(small_scene.gsd_m)


def test_other_views_span_the_requested_base_to_height_ratios():
    from demtool.synth.scene import camera_positions

    params = SceneParams(n_views=8)
    centres = camera_positions(params)
    ratios = np.linalg.norm(centres[2:, :2], axis=1) / params.altitude_m
    np.testing.assert_allclose(ratios, np.linspace(0.1, 0.5, 6))
    azimuths = np.degrees(np.arctan2(centres[2:, 0], centres[2:, 1])) % 360
    assert np.ptp(azimuths) > 180  # spread all around


@pytest.mark.parametrize("view", ["view_00", "view_01", "view_03"])
def test_hits_lie_on_the_dem_and_project_back_to_their_pixel(small_scene, view):
    camera = small_scene.cameras[view]
    rng = np.random.default_rng(0)
    rows, cols = rng.integers(0, camera.height, 400), rng.integers(0, camera.width, 400)
    pixels = np.column_stack([cols, rows]).astype(float)
    points = camera.backproject(pixels, small_scene.depths[view][rows, cols])
    np.testing.assert_allclose(points[:, 2], dem_height(small_scene, points), atol=1e-5)
    np.testing.assert_allclose(camera.project(points), pixels, atol=1e-6)  # ≪ 0.1 px
    if view == small_scene.target:
        np.testing.assert_allclose(small_scene.truth_target[rows, cols], points[:, 2], atol=1e-4)


def test_projected_dem_nodes_land_on_the_pixel_whose_ray_hits_them(small_scene):
    """Project truth-DEM nodes into the target; the ray through that position hits the node."""
    t = small_scene.dem_transform
    rng = np.random.default_rng(5)
    rows, cols = rng.integers(84, 172, 300), rng.integers(84, 172, 300)  # in the view
    nodes = np.column_stack([t.c + (cols + 0.5) * t.a, t.f + (rows + 0.5) * t.e,
                             small_scene.dem[rows, cols].astype(np.float64)])
    uv = small_scene.cameras[small_scene.target].project(nodes)
    hits = target_points(small_scene, uv)
    error = np.linalg.norm(hits - nodes, axis=1)
    assert np.median(error) < 1e-6
    assert np.mean(error < 1e-3) > 0.99  # a nadir view sees (almost) every node


# ---------------------------------------------------------------------------------------
# Rendering
# ---------------------------------------------------------------------------------------


def _plane_expectation(scene, view):
    camera = scene.cameras[view]
    rows, cols = np.mgrid[0:camera.height, 0:camera.width]
    rays = camera.rays(np.column_stack([cols.ravel(), rows.ravel()]).astype(float))
    ground = camera.center - (camera.center[2] / rays[:, 2])[:, None] * rays  # ray ∩ Z = 0
    toward_camera = camera.center - ground
    toward_camera /= np.linalg.norm(toward_camera, axis=1, keepdims=True)
    sun = scene.sun_vector
    phase = np.degrees(np.arccos(toward_camera @ sun))
    reflectance = lunar_lambert_closed_form(sun[2], toward_camera[:, 2], phase,
                                            scene.params.albedo_mean)
    i = np.radians(scene.params.sun_incidence_deg)
    flat_nadir = lunar_lambert_closed_form(np.cos(i), 1.0, scene.params.sun_incidence_deg,
                                           scene.params.albedo_mean)
    return (reflectance * scene.params.exposure_dn / flat_nadir).reshape(rows.shape)


@pytest.mark.parametrize("sun", [(60.0, 225.0), (30.0, 90.0)])
def test_plane_renders_to_closed_form_lunar_lambert(sun):
    scene = make_scene(SceneParams(**PLANE, sun_incidence_deg=sun[0], sun_azimuth_deg=sun[1]))
    for view in scene.names:
        expected = _plane_expectation(scene, view)
        assert np.abs(scene.images[view] - expected).max() <= 0.5 + 1e-3  # 12-bit rounding
        assert not scene.shadows[view].any()
    assert np.abs(scene.truth_target).max() < 1e-6
    # the oblique views really differ from the nadir one (the check is not vacuous)
    assert abs(np.mean(scene.images["view_01"]) - np.mean(scene.images["view_00"])) > 5


def test_shadows_fall_behind_a_tall_ridge_and_match_the_analytic_outline():
    params = SceneParams(**{**PLANE, "image_size": 160},  # the target sees X = -40 … 40 m
                         sun_incidence_deg=60.0, sun_azimuth_deg=270.0)  # sun in the west
    x = (np.arange(params.dem_size) + 0.5) - 0.5 * params.dem_size
    ridge_x = -12.0
    profile = 15.0 * np.exp(-0.5 * ((x - ridge_x) / 2.5) ** 2)  # north-south ridge, 15 m
    scene = make_scene(params, dem=np.tile(profile, (params.dem_size, 1)))
    camera = scene.cameras[scene.target]
    rows, cols = np.mgrid[0:camera.height, 0:camera.width]
    hits = camera.backproject(np.column_stack([cols.ravel(), rows.ravel()]).astype(float),
                              scene.depths[scene.target].ravel())
    hx = hits[:, 0].reshape(rows.shape)
    # Analytic: shadowed where some terrain west of the point rises above the sun ray.
    tan_elevation = np.tan(np.radians(30.0))
    fine = np.arange(-64.0, 64.0, 0.01)
    fine_h = np.interp(fine, x, profile)
    blocker = np.maximum.accumulate(fine_h + fine * tan_elevation)  # max of h(x') + x' tanε
    hz = np.interp(hx, fine, fine_h)
    analytic = np.interp(hx, fine, blocker) > hz + hx * tan_elevation + 1e-3
    shadow_start, shadow_end = hx[analytic].min(), hx[analytic].max()
    assert ridge_x < shadow_start < ridge_x + 5  # on the lee slope
    assert shadow_end == pytest.approx(ridge_x + 15.0 / tan_elevation, abs=3.0)
    assert hx.max() > shadow_end + 10 and hx.min() < ridge_x - 10  # both ends in view
    shadow = scene.shadows[scene.target]
    assert shadow[(hx > ridge_x + 5) & (hx < ridge_x + 20)].all()  # behind the ridge
    assert not shadow[hx < ridge_x].any() and not shadow[hx > shadow_end + 1].any()
    # the mask equals the analytic outline except within ±0.5 m of its two edges
    outline = (np.abs(hx - shadow_end) < 0.5) | (np.abs(hx - shadow_start) < 0.5)
    assert np.all(shadow[~outline] == analytic[~outline])
    image = scene.images[scene.target]
    assert np.all(image[shadow] == 0)
    assert image[hx < ridge_x - 8].min() > 1000 and image[hx > shadow_end + 1].min() > 1000


@pytest.mark.parametrize("view", ["view_00", "view_03"])
def test_shadow_mask_agrees_with_a_brute_force_march_toward_the_sun(small_scene, view):
    camera = small_scene.cameras[view]
    rng = np.random.default_rng(2)
    rows, cols = rng.integers(0, camera.height, 3000), rng.integers(0, camera.width, 3000)
    points = camera.backproject(np.column_stack([cols, rows]).astype(float),
                                small_scene.depths[view][rows, cols])
    sun = small_scene.sun_vector
    rise = float(small_scene.dem.max()) - points[:, 2]  # march until above every summit
    fractions = np.linspace(0.0, 1.0, 600)[1:]
    u = rise[:, None] / sun[2] * fractions[None, :]  # steps of ≤ 0.06 m horizontally
    samples = points[:, None, :] + u[..., None] * sun
    terrain = dem_height(small_scene, samples.reshape(-1, 3)).reshape(u.shape)
    excess = np.max(terrain - samples[..., 2], axis=1)  # how far the terrain pokes above
    mask = small_scene.shadows[view][rows, cols]
    assert (excess > 0.05).sum() > 20  # the scene has shadows to agree on
    # Every clear blocker is found; misses are grazing (terrain < 5 cm above the sun ray,
    # within a marching step or on the terminator, where the smooth shading normal
    # and the bilinear facets disagree).
    assert mask[excess > 0.05].all()
    assert np.mean(mask == (excess > 1e-4)) > 0.98
    assert np.mean(mask & (excess < 1e-4)) < 0.01  # attached shadows only (μ0 ≤ 0)


def test_same_seed_same_images_other_seed_other_scene():
    a = make_scene(SceneParams(**TINY, seed=7))
    b = make_scene(SceneParams(**TINY, seed=7))
    c = make_scene(SceneParams(**TINY, seed=8))
    for name in a.names:
        np.testing.assert_array_equal(a.images[name], b.images[name])
    np.testing.assert_array_equal(a.dem, b.dem)
    assert not np.array_equal(a.dem, c.dem)
    assert not np.array_equal(a.images["view_00"], c.images["view_00"])


def test_images_are_12_bit_with_photon_and_read_noise(small_scene):
    image = small_scene.images["view_00"]
    assert image.dtype == np.float32 and np.isfinite(image).all()
    assert image.min() >= 0 and image.max() <= 4095
    np.testing.assert_array_equal(image, np.rint(image))
    quiet = make_scene(SceneParams(**PLANE))
    noisy = make_scene(SceneParams(**{**PLANE, "noise": True}))
    difference = noisy.images["view_00"] - quiet.images["view_00"]
    signal = quiet.images["view_00"]
    expected_sigma = np.sqrt(signal.mean() / 10.0 + 2.0**2 + 1 / 12)  # shot, read, rounding
    assert difference.std() == pytest.approx(expected_sigma, rel=0.1)


# ---------------------------------------------------------------------------------------
# Parameters
# ---------------------------------------------------------------------------------------


def test_footprint_beyond_the_dem_is_a_clear_parameter_error():
    with pytest.raises(ParameterError, match=r"view_0\d sees ground .* DEM"):
        make_scene(SceneParams(**{**TINY, "gsd_m": 2.0}))


@pytest.mark.parametrize("change, message", [
    ({"n_views": 1}, "--views"),
    ({"sun_incidence_deg": 95.0}, "--sun-incidence"),
    ({"crater_min_diameter_m": 30.0, "crater_max_diameter_m": 10.0}, "--crater-max"),
    ({"altitude_m": -5.0}, "--altitude"),
    ({"albedo_variation": 1.5}, "--albedo-variation"),
])
def test_invalid_parameters_are_named(change, message):
    with pytest.raises(ParameterError, match=message):
        make_scene(SceneParams(**{**TINY, **change}))


def test_custom_dem_of_wrong_shape_is_rejected():
    with pytest.raises(ParameterError, match="dem has shape"):
        make_scene(SceneParams(**TINY), dem=np.zeros((10, 10)))


# ---------------------------------------------------------------------------------------
# Truth for the later stages
# ---------------------------------------------------------------------------------------


def test_truth_disparity_matches_projection_through_the_rendered_depths(small_scene):
    target = small_scene.cameras[small_scene.target]
    partner = small_scene.cameras[small_scene.partner]
    shift = np.array([[1.0, 0.0, 7.0], [0.0, 1.0, -4.0], [0.0, 0.0, 1.0]])  # both rectified
    shape = (target.height - 10, target.width + 20)
    truth = truth_disparity(small_scene, shift, shift, shape)
    assert truth.disparity.shape == shape and truth.disparity.dtype == np.float32
    rows, cols = np.mgrid[20:150:7, 20:150:7]
    points = target.backproject(np.column_stack([cols.ravel(), rows.ravel()]).astype(float),
                                small_scene.depths[small_scene.target][rows, cols].ravel())
    expected = cols.ravel() - partner.project(points)[:, 0]  # the shift cancels in x
    got = truth.disparity[rows.ravel() - 4, cols.ravel() + 7]
    np.testing.assert_allclose(got, expected, atol=1e-3)
    assert np.isnan(truth.disparity[:, :7]).all()  # left of the target image
    assert truth.visible.mean() > 0.8
    assert np.all(np.isfinite(truth.disparity[truth.visible]))


def test_truth_of_a_large_turn_pair_names_its_views(small_scene):
    """view_00 / view_03 rectified with a −72° turn: the dense truth of that pair (named
    with left= / right=) agrees with point-based truth (target pixels cast onto the DEM,
    projected into view_03) to 0.11 px RMS rows; through the default partner (view_01)
    it would be 2.9 px."""
    from demtool.imaging.homography import apply_homography
    from demtool.rectify.core import rectify_pair, rotation_at_centre

    rect = rectify_pair(small_scene.images["view_00"], small_scene.images["view_03"])
    assert rotation_at_centre(rect.H_left, rect.size_left) < -60
    width, height = rect.size_rect
    match = rectified_correspondence(small_scene, rect.H_left, rect.H_right, (height, width),
                                     left="view_00", right="view_03")
    truth = truth_disparity(small_scene, rect.H_left, rect.H_right, (height, width),
                            left="view_00", right="view_03")
    visible = truth.visible
    assert visible.sum() > 20_000
    dense_rows = (np.arange(height)[:, None] - match.y_right)[visible]
    dense_rms = np.sqrt(np.mean(dense_rows**2))
    # Point-based truth on a grid of target pixels (independent of the rectified grid).
    camera = small_scene.cameras["view_00"]
    rows, cols = np.mgrid[3:camera.height:6, 3:camera.width:6]
    pixels = np.column_stack([cols.ravel(), rows.ravel()]).astype(float)
    seen = small_scene.cameras["view_03"].project(target_points(small_scene, pixels))
    inside = np.all(np.isfinite(seen), axis=1) & np.all((seen > 0) & (seen < 191), axis=1)
    point_rows = (apply_homography(rect.H_left, pixels[inside])[:, 1]
                  - apply_homography(rect.H_right, seen[inside])[:, 1])
    point_rms = np.sqrt(np.mean(point_rows**2))
    assert dense_rms < 0.2 and point_rms < 0.2
    assert abs(dense_rms - point_rms) < 0.03
    # Disparity is x_left − x_right of the same correspondence.
    x_left = np.arange(width)[None, :]
    np.testing.assert_allclose(truth.disparity[visible],
                               (x_left - match.x_right)[visible], atol=1e-3)
    # The defaults are target / partner (view_01): not this pair's truth.
    default = rectified_correspondence(small_scene, rect.H_left, rect.H_right,
                                       (height, width))
    wrong = (np.arange(height)[:, None] - default.y_right)[visible]
    assert np.sqrt(np.nanmean(wrong**2)) > 1.0


@pytest.mark.parametrize(("option", "kwargs"), [("right", {"right": "view_09"}),
                                                ("left", {"left": "nope"})])
def test_truth_names_an_unknown_view(small_scene, option, kwargs):
    with pytest.raises(ParameterError, match=rf"^{option}: the scene has no pinhole view"):
        truth_disparity(small_scene, np.eye(3), np.eye(3), (8, 8), **kwargs)


def test_truth_correspondence_links_similar_intensities(small_scene):
    """Where the truth says two pixels see the same point, both images agree closely."""
    identity = np.eye(3)  # no rectification: right coordinates are partner pixels
    image_t = small_scene.images[small_scene.target]
    match = rectified_correspondence(small_scene, identity, identity, image_t.shape)
    rows, cols = np.nonzero(match.visible)
    image_p = small_scene.images[small_scene.partner]
    sampled = map_coordinates(image_p, [match.y_right[rows, cols], match.x_right[rows, cols]],
                              order=1)
    correlation = np.corrcoef(image_t[rows, cols], sampled)[0, 1]
    shuffled = np.corrcoef(image_t[rows, cols], np.roll(sampled, 37))[0, 1]
    assert correlation > 0.9 and shuffled < 0.5
    truth = truth_disparity(small_scene, identity, identity, image_t.shape)
    np.testing.assert_allclose(truth.disparity[rows, cols], cols - match.x_right[rows, cols],
                               atol=1e-4)
