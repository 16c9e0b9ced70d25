"""The refine runner's grid matching: the image put on the DEM's grid."""

import numpy as np
import pytest
from affine import Affine

from demtool.errors import InputError
from demtool.io import Raster
from demtool.refine.inputs import image_on_dem_grid


def raster(data, transform, tags=None, path="x.tif"):
    return Raster(data=np.asarray(data, np.float32), transform=transform, crs=None,
                  tags=tags or {}, path=path)


def test_same_pixel_grid_is_used_as_is_and_frames_must_agree():
    image = raster(np.arange(12.0).reshape(3, 4), Affine(1, 0, 0, 0, -1, 0),
                   {"frame": "image:view_00"}, "view_00.tif")
    dem = raster(np.zeros((3, 4)), Affine(0.5, 0, 0, 0, -0.5, 0), {"frame": "image:view_00"})
    values, note = image_on_dem_grid(image, dem)
    assert note is None and values is image.data
    other = raster(np.zeros((3, 4)), dem.transform, {"frame": "image:view_01"}, "dem.tif")
    with pytest.raises(InputError, match="is in frame 'image:view_00' but the DEM dem.tif"):
        image_on_dem_grid(image, other)


def test_map_grids_are_resampled_bilinearly():
    rows, cols = np.mgrid[0:50, 0:60].astype(np.float64)
    image = raster(3.0 * cols + rows, Affine(0.5, 0, 0, 0, -0.5, 0))  # 0.5 m pixels
    dem = raster(np.zeros((20, 20)), Affine(1.0, 0, 2.0, 0, -1.0, -3.0))  # 1 m, shifted
    values, note = image_on_dem_grid(image, dem)
    assert values.dtype == np.float32 and "resampled onto the DEM grid 20 × 20" in note
    r, c = np.mgrid[0:20, 0:20]
    col_s = (2.0 + (c + 0.5)) / 0.5 - 0.5
    row_s = (3.0 + (r + 0.5)) / 0.5 - 0.5
    good = np.isfinite(values)
    assert good[:10, :10].all()
    np.testing.assert_allclose(values[good], (3 * col_s + row_s)[good], atol=1e-3)
    far = raster(np.zeros((10, 10)), Affine(1.0, 0, 1e5, 0, -1.0, 0))
    with pytest.raises(InputError, match="does not overlap"):
        image_on_dem_grid(image, far)
