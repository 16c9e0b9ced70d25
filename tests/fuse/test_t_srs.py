"""fuse --t-srs: the fused grid on any projected CRS of the DEMs' body, at the first DEM's
spacing; CRSs of another body or surface refused in one line."""

import numpy as np
from affine import Affine
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli


def plane_dem(path, x0, y0, size=60, gsd=30.0):
    """A tilted plane (h = 500 + 0.01 x − 0.02 y, UTM 31 N metres) on EPSG:32631."""
    cols, rows = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5)
    x, y = x0 + gsd * cols, y0 - gsd * rows
    heights = (500.0 + 0.01 * (x - 600000.0) - 0.02 * (y - 5000000.0)).astype(np.float32)
    dio.write_raster(path, heights, crs="EPSG:32631",
                     transform=Affine(gsd, 0.0, x0, 0.0, -gsd, y0))
    return path


def test_fuse_on_another_utm_zone(tmp_path):
    import rasterio
    from pyproj import Transformer

    a = plane_dem(tmp_path / "a.tif", 600000.0, 5001800.0)
    b = plane_dem(tmp_path / "b.tif", 600900.0, 5001200.0)
    out = tmp_path / "fused.tif"
    result = CliRunner().invoke(cli, ["-q", "fuse", str(a), str(b), "--t-srs", "EPSG:32632",
                                      "--align", "none", "--out", str(out)])
    assert result.exit_code == 0, result.output
    with rasterio.open(out) as ds:
        assert ds.crs.to_epsg() == 32632
        assert ds.transform.a == 30.0 and ds.transform.c % 30.0 == 0.0
        z = ds.read(1)
        transform = ds.transform
    rows, cols = np.nonzero(np.isfinite(z))
    assert rows.size > 3000
    x = transform.c + transform.a * (cols + 0.5)
    y = transform.f + transform.e * (rows + 0.5)
    x31, y31 = Transformer.from_crs("EPSG:32632", "EPSG:32631", always_xy=True).transform(x, y)
    want = 500.0 + 0.01 * (x31 - 600000.0) - 0.02 * (y31 - 5000000.0)
    inner = (z[rows, cols] > 0) & (np.abs(z[rows, cols] - want) < 5)
    assert inner.mean() > 0.97  # edges: bilinear against NaN borders
    np.testing.assert_allclose(z[rows, cols][inner], want[inner], atol=0.05)


def test_fuse_t_srs_of_another_body_or_surface_is_one_line(tmp_path):
    a = plane_dem(tmp_path / "a.tif", 600000.0, 5001800.0)
    for value, message in (("IAU_2015:30110", "is a CRS of Moon but the data are of Earth"),
                           ("IAU_2015:39910", "is not that of")):
        result = CliRunner().invoke(cli, ["-q", "fuse", str(a), "--t-srs", value, "--out",
                                          str(tmp_path / "f.tif")])
        assert result.exit_code == 1, result.output
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and message in lines[0], result.output
    assert not (tmp_path / "f.tif").exists()
