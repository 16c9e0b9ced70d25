"""Ground control from a reference DEM (``bundle --reference-dem``, issue 14, check 2).

The core on an analytic orbital block (frame cameras 100 km above the Moon, 60° field,
2048 px, independent 50 m / 0.5 mrad errors, tie points 0.1 px): the DEM ties the
block's datum that tie points and priors leave open.  The command's bad inputs: one
line, exit 1, nothing written.
"""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from demtool.bundle.offsets import rotation_vector
from demtool.bundle.priors import AdjustedSensor, adjust_with_priors
from demtool.bundle.surface import ReferenceSurface
from demtool.cli import cli
from tests.bundle import frames, orbital


def _errors(prior, truth, adjustment, xyz):
    """Per image: position error (m), pointing error (mrad) and the largest image
    displacement (px) of ground points between the adjusted and the true model."""
    rows = []
    for model, true, offset in zip(prior, truth, adjustment.offsets, strict=True):
        adjusted = AdjustedSensor(model, offset)
        position = np.linalg.norm(adjusted.camera_center(0.0) - true.position)
        pointing = np.linalg.norm(rotation_vector(offset.matrix @ model.rotation
                                                  @ true.rotation.T)) * 1e3
        line0, sample0 = true.ground_to_image(xyz)
        line1, sample1 = adjusted.ground_to_image(xyz)
        seen = (line0 > 0) & (line0 < true.lines) & (sample0 > 0) & (sample0 < true.samples)
        rows.append((position, pointing,
                     np.max(np.hypot(line1 - line0, sample1 - sample0)[seen])))
    return np.array(rows)


@pytest.fixture(scope="module")
def orbital_block():
    truth = orbital.true_models(altitude=100e3, field_deg=60.0, size=2048)
    half = 100e3 * np.tan(np.radians(30.0)) + 30e3
    xyz = orbital.ground_points(6000, half_width_m=half)
    obs, _ = orbital.tie_observations(truth, xyz, noise_px=0.1)
    heights, transform, crs = orbital.reference_dem(spacing_m=500.0, noise_m=3.0,
                                                    half_width_m=1.2 * half)
    surface = ReferenceSurface(heights, transform, crs, orbital.RADIUS, 5.0)
    return truth, orbital.perturbed(truth, zero_mean=False), obs, surface, xyz


def test_reference_dem_ties_an_orbital_block_to_the_ground(orbital_block):
    """Measured: with the DEM <= 2.9 m, <= 0.023 mrad, <= 0.033 px; without it (priors
    only: the datum is their mean) 26 m, 0.24 mrad, 1.15 px."""
    truth, prior, obs, surface, xyz = orbital_block
    tied = adjust_with_priors(prior, obs, position_sigma=50.0, pointing_sigma=0.5,
                              surface=surface)
    free = adjust_with_priors(prior, obs, position_sigma=50.0, pointing_sigma=0.5)
    with_dem, without = _errors(prior, truth, tied, xyz), _errors(prior, truth, free, xyz)
    assert with_dem[:, 0].max() < 7.0, with_dem
    assert with_dem[:, 1].max() < 0.05, with_dem
    assert with_dem[:, 2].max() < 0.15, with_dem
    assert without[:, 2].max() > 0.6, without  # the datum the priors leave
    assert without[:, 0].max() > 3 * with_dem[:, 0].max()
    # the covariance says how well the data fix each pose: errors within 3 sigmas
    sigmas = tied.sigmas()
    assert np.all(with_dem[:, :2] < 3.0 * sigmas)
    assert np.all(sigmas[:, 0] < 10.0) and np.all(free.sigmas()[:, 0] > 30.0)
    # tie points lie on the DEM within its noise
    dh = tied.surface_residuals[np.isfinite(tied.surface_residuals)]
    assert len(dh) == len(tied.points)
    assert abs(np.median(dh)) < 0.5 and np.sqrt(np.mean(dh ** 2)) < 5.0


