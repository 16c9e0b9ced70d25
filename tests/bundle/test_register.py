"""Registration of the prior block to a reference DEM before the adjustment
(``demtool.bundle.surface.register_points``, issue 14): a known shift of a point cloud
is found on analytic terrain, and a rendered orbital line-scan pair whose priors start
the adjustment outside the DEM fit's reach ends on the ground."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from demtool.bundle.surface import ReferenceSurface, register_points
from tests.bundle import orbital
from tests.helpers.bench import load_bench


def _surface(*, amplitude: float, scale: float, post_m: float = 100.0):
    heights, transform, crs = orbital.reference_dem(spacing_m=post_m, noise_m=1.0,
                                                    half_width_m=20e3, amplitude=amplitude,
                                                    scale=scale)
    return ReferenceSurface(heights, transform, crs, orbital.RADIUS, 2.0)


@pytest.mark.parametrize("amplitude, scale", [(500.0, 0.2), (1000.0, 1.0)])
def test_a_known_shift_is_found(amplitude, scale):
    """Points on the terrain moved 340 m west, 210 m north and 45 m up (beyond the reach
    of the slopes of 1.4 km hills) come back to within a quarter post (25 m) and the
    DEM's noise (measured: 5 m, 5 m, 0.08 m)."""
    surface = _surface(amplitude=amplitude, scale=scale)
    east, north, up = orbital._enu()
    moved_by = -340.0 * east + 210.0 * north + 45.0 * up
    xyz = orbital.ground_points(2000, half_width_m=15e3, amplitude=amplitude, scale=scale,
                                seed=9)
    found = register_points(surface, xyz + moved_by, radius_m=600.0)
    error = found.shift + moved_by
    assert abs(error @ east) < 25.0 and abs(error @ north) < 25.0
    assert abs(error @ up) < 1.0
    assert found.east_m == pytest.approx(340.0, abs=25.0)
    assert found.spread_m < 5.0 < 20.0 < found.spread_before_m
    assert found.searched_m == 600.0 and found.used


def test_points_off_the_dem_give_no_registration():
    surface = _surface(amplitude=500.0, scale=0.2)
    east, _, _ = orbital._enu()
    far = orbital.ground_points(200, half_width_m=5e3, seed=3) + 80e3 * east
    assert register_points(surface, far, radius_m=500.0) is None


def test_the_search_keeps_to_its_radius():
    """A shift twice the radius is not found: the search is bounded by the priors."""
    surface = _surface(amplitude=500.0, scale=0.2)
    east, _, _ = orbital._enu()
    xyz = orbital.ground_points(1000, half_width_m=15e3, amplitude=500.0, scale=0.2)
    found = register_points(surface, xyz + 800.0 * east, radius_m=400.0)
    assert np.hypot(found.east_m, found.north_m) <= 400.0 + 1e-6


@pytest.mark.slow
def test_line_scan_pair_starting_beyond_the_dem_fit_ends_on_the_ground(tmp_path):
    """An orbital line-scan pair (100 km, 5 m pixels, craters of 20 m–1.5 km), ISDs 50 m /
    0.5 mrad off, a reference DEM of 20 m posts + 1 m noise.  Started from the priors
    the adjustment converged on a wrong fit with perfect residuals: the adjusted models
    put the ground 0.63 px (3 m) off in both images (measured before the registration,
    and with ``--no-register-to-dem`` in bench/bundle_register.py); from the block
    registered to the DEM first it ended 0.12 px off, the lower cost of the two.  With
    the denser default tie points (12656 keypoints per 900 px image instead of 8192)
    the two starts swapped roles (0.17 px from the priors, 0.74 px from the registered
    block, at a lower cost: local minima a few metres apart on the bilinear DEM); with
    the first adjustment run on the DEM averaged over 2 × 2 posts, then on the DEM, both
    starts end 0.13–0.15 px off after the first round and 0.17 px after the second (the
    priors' start at the lower cost, so the registration is found but not used)."""
    from demtool.cli import cli

    bench, register_bench = load_bench("bundle_priors_dem"), load_bench("bundle_register")
    scene = tmp_path / "scene"
    made = CliRunner().invoke(cli, ["-q", "synth", *register_bench.SYNTH, "--seed", "0",
                                    "--out", str(scene)])
    assert made.exit_code == 0, made.output
    names = ["view_00", "view_01"]
    bench.perturb(scene, tmp_path / "perturbed", names, np.random.default_rng(1))
    reference, error = bench.degraded_reference(scene / "truth_dem_map.tif",
                                                tmp_path / "reference.tif", factor=4,
                                                noise_m=1.0, seed=2)
    args = ["-q", "bundle", *[str(scene / f"{n}.tif") for n in names]]
    for n in names:
        args += ["--sensors", str(tmp_path / "perturbed" / f"{n}.json")]
    done = CliRunner().invoke(cli, [
        *args, "--position-sigma", "50", "--pointing-sigma", "0.5", "--reference-dem",
        str(reference), "--reference-dem-sigma", str(error), "--adjusted-dir",
        str(tmp_path / "adjusted"), "--out", str(tmp_path / "bundle.npz")])
    assert done.exit_code == 0, done.output
    summary = json.loads((tmp_path / "bundle.npz.json").read_text())["summary"]
    registration = summary["reference_dem"]["registration"]
    assert registration["spread_m"] < registration["spread_before_m"]
    offsets = register_bench.ground_offsets(scene, tmp_path / "adjusted", names)
    assert np.all(offsets[:, 0] < 0.3), (offsets, registration)


def test_a_geographic_dem_gives_the_same_registration():
    """A DEM in degrees of longitude and latitude (LOLA's simple cylindrical products):
    post spacing and search in metres all the same (0.001° ≈ 30 m posts here)."""
    from affine import Affine

    from demtool.maps import body_by_name

    lon0, lat0 = orbital.CENTRE_LONLAT
    step, n = 0.001, 900
    transform = Affine(step, 0.0, lon0 - 0.5 * n * step, 0.0, -step, lat0 + 0.5 * n * step)
    cols, rows = np.meshgrid(np.arange(n) + 0.5, np.arange(n) + 0.5)
    heights = orbital.relief(transform.c + cols * step, transform.f - rows * step,
                             amplitude=500.0, scale=0.2)
    surface = ReferenceSurface(heights, transform, body_by_name("Moon").geographic_crs(),
                               orbital.RADIUS, 2.0)
    centre = orbital.ground_points(1, half_width_m=1.0, amplitude=500.0, scale=0.2)[0]
    assert surface.post_spacing_m(centre) == pytest.approx(
        np.sqrt(np.cos(np.radians(lat0))) * np.radians(step) * orbital.RADIUS, rel=0.01)
    east, north, up = orbital._enu()
    moved_by = 150.0 * east - 120.0 * north - 20.0 * up
    xyz = orbital.ground_points(1500, half_width_m=10e3, amplitude=500.0, scale=0.2)
    found = register_points(surface, xyz + moved_by, radius_m=300.0)
    error = found.shift + moved_by
    assert abs(error @ east) < 10.0 and abs(error @ north) < 10.0
    assert abs(error @ up) < 1.0
