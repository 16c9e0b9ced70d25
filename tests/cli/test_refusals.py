"""Refusals that are true (issue 25): compare of rasters that are not heights or not in one
frame, and usage errors (exit 2, no traceback) of every stage."""

from __future__ import annotations

import numpy as np
import pytest
from affine import Affine
from click.testing import CliRunner
from rasterio.crs import CRS

from demtool import io as dio
from demtool.cli import cli
from demtool.compare.frames import check_comparable, not_heights_reason
from demtool.errors import InputError
from demtool.stages import STAGES

MOON_EQC = CRS.from_proj4("+proj=eqc +R=1737400 +units=m +no_defs")


def _invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _heights(path, *, crs=None, **tags):
    data = np.random.default_rng(0).normal(size=(32, 32)) + 100.0
    transform = Affine(10, 0, 0, 0, -10, 320) if crs is not None else \
        dio.image_frame_transform(10.0)
    dio.write_raster(path, data, transform=transform, crs=crs, tags=tags)
    return path


@pytest.mark.parametrize("case", ["image_vs_map", "local_vs_map", "disparity", "synth_view"])
def test_compare_refuses_what_has_no_meaning(tmp_path, case):
    reference = _heights(tmp_path / "ref.tif", crs=MOON_EQC)
    if case == "image_vs_map":
        dem = _heights(tmp_path / "dem.tif", frame="image:left")
        expected = "in an image's pixel frame"
    elif case == "local_vs_map":
        dem = _heights(tmp_path / "dem.tif", frame="map:local")
        expected = "in a local metric frame"
    elif case == "disparity":
        dem = _heights(tmp_path / "dem.tif", frame="image:left_rect", demtool_stage="sgm")
        expected = "a disparity map written by demtool sgm"
    else:
        dem = _heights(tmp_path / "dem.tif", frame="image:view_00", units="DN")
        expected = "units=DN"
    out = tmp_path / "report"
    result = _invoke("compare", dem, reference, "--out", out)
    assert result.exit_code == 1, result.output
    assert expected in result.output and str(dem) in result.output
    assert len(result.output.strip().splitlines()) == 1
    assert not out.exists() or not any(out.iterdir())


def test_isis_instrument_labels_are_images():
    label = '{"IsisCube": {"Core": {}, "Instrument": {"SpacecraftName": "MRO"}}}'
    assert "instrument image" in not_heights_reason({}, label)
    assert not_heights_reason({}, '{"IsisCube": {"Mapping": {}}}') is None
    assert not_heights_reason({"units": "m", "demtool_stage": "dem"}) is None


def test_frames_that_meet():
    check_comparable(("a", None, {"frame": "image:x"}), ("b", None, {"frame": "image:x"}))
    check_comparable(("a", MOON_EQC, {}), ("b", MOON_EQC, {}))
    check_comparable(("a", None, {}), ("b", MOON_EQC, {}))  # untagged: not refused here
    with pytest.raises(InputError, match="in one frame"):
        check_comparable(("a", MOON_EQC, {}), ("b", None, {"frame": "image:x"}))


@pytest.mark.parametrize("stage", list(STAGES))
def test_usage_errors_exit_2_without_traceback(stage):
    result = _invoke(stage)
    assert result.exit_code == 2, (stage, result.output)
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)


def test_mapproject_without_sensor_is_a_usage_error(tmp_path):
    image = _heights(tmp_path / "image.tif", frame="image:image")
    result = _invoke("mapproject", image, "--height", 0, "--out", tmp_path / "o.tif")
    assert result.exit_code == 2, result.output
    assert "Missing option '--sensor'" in result.output
    assert not (tmp_path / "o.tif").exists()
