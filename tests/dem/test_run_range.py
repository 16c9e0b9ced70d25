"""dem accepts the disparities sgm searched and found (one range through the chain)."""

from __future__ import annotations

import logging

import numpy as np

from demtool import io as dio
from demtool.dem.inputs import read_disparity, searched_range


def _write(path, data, **tags):
    dio.write_raster(path, data.astype(np.float32), transform=dio.image_frame_transform(1.0),
                     tags={"frame": "image:left_rect", **tags})


def test_widened_disparities_are_kept(tmp_path):
    rng = np.random.default_rng(0)
    data = rng.uniform(0.0, 10.0, (40, 50))
    data[:, 20:] = rng.uniform(40.0, 50.0, (40, 30))  # found after widening to 0 … 59
    rectification = {"disparity_range": np.array([0.0, 10.0])}
    log = logging.getLogger("test")
    _write(tmp_path / "widened.tif", data, min_disparity=0, num_disparities=60)
    kept = read_disparity(tmp_path / "widened.tif", "rectify.npz", rectification, (50, 40), log)
    assert np.isfinite(kept.data).all()
    # without sgm's tags the rectification's range alone rules: the far values are masked
    _write(tmp_path / "bare.tif", np.where(np.arange(50) < 30, data, np.nan))
    masked = read_disparity(tmp_path / "bare.tif", "rectify.npz", rectification, (50, 40), log)
    assert not np.isfinite(masked.data[:, 20:30]).any()
    assert np.isfinite(masked.data[:, :20]).all()


def test_searched_range_reads_sgm_tags():
    assert searched_range({"min_disparity": "-5", "num_disparities": "11"}) == (-5.0, 5.0)
    assert searched_range({}) is None
    assert searched_range({"min_disparity": "x", "num_disparities": "3"}) is None
