"""The rectified pair is read in two threads (:func:`demtool.io.read_raster_pair`)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from PIL import Image

from demtool import io as dio
from demtool.errors import InputError


def test_the_pair_reads_as_two_reads_do_without_warnings(tmp_path):
    rng = np.random.default_rng(0)
    first = rng.normal(size=(40, 30)).astype(np.float32)
    first[3, 4] = np.nan
    dio.write_raster(tmp_path / "a.tif", first)
    second = rng.integers(0, 255, size=(40, 30)).astype(np.uint8)
    Image.fromarray(second).save(tmp_path / "b.png")  # not georeferenced
    before = list(warnings.filters)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        left, right = dio.read_raster_pair(tmp_path / "a.tif", tmp_path / "b.png")
    assert list(warnings.filters) == before
    assert np.array_equal(left.data, first, equal_nan=True)
    assert np.array_equal(right.data, second.astype(np.float32))
    alone = dio.read_raster(tmp_path / "b.png")
    assert right.transform == alone.transform and right.tags == alone.tags


@pytest.mark.parametrize("missing", ["first", "both"])
def test_an_error_names_the_first_file_that_fails(tmp_path, missing):
    dio.write_raster(tmp_path / "ok.tif", np.ones((8, 8), dtype=np.float32))
    first = tmp_path / "nothing_1.tif"
    second = tmp_path / ("nothing_2.tif" if missing == "both" else "ok.tif")
    with pytest.raises(InputError, match="nothing_1.tif.*left image"):
        dio.read_raster_pair(first, second, what=("left image", "right image"))
    with pytest.raises(InputError, match="nothing_1.tif.*right image"):
        dio.read_raster_pair(tmp_path / "ok.tif", first, what=("left image", "right image"))


def test_numba_starts_in_a_thread_that_ends(monkeypatch):
    import threading

    from demtool.sgm.run import start_numba

    raised = []
    monkeypatch.setattr(threading, "excepthook", raised.append)
    loading = start_numba()
    loading.join(timeout=120)
    assert not loading.is_alive() and raised == []
