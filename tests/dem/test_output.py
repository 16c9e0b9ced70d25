"""demtool.dem.output.write_dem_rasters: the DEM, mask and error rasters written at once
on threads are the files written one after the other (byte for byte, overviews too)."""

from types import SimpleNamespace

import numpy as np
from affine import Affine

from demtool import io as dio
from demtool.dem.output import write_dem_rasters


def test_rasters_written_at_once_are_the_files_written_one_by_one(tmp_path):
    rng = np.random.default_rng(2)
    shape = (520, 560)  # above OVERVIEW_MIN_SIDE: overviews built on the threads too
    dem = rng.normal(size=shape).cumsum(axis=1)
    dem[:40] = np.nan
    filled = rng.random(shape) < 0.1
    error = np.abs(rng.normal(size=shape)).astype(np.float32)
    result = SimpleNamespace(dem=dem, filled=filled, error=error)
    run = SimpleNamespace(provenance=SimpleNamespace(
        tags=lambda **kw: {k: str(v) for k, v in kw.items()}))
    transform, crs = Affine(2.0, 0, 100.0, 0, -2.0, 500.0), "EPSG:32631"
    paths = {name: tmp_path / f"{name}.tif" for name in ("dem", "mask", "error")}
    written = write_dem_rasters(run, SimpleNamespace(mask_band=False), paths["dem"], result,
                                transform=transform, crs=crs, tags={"stage": "dem"},
                                side_tags={"body": "test"}, mask_path=paths["mask"],
                                error_path=paths["error"])
    assert written == [paths["dem"], paths["mask"], paths["error"]]
    mask = filled.astype(np.float32)
    mask[np.isnan(dem)] = np.nan
    alone = tmp_path / "alone"
    alone.mkdir()
    for name, data, tags, band in (
            ("dem", dem, {"stage": "dem"}, "height"),
            ("mask", mask, {"meaning": "1 = interpolated, 0 = measured", "body": "test"},
             "interpolated"),
            ("error", error, {"meaning": "median ray gap of the cell's points",
                              "units": "metres", "body": "test"}, "ray_gap")):
        dio.write_raster(alone / f"{name}.tif", data, transform=transform, crs=crs,
                         tags=tags, band_names=[band])
        assert paths[name].read_bytes() == (alone / f"{name}.tif").read_bytes(), name
