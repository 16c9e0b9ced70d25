"""run_rectify: nodata in its outputs is NaN, never ±inf (the file contract)."""

import numpy as np
import rasterio

from demtool import io as dio


def test_rectified_images_carry_nan_never_inf(stereo_scene, tmp_path, monkeypatch):
    import demtool.rectify.core as core
    from demtool.rectify.run import run_rectify

    warp = core.warp_to_rectified

    def warp_with_inf(image, H, size):  # what an overflowing warp would give
        out = warp(image, H, size)
        out[:3, :5] = np.inf
        out[-2:, -4:] = -np.inf
        return out

    monkeypatch.setattr(core, "warp_to_rectified", warp_with_inf)
    dio.write_raster(tmp_path / "view_00.tif", stereo_scene.left)
    dio.write_raster(tmp_path / "view_01.tif", stereo_scene.right)
    run_rectify(tmp_path / "view_00.tif", tmp_path / "view_01.tif", tmp_path / "out")
    for name in ("left_rect.tif", "right_rect.tif"):
        with rasterio.open(tmp_path / "out" / name) as dataset:  # raw: io would mask inf
            data = dataset.read(1)
        assert not np.isinf(data).any()
        assert np.isnan(data[:3, :5]).all() and np.isnan(data[-2:, -4:]).all()
        assert np.isfinite(data).mean() > 0.5
