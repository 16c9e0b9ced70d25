"""Point clouds written as LAS/LAZ (laspy) and PLY: same points, CRS, attributes."""

import laspy
import numpy as np
import pytest

from demtool.errors import ParameterError
from demtool.io.points import write_points
from tests.helpers.fuse import moon_crs


def _cloud(n=500, seed=0):
    rng = np.random.default_rng(seed)
    xyz = np.column_stack([rng.uniform(-4000, 4000, n), rng.uniform(2e5, 2.05e5, n),
                           rng.uniform(-800, 300, n)])
    return xyz, {"ray_gap": rng.uniform(0, 2, n), "brightness": rng.uniform(10, 250, n)}


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_las_on_a_body_map_reads_back_with_laspy(tmp_path, suffix):
    crs, _ = moon_crs()
    xyz, attributes = _cloud()
    path = write_points(tmp_path / f"points{suffix}", xyz, attributes, crs=crs,
                        description="test points on the Moon")
    las = laspy.read(path)
    assert las.header.version == "1.4" and las.header.point_format.id == 6
    back = np.column_stack([las.x, las.y, las.z])
    np.testing.assert_allclose(back, xyz, rtol=0, atol=0.5e-3 + 1e-9)  # 1 mm steps
    assert las.header.global_encoding.wkt
    assert las.header.parse_crs().equals(crs)
    np.testing.assert_allclose(las.ray_gap, attributes["ray_gap"], rtol=1e-6)
    np.testing.assert_allclose(las.brightness, attributes["brightness"], rtol=1e-6)
    order = np.argsort(attributes["brightness"])
    assert np.all(np.diff(las.intensity[order].astype(int)) >= 0)  # rescaled, monotonic
    assert las.intensity.max() == 65535
    assert [p.name for p in tmp_path.iterdir()] == [f"points{suffix}"]
    if suffix == ".laz":
        assert (tmp_path / "points.laz").read_bytes()[:4] == b"LASF"
        assert las.header.point_format.id == 6 and laspy.read(path).header.are_points_compressed


def test_local_frame_las_has_no_crs_and_ply_keeps_its_properties(tmp_path):
    xyz, attributes = _cloud(50)
    xyz = xyz - xyz.mean(axis=0)  # a rover's few metres
    las = laspy.read(write_points(tmp_path / "local.las", xyz, {"ray_gap": attributes["ray_gap"]},
                                  description="rover frame"))
    assert las.header.parse_crs() is None and las.header.scales[0] == 1e-3
    np.testing.assert_allclose(np.column_stack([las.x, las.y, las.z]), xyz, atol=0.5e-3)
    crs, _ = moon_crs()
    ply = write_points(tmp_path / "p.ply", xyz, attributes, crs=crs)
    header = ply.read_bytes()[:3000]
    assert b"element vertex 50" in header and b"property float ray_gap" in header
    assert b"comment crs PROJCRS" in header


def test_unknown_suffix_is_refused_before_writing(tmp_path):
    with pytest.raises(ParameterError, match=r"points\.xyz: a point cloud is written as"):
        write_points(tmp_path / "points.xyz", np.zeros((3, 3)))
    assert not list(tmp_path.iterdir())


def test_dem_refuses_an_unknown_point_format_before_reading_anything(tmp_path):
    from click.testing import CliRunner

    from demtool.cli import cli

    result = CliRunner().invoke(cli, ["dem", "--disparity", str(tmp_path / "d.tif"),
                                      "--rectify", str(tmp_path / "r.npz"), "--points-out",
                                      str(tmp_path / "p.xyz"), "--out", str(tmp_path / "dem.tif")])
    assert result.exit_code == 1
    assert "p.xyz: a point cloud is written as .ply, .las, .laz, not .xyz" in result.output
    assert "Traceback" not in result.output and not list(tmp_path.iterdir())