def test_jackknife_sigma_widens_only_for_correlated_dem_errors(orbital_block):
    """The spatial jackknife (3 × 3 blocks of tie points) against the formal sigma.
    Independent DEM noise: both say the same (measured ratio 1.00–1.11 in position).
    A DEM error correlated over tens of kilometres (15 m, 60 km × 50 km waves, which
    the formal sigma cannot see): pointing errors 0.046–0.052 mrad against a formal
    0.032 mrad, jackknife 0.037–0.052 mrad."""
    truth, prior, obs, surface, xyz = orbital_block
    tied = adjust_with_priors(prior, obs, position_sigma=50.0, pointing_sigma=0.5,
                              surface=surface)
    ratio = tied.sigmas() / tied.sigmas(formal=True)
    assert np.all(ratio >= 1.0) and np.all(ratio < 1.3), ratio
    rows, cols = np.indices(surface.heights.shape)
    wavy = surface.heights + 15.0 * np.sin(2 * np.pi * rows / 120.0 + 1.0) * np.cos(
        2 * np.pi * cols / 100.0 + 0.5)
    biased = adjust_with_priors(prior, obs, position_sigma=50.0, pointing_sigma=0.5,
                                surface=ReferenceSurface(wavy, surface.transform, surface.crs,
                                                         surface.radius, surface.sigma))
    errors = _errors(prior, truth, biased, xyz)
    formal, jackknife = biased.sigmas(formal=True), biased.sigmas()
    assert np.all(errors[:, 1] > 1.3 * formal[:, 1]), (errors, formal)
    assert np.mean(jackknife[:, 1] / formal[:, 1]) > 1.2, (jackknife, formal)
    assert np.all(errors[:, :2] < 2.0 * jackknife), (errors, jackknife)
    assert biased.jackknife_covariance.shape == (36, 36)
    assert np.allclose(biased.jackknife_covariance, biased.jackknife_covariance.T)


def test_spatial_groups_split_the_ground_into_equal_blocks():
    from demtool.bundle.priors import spatial_groups

    xyz = orbital.ground_points(900, half_width_m=30e3)
    groups = spatial_groups(xyz)
    assert set(groups) == set(range(9))
    counts = np.bincount(groups).reshape(3, 3)
    assert np.all(np.abs(counts.sum(axis=1) - 300) <= 1)  # east terciles
    assert np.all(np.abs(counts - 100) <= 15)
    east, north, _ = orbital._enu()
    # blocks are ordered west to east, then south to north within each
    e = np.array([np.median(xyz[groups == g] @ east) for g in range(9)]).reshape(3, 3)
    n = np.array([np.median(xyz[groups == g] @ north) for g in range(9)]).reshape(3, 3)
    assert np.all(np.diff(e, axis=0) > 10e3) and np.all(np.diff(n, axis=1) > 10e3)


# --- the command's bad inputs -------------------------------------------------------

@pytest.fixture(scope="module")
def sensor_files(tmp_path_factory):
    """Two frame ISDs of the 30 km block and two 320 px noise images (the checks of the
    reference DEM come before any matching)."""
    from demtool import io as dio

    folder = tmp_path_factory.mktemp("dem_inputs")
    rng = np.random.default_rng(0)
    images, isds = [], []
    for model in frames.true_models()[:2]:
        image = folder / f"{model.name}.tif"
        dio.write_raster(image, rng.uniform(0, 100, (320, 320)),
                         transform=dio.image_frame_transform(1.0))
        isd = folder / f"{model.name}.json"
        frames.write_isd(model, isd)
        images.append(str(image))
        isds.append(str(isd))
    return images, isds


def _dem(path, *, crs, transform=None, value=0.0):
    from affine import Affine

    from demtool import io as dio

    dio.write_raster(path, np.full((50, 50), value), crs=crs,
                     transform=transform or Affine(0.02, 0, 19.5, 0, -0.02, 10.5))
    return path


def _run(tmp_path, images, isds, dem, *extra):
    args = ["bundle", *images]
    for isd in isds:
        args += ["--sensors", isd]
    return CliRunner().invoke(cli, [*args, "--reference-dem", str(dem), "--out",
                                    str(tmp_path / "bundle.npz"), "--adjusted-dir",
                                    str(tmp_path / "adjusted"), *extra])


def _refused(result, tmp_path, *words):
    assert result.exit_code == 1, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1, lines
    for word in words:
        assert word in lines[0], lines[0]
    assert not (tmp_path / "bundle.npz").exists()
    assert not (tmp_path / "adjusted").exists()


def test_reference_dem_of_another_body_is_refused(sensor_files, tmp_path):
    from demtool.maps import body_by_name

    dem = _dem(tmp_path / "mars.tif", crs=body_by_name("Mars").geographic_crs())
    _refused(_run(tmp_path, *sensor_files, dem), tmp_path, str(dem), "Mars", "Moon")


def test_reference_dem_in_degrees_without_crs_is_refused(sensor_files, tmp_path):
    dem = _dem(tmp_path / "degrees.tif", crs=None)
    _refused(_run(tmp_path, *sensor_files, dem), tmp_path, str(dem), "no CRS")


def test_reference_dem_on_an_ellipsoid_is_refused(sensor_files, tmp_path):
    dem = _dem(tmp_path / "ellipsoid.tif",
               crs="+proj=longlat +a=1738100 +b=1736000 +no_defs +type=crs")
    _refused(_run(tmp_path, *sensor_files, dem), tmp_path, str(dem), "ellipsoid")


