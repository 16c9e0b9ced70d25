"""``bundle --control-network``: line scanners adjusted on an ISIS control network."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from demtool.bundle.network import adjust_network, image_axes, solve_mask
from demtool.bundle.network_inputs import build_problem, match_serials, serial_clock
from demtool.bundle.network_models import CorrectedSensor, adjust_isd_timed
from demtool.cli import cli
from demtool.errors import InputError
from demtool.io.controlnet import write_control_network
from demtool.sensors import sensor_from_isd
from tests.bundle import network_block as nb
from tests.helpers.linescan import isd_dict

NAMES = ["img0", "img1", "img2"]
SIGMAS = np.array([1e-3] * 3 + [1e-4] * 3 + [1e-5] * 3 + [100.0] * 3)


@pytest.fixture(scope="module")
def block():
    models = nb.true_models()
    theta = nb.bias()
    theta[:, 2] = 0.0  # kappa: a 200 px swath does not determine a twist (see its sigma)
    priors = [sensor_from_isd(d) for d in nb.prior_isds(models, theta)]
    return models, theta, priors


@pytest.fixture(scope="module")
def sensor_options(block, tmp_path_factory) -> list:
    """``--sensors`` options naming the prior ISDs, written once (read-only)."""
    models, theta, _ = block
    folder = tmp_path_factory.mktemp("isds")
    options = []
    for name, isd in zip(NAMES, nb.prior_isds(models, theta), strict=True):
        (folder / f"{name}.json").write_text(json.dumps(isd))
        options += ["--sensors", folder / f"{name}.json"]
    return options


def _problem(block, **network_options):
    """The adjustment problem of a synthetic network (:func:`nb.network`'s options) on
    the prior models, solving angles and rates."""
    models, _, priors = block
    network, _ = nb.network(models, **network_options)
    mapping = match_serials(network.serials(), priors, NAMES)
    problem, _, _ = build_problem(network, priors, NAMES, mapping,
                                  solve=solve_mask(["angles", "rates"]), sigmas=SIGMAS,
                                  pixel_sigma=0.1)
    return problem


def test_corrected_isd_is_the_corrected_model(block):
    models, theta, priors = block
    for model, t, prior in zip(models, theta, priors, strict=True):
        direct = CorrectedSensor(model, image_axes(model), t)
        lines = np.array([1.0, 150.0, 299.0])
        samples = np.array([10.0, 100.0, 190.0])
        ground = direct.image_to_ground(lines, samples)
        np.testing.assert_allclose(prior.image_to_ground(lines, samples), ground, atol=1e-3)
        line, sample = prior.ground_to_image(ground)
        np.testing.assert_allclose(line, lines, atol=1e-4)
        np.testing.assert_allclose(sample, samples, atol=1e-4)


def test_serials_matched_by_clock_and_explicitly(block):
    models, _, priors = block
    network, _ = nb.network(models, count=3)
    serials = network.serials()
    assert serial_clock(serials[1]) == float(serials[1].split("/")[2].split(":")[0])
    assert match_serials(serials[::-1], priors, NAMES) == {s: k for k, s in enumerate(serials)}
    assert match_serials(serials, priors, NAMES, explicit=serials[::-1]) == \
        {s: 2 - k for k, s in enumerate(serials)}
    with pytest.raises(InputError, match="matches an image"):
        match_serials(["OTHER/CAM/not-a-clock"], priors, NAMES)


def test_known_pointing_error_is_recovered_with_ground_control(block):
    _, theta, _ = block
    solution = adjust_network(_problem(block, count=40, fixed=8, noise_px=0.1))
    assert solution.initial_sigma0 > 5 * solution.sigma0  # errors of 1-3 px, noise 0.1 px
    assert 0.7 < solution.sigma0 < 1.3  # the measures' noise is their sigma
    error = solution.theta[:, :6] + theta[:, :6]
    sigma = solution.theta_sigma[:, :6]
    assert np.all(np.abs(error) < 4 * sigma)
    assert np.all(np.abs(error[:, :2]) < 0.15 * np.abs(theta[:, :2]).max())  # omega, phi


def _bundle(net, out, sensor_options, *options):
    """``demtool -q bundle --control-network net --out out …``: exit code, output lines."""
    args = ["-q", "bundle", "--control-network", net, "--out", out, *options, *sensor_options]
    result = CliRunner().invoke(cli, [str(a) for a in args])
    return result.exit_code, result.output.strip().splitlines()


def test_network_of_other_images_is_one_line_exit_1(block, sensor_options, tmp_path):
    models, _, _ = block
    network, _ = nb.network(models, count=4)
    for point in network.points:
        for m in point.measures:
            m.serial = "MRO/CTX/1234:000"
    net = write_control_network(tmp_path / "other.net", network)
    code, lines = _bundle(net, tmp_path / "b.npz", sensor_options)
    assert code == 1 and len(lines) == 1 and "matches an image" in lines[0]
    assert not (tmp_path / "b.npz").exists()


def test_measure_outside_its_image_is_one_line_exit_1(block, sensor_options, tmp_path):
    models, _, _ = block
    network, _ = nb.network(models, count=4)
    network.points[2].measures[1].line = 5000.0
    net = write_control_network(tmp_path / "out.net", network)
    code, lines = _bundle(net, tmp_path / "b.npz", sensor_options)
    assert code == 1 and len(lines) == 1 and "outside its image img1" in lines[0]


def test_time_varying_isd_writeback_keeps_other_keys():
    model = nb.true_models()[1]
    isd = isd_dict(model, center_time=100.0)
    isd["extra"] = {"kept": True}
    theta = np.zeros(12)
    theta[3] = 1e-4
    out = adjust_isd_timed(isd, image_axes(model), theta, center_time=100.0)
    assert out["extra"] == {"kept": True} and out["instrument_position"] == \
        isd["instrument_position"]
    assert out["instrument_pointing"]["quaternions"] != isd["instrument_pointing"]["quaternions"]


def test_serials_of_two_missions_match_each_by_its_own_clock(block):
    _, _, priors = block
    serials = [nb.serial(k, m) for k, m in enumerate(priors)]
    other = f"LRO/NACL/{int(serial_clock(serials[2]) - 3.2e8):010d}:123"  # another epoch
    mapping = match_serials([serials[0], serials[1], other], priors, NAMES)
    assert mapping == {serials[0]: 0, serials[1]: 1, other: 2}
    assert match_serials(["X/Y/12345:0"], priors, NAMES,
                         label_clocks=[None, "12345:0", None]) == {"X/Y/12345:0": 1}


def test_known_pointing_error_is_recovered_with_altimetry_as_ground_control(block):
    """No control points: the heights of the network's points tied to laser shots (a grid
    of tracks 10 m apart over the analytic terrain, 0.3 m noise)."""
    import dataclasses

    from demtool.bundle.network_altimetry import ShotSurface
    from demtool.io.altimetry import Shots
    from tests.helpers.linescan import R, terrain

    _, theta, _ = block
    problem = _problem(block, count=40, noise_px=0.1)
    metre = 1.0 / (R * np.radians(1.0))
    lat = np.tile(5.0 + np.linspace(-600, 600, 241) * metre, 121)
    lon = np.repeat(10.0 + np.arange(-60, 61) * 10 * metre / np.cos(np.radians(5.0)), 241)
    height = terrain(lon, lat) + np.random.default_rng(1).normal(0, 0.3, len(lon))
    shots = Shots(lon, lat, R + height, None, np.arange(len(lon)) * 0.01,
                  np.zeros(len(lon), dtype=int), "synthetic")
    surface = ShotSurface(shots, radius=R, sigma=0.3)
    solution = adjust_network(dataclasses.replace(problem, reference=surface))
    error = solution.theta[:, :6] + theta[:, :6]
    assert np.all(np.abs(error) < 3 * solution.theta_sigma[:, :6])
    assert np.all(np.abs(error[:, :2]) < 0.3 * np.abs(theta[:, :2]).max())  # omega, phi
    dh, _ = surface.residuals(solution.points)
    assert np.nanmedian(np.abs(dh)) < 1.0


def test_reference_points_of_another_body_are_one_line_exit_1(block, sensor_options,
                                                               tmp_path):
    models, _, _ = block
    network, _ = nb.network(models, count=4)
    net = write_control_network(tmp_path / "n.net", network)
    mars = tmp_path / "mars.csv"
    mars.write_text("longitude,latitude,radius_km\n10,5,3396.2\n10.001,5,3396.1\n")
    code, lines = _bundle(net, tmp_path / "b.npz", sensor_options, "--reference-points", mars)
    assert code == 1 and len(lines) == 1 and "another body" in lines[0]
    assert not (tmp_path / "b.npz").exists()
