"""A ``.tsai`` pinhole in a body-fixed frame (as ASP's ``cam_gen`` writes for planetary
frame cameras): ``mapproject`` puts it on the body its map CRS or DEM names, at the
image's size, and ``dem --mapprojected`` reads it back from the orthoimage's tags; with
nothing naming the body it is refused in one line (issue 46's leftover: it was refused as
"a camera in a local frame")."""

import dataclasses

import pytest
from click.testing import CliRunner

from demtool.cli import cli
from demtool.dem.inputs import read_ortho
from demtool.sensors import read_sensor
from tests.cli.test_mapproject import check_corners, ramp_images
from tests.helpers.tsai import NULL_LENS

MOON_RADIUS_M = 1737400.0
#: 100 km above the Moon at (0° E, 0° N), looking down -x; 128 x 128 px of 10 µm, f 20 mm
#: (2000 px): 50 m a pixel on the ground
TSAI = NULL_LENS.replace("cu = 5.12\ncv = 5.12", "cu = 0.64\ncv = 0.64")
MOON_MAP = "IAU_2015:30110"


@pytest.fixture
def tsai(tmp_path):
    path = tmp_path / "cam.tsai"
    path.write_text(TSAI)
    sensor = read_sensor(path, radii=(MOON_RADIUS_M, MOON_RADIUS_M))
    return path, dataclasses.replace(sensor, width=128, height=128)


def test_body_fixed_tsai_mapprojects_on_the_body_its_crs_names(tsai, tmp_path):
    path, sensor = tsai
    grid = check_corners(sensor, path, tmp_path, 0.0, args=("--t-srs", MOON_MAP))
    assert grid.gsd[0] == pytest.approx(50.0, rel=0.05)
    ortho = read_ortho(tmp_path / "lines_ortho.tif", what="left orthoimage")
    assert ortho.sensor.radii == pytest.approx((MOON_RADIUS_M, MOON_RADIUS_M))
    assert (ortho.sensor.lines, ortho.sensor.samples) == (128, 128)


def test_body_fixed_tsai_without_a_body_is_refused_in_one_line(tsai, tmp_path):
    path, sensor = tsai
    ramp, _ = ramp_images(tmp_path, sensor)
    out = tmp_path / "ortho.tif"
    result = CliRunner().invoke(cli, ["mapproject", str(ramp), "--sensor", str(path),
                                      "--height", "0", "--out", str(out)])
    assert result.exit_code == 1, result.output
    errors = [line for line in result.output.splitlines() if line.startswith("Error")]
    assert len(errors) == 1 and str(path) in errors[0] and "--t-srs" in errors[0]
    assert not out.exists()


def test_local_frame_tsai_on_a_body_is_refused_as_inside_it(tmp_path):
    """A rover's .tsai (cameras a metre from the origin) given a body: inside the body."""
    path = tmp_path / "rover.tsai"
    path.write_text(TSAI.replace("C = 1837400 0 0", "C = 0.1 0.2 -0.9"))
    sensor = dataclasses.replace(read_sensor(path), width=128, height=128)
    ramp, _ = ramp_images(tmp_path, sensor)
    out = tmp_path / "ortho.tif"
    result = CliRunner().invoke(cli, ["mapproject", str(ramp), "--sensor", str(path),
                                      "--height", "0", "--t-srs", MOON_MAP, "--out", str(out)])
    assert result.exit_code == 1, result.output
    errors = [line for line in result.output.splitlines() if line.startswith("Error")]
    assert len(errors) == 1 and str(path) in errors[0], result.output
    assert not out.exists()
