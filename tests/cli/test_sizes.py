"""Sizes checked first (issue 31, class 3): a grid's size is stated before any work and a
grid beyond the memory budget (or the disk, or any sense) is refused naming the option
or file that made it so — mapproject --gsd / --bounds, dem --gsd, a noise raster given as
a disparity."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool import sizes
from demtool.cli import cli
from demtool.errors import ParameterError
from demtool.mapproject.checks import bounds_overlap, footprint_box
from tests.helpers.frame_scene import make_frame_scene, write_frame_scene


def _invoke(*args):
    return CliRunner().invoke(cli, ["-q", *map(str, args)])


def _one_error(result, status, *parts):
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert result.exit_code == status, result.output
    assert len(errors) == 1 and "Traceback" not in result.output, result.output
    for part in parts:
        assert part in errors[0], errors[0]


def test_check_grid_states_and_refuses(caplog):
    import logging

    log = logging.getLogger("demtool.test_sizes")
    with caplog.at_level(logging.INFO, logger="demtool.test_sizes"):
        assert sizes.check_grid((100, 200), bytes_per_cell=8, what="map DEM", option="--gsd",
                                log=log, budget=10**6) == 160_000
    assert "map DEM grid: 200 x 100 cells (156 KiB)" in caplog.text
    with pytest.raises(ParameterError, match=r"--gsd: the map DEM would be 2000 x 1000 cells "
                                             r"\(15\.3 MiB\), beyond the memory budget of "
                                             r"977 KiB"):
        sizes.check_grid((1000, 2000), bytes_per_cell=8, what="map DEM", option="--gsd",
                         budget=10**6)


def test_memory_budget_from_the_environment(monkeypatch):
    monkeypatch.setenv(sizes.BUDGET_ENV, "2GiB")
    assert sizes.memory_budget() == 2 * 1024 ** 3
    monkeypatch.setenv(sizes.BUDGET_ENV, "lots")
    with pytest.raises(ParameterError, match="DEMTOOL_MEMORY_BUDGET='lots'"):
        sizes.memory_budget()
    monkeypatch.delenv(sizes.BUDGET_ENV)
    assert 0 < sizes.memory_budget() <= max(sizes.physical_memory(), 16 * 1024 ** 3)


@pytest.mark.parametrize("bounds, overlap", [
    ((179.0, -1.0, 181.0, 1.0), True),      # across the antimeridian, 0…360 style
    ((-181.0, -1.0, -179.0, 1.0), True),    # the same ground written 360° lower
    ((170.0, -1.0, 178.0, 1.0), False),
    ((179.5, 2.0, 180.5, 3.0), False),      # right longitudes, other latitudes
    ((179.9, -1.0, -179.9, 1.0), True),     # a box across 180 as LON_MAX < LON_MIN
    ((0.0, -90.0, 360.0, 90.0), True)])
def test_bounds_against_a_footprint_across_the_antimeridian(bounds, overlap):
    box = footprint_box([179.8, -179.8, -179.8, 179.8], [-0.5, -0.5, 0.5, 0.5])
    assert box == pytest.approx((179.8, -0.5, 180.2, 0.5))
    assert bounds_overlap(bounds, box) == overlap


@pytest.fixture(scope="module")
def frame_files(tmp_path_factory):
    scene = make_frame_scene(size=160, seed=7)
    return write_frame_scene(scene, tmp_path_factory.mktemp("sizes_scene"))


@pytest.mark.parametrize("args, status, parts", [
    (["--gsd", "1e-5"], 1, ["--gsd: the orthoimage would be", "cells per pixel"]),
    (["--bounds", "100", "10", "101", "11"], 1,
     ["--bounds: lon 100…101, lat 10…11 does not overlap the image's footprint"]),
    (["--bounds", "10", "-100", "11", "10"], 2,
     ["'--bounds'", "latitudes within +-90"])])
def test_mapproject_grid_checked_first(frame_files, tmp_path, args, status, parts):
    out = tmp_path / "ortho.tif"
    result = _invoke("mapproject", frame_files["left"], "--sensor", frame_files["left_isd"],
                     "--height", "0", "--out", out, *args)
    _one_error(result, status, *parts)
    assert list(tmp_path.iterdir()) == []


def test_mapproject_out_is_a_folder_is_a_file_problem(frame_files, tmp_path):
    result = _invoke("mapproject", frame_files["left"], "--sensor", frame_files["left_isd"],
                     "--height", "0", "--out", tmp_path)
    _one_error(result, 1, "--out is a folder, expected a file name")


@pytest.mark.slow
def test_dem_grid_checked_before_gridding(frame_files, tmp_path, monkeypatch):
    monkeypatch.setenv(sizes.BUDGET_ENV, "1GiB")
    rect = tmp_path / "rect"
    run = _invoke("rectify", frame_files["left"], frame_files["right"], "--sensor-left",
                  frame_files["left_isd"], "--sensor-right", frame_files["right_isd"],
                  "--out", rect)
    assert run.exit_code == 0, run.output
    data = dio.read_npz(rect / "rectify.npz", "rectification")
    width, height = (int(v) for v in data["size_rect"])
    flat = tmp_path / "flat.tif"
    dio.write_raster(flat, np.zeros((height, width), np.float32))
    out = tmp_path / "dem.tif"
    result = _invoke("dem", "--disparity", flat, "--rectify", rect / "rectify.npz", "--gsd",
                     "1e-4", "--out", out)
    _one_error(result, 1, "--gsd: the map DEM would be", "beyond the memory budget of 1 GiB")
    noise = tmp_path / "noise.tif"
    rng = np.random.default_rng(0)
    dio.write_raster(noise, rng.integers(0, 65535, (height, width)).astype(np.float32))
    result = _invoke("dem", "--disparity", noise, "--rectify", rect / "rectify.npz", "--out",
                     out)
    assert result.exit_code == 1, result.output
    assert str(noise) in result.output and "Traceback" not in result.output
    assert not out.exists()


def test_free_memory_goes_back_to_the_system_on_glibc():
    """malloc_trim where the C library is glibc; elsewhere nothing, and False."""
    import platform

    blocks = [np.ones(50_000) for _ in range(200)]  # 80 MB of small heap blocks
    del blocks
    assert sizes.release_free_memory() is (platform.libc_ver()[0] == "glibc")
