"""A tiled sgm on two orthoimages writes its disparity on their map grid (CRS included),
as the untiled run does, so ``dem --mapprojected`` takes it (issue 47's NAC route)."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio
from affine import Affine
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from demtool.mapproject.surface import SENSOR_TAG


@pytest.mark.slow
def test_tiled_disparity_keeps_the_orthoimages_crs(tmp_path):
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(3)
    texture = (500 + 40 * gaussian_filter(rng.normal(size=(96, 140)), 1.5)).astype(np.float32)
    transform = Affine(0.5, 0.0, 1000.0, 0.0, -0.5, 2000.0)
    crs = rasterio.crs.CRS.from_epsg(32631)
    for name, image in (("left", texture[:, 3:131]), ("right", texture[:, 8:136])):
        dio.write_raster(tmp_path / f"{name}.tif", np.ascontiguousarray(image),
                         transform=transform, crs=crs, tags={SENSOR_TAG: f"{name}.json"})
    for label, options in (("untiled", []), ("tiled", ["--tile-size", "64", "--workers", "1"])):
        out = tmp_path / f"{label}.tif"
        result = CliRunner().invoke(cli, ["-q", "sgm", str(tmp_path / "left.tif"),
                                          str(tmp_path / "right.tif"), "--out", str(out),
                                          "--min-disparity", "0", "--num-disparities", "16",
                                          "--cost", "census", *options])
        assert result.exit_code == 0, result.output
        with rasterio.open(out) as src:
            assert src.crs == crs, label
            assert src.transform == transform, label
            disparity = src.read(1)
        assert abs(np.nanmedian(disparity[8:-8, 24:-8]) - 5.0) < 0.25, label
