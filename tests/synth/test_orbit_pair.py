"""The later-orbit partner of a line-scan ISD (demtool.synth.orbit_pair)."""

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest

from demtool.errors import InputError
from demtool.sensors.isd import sensor_from_isd
from demtool.synth.orbit_pair import later_orbit_isd
from tests.helpers.linescan import isd_dict, linescan_sensor

SHARED = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"
NAC = SHARED / "altimetry" / "lola_nac_pair" / "lidarObservationImage1.isd"


def _check(isd: dict, convergence: float, site: tuple[float, float]) -> None:
    """The site projects to the same pixel of both views, which converge as asked."""
    original = copy.deepcopy(isd)
    pair = later_orbit_isd(isd, convergence_deg=convergence, site_line=site[0],
                           site_sample=site[1])
    assert isd == original  # input not modified
    first, second = sensor_from_isd(isd), sensor_from_isd(pair.isd)
    assert (second.lines, second.samples) == (first.lines, first.samples)
    xyz = pair.site_body_m[None]
    for model in (first, second):
        line, sample = model.ground_to_image(xyz)
        assert abs(line[0] - site[0]) < 0.05 and abs(sample[0] - site[1]) < 0.05
    # convergence at the site, from the two models' positions when they see it
    line = np.array([site[0]])
    c1 = first.position_at(first.line_time(line))[0] - pair.site_body_m
    c2 = second.position_at(second.line_time(line))[0] - pair.site_body_m
    angle = math.degrees(math.acos(c1 @ c2 / np.linalg.norm(c1) / np.linalg.norm(c2)))
    assert angle == pytest.approx(convergence, abs=0.05)
    assert pair.convergence_deg == pytest.approx(convergence, abs=1e-6)
    assert pair.roll_axis_from_along_track_deg < 1.0  # a roll
    quats = np.asarray(pair.isd["instrument_pointing"]["quaternions"])
    np.testing.assert_allclose(np.linalg.norm(quats, axis=1), 1.0, atol=1e-12)


def test_synthetic_line_scanner_seen_from_a_neighbouring_orbit():
    isd = isd_dict(linescan_sensor(lines=400, samples=300, roll_deg=3.0))
    _check(isd, 20.0, (200.0, 150.0))
    _check(isd, 25.0, (120.5, 60.0))


def test_refusals():
    isd = isd_dict(linescan_sensor(lines=40, samples=30))
    with pytest.raises(InputError, match=r"x\.json: convergence 75\.0° is outside"):
        later_orbit_isd(isd, convergence_deg=75.0, source="x.json")
    frame = dict(isd, name_model="USGS_ASTRO_FRAME_SENSOR_MODEL")
    with pytest.raises(InputError, match="line-scan ISDs, not 'USGS_ASTRO_FRAME"):
        later_orbit_isd(frame, convergence_deg=20.0)


@pytest.mark.skipif(not NAC.is_file(), reason="../shared/data (LRO NAC ISD) absent")
def test_real_nac_isd_in_j2000():
    """A real ALE ISD: J2000 positions in km, a body rotation, a constant rotation."""
    _check(json.loads(NAC.read_text()), 20.0, (26112.0, 2532.0))
