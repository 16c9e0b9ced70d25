"""A pair of sensor models at one place (one model given twice) is refused before any
triangulation (issue 31: a zero-baseline pair is refused)."""

import pytest

from demtool.dem.run_sensors import _check_baseline
from demtool.errors import ProcessingError
from demtool.sensors import read_sensor
from tests.helpers.camera_isd import nadir_isd, write_isd

CAMERA = dict(focal_mm=50.0, pitch_mm=0.01, lines=64, samples=64)


def test_zero_baseline_is_refused_and_a_real_pair_passes(tmp_path):
    left = read_sensor(write_isd(tmp_path / "left.json", nadir_isd(10.0, 5.0, 50e3, **CAMERA)))
    right = read_sensor(write_isd(tmp_path / "right.json",
                                  nadir_isd(10.2, 5.0, 50e3, **CAMERA)))  # 6 km east
    _check_baseline(left, right, "d.tif")
    with pytest.raises(ProcessingError, match=r"d\.tif: the two sensor models stand at one "
                                              r"place \(baseline 0 m for a range of 50 km\)"):
        _check_baseline(left, left, "d.tif")