def test_reference_dem_elsewhere_on_the_body_is_refused(sensor_files, tmp_path):
    from affine import Affine

    from demtool.maps import body_by_name

    dem = _dem(tmp_path / "far.tif", crs=body_by_name("Moon").geographic_crs(),
               transform=Affine(0.02, 0, -120.0, 0, -0.02, -40.0))
    _refused(_run(tmp_path, *sensor_files, dem), tmp_path, str(dem), "does not cover")


def test_reference_dem_missing_or_without_sensor_models(sensor_files, tmp_path):
    images, isds = sensor_files
    missing = tmp_path / "missing.tif"
    _refused(_run(tmp_path, images, isds, missing), tmp_path, str(missing))
    result = CliRunner().invoke(cli, ["bundle", *images, "--reference-dem",
                                      str(_dem(tmp_path / "d.tif", crs=None)),
                                      "--out", str(tmp_path / "bundle.npz")])
    _refused(result, tmp_path, "--reference-dem needs sensor models")


def test_reference_dem_sigma_must_be_positive(sensor_files, tmp_path):
    from demtool.maps import body_by_name

    dem = _dem(tmp_path / "moon.tif", crs=body_by_name("Moon").geographic_crs())
    result = _run(tmp_path, *sensor_files, dem, "--reference-dem-sigma", "0")
    assert result.exit_code == 2 and "--reference-dem-sigma" in result.output
    assert not (tmp_path / "bundle.npz").exists()


def test_radius_maps_are_read_as_heights():
    """An ISIS shape model stores radii (LOLA's ldem): its values minus the radius."""
    from demtool.maps import holds_radii

    radius = 1_737_400.0
    assert holds_radii(np.array([[radius + 3000.0, radius - 1500.0]]), radius)
    assert not holds_radii(np.array([[3000.0, -1500.0, np.nan]]), radius)
    assert not holds_radii(np.array([[np.nan]]), radius)


def test_a_camera_moved_beyond_three_sigma_gets_one_warning_naming_the_sigma(caplog):
    import logging

    from demtool.bundle.params import BundleParams
    from demtool.bundle.run import warn_far_moves

    summary = {"images": {
        "near": {"position_change_m": 50.0, "position_change_prior_sigmas": 0.5,
                 "pointing_change_mrad": 0.4, "pointing_change_prior_sigmas": 0.4},
        "far": {"position_change_m": 720.0, "position_change_prior_sigmas": 7.2,
                "pointing_change_mrad": 0.5, "pointing_change_prior_sigmas": 0.5}}}
    log = logging.getLogger("test.far_moves")
    with caplog.at_level(logging.WARNING, logger="test.far_moves"):
        warn_far_moves(summary, BundleParams(), log, reference=True)
    messages = [r.getMessage() for r in caplog.records]
    assert len(messages) == 1 and messages[0].startswith("far moved position by 720.0 m")
    assert "7.2 sigma" in messages[0] and "--position-sigma" in messages[0]
    assert "--pointing-sigma" not in messages[0] and "--reference-dem-sigma" in messages[0]


def test_a_coarse_dem_measures_its_interpolation_error_on_enough_posts(sensor_files,
                                                                       tmp_path):
    """A 6 km-post DEM under a 30 km block: the tie points' window holds a few posts, so
    the slope share is measured on the FACTOR_POSTS around it; each tie point's σ adds
    the curvature bound of the window's own posts."""
    from affine import Affine

    from demtool import io as dio
    from demtool.bundle.run_reference import read_reference_surface
    from demtool.bundle.surface import curvature_error, interpolation_factor, measuring_window
    from demtool.maps import body_by_name
    from demtool.sensors import read_sensor

    rng = np.random.default_rng(3)
    walk = 40.0 * (np.cumsum(rng.normal(size=(100, 100)), axis=0)
                   + np.cumsum(rng.normal(size=(100, 100)), axis=1))
    path = tmp_path / "coarse.tif"
    dio.write_raster(path, walk, crs=body_by_name("Moon").geographic_crs(),
                     transform=Affine(0.2, 0, 10.0, 0, -0.2, 20.0))
    _, isds = sensor_files
    surface = read_reference_surface(path, [read_sensor(p) for p in isds], isds, sigma=10.0)
    r0 = round((surface.transform.f - 20.0) / -0.2)
    c0 = round((surface.transform.c - 10.0) / 0.2)
    rows, cols = surface.heights.shape
    assert rows < 20 and cols < 20  # the footprints' window
    wide = measuring_window((r0, r0 + rows, c0, c0 + cols), walk.shape)
    assert surface.slope_factor == pytest.approx(
        interpolation_factor(walk[wide[0]:wide[1], wide[2]:wide[3]]))
    assert 0.05 < surface.slope_factor < 1.0
    assert surface.curvature == pytest.approx(curvature_error(surface.heights))
