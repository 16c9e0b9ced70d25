"""Readers and writers on tile threads keep the other threads' warning filters
(demtool.io.quiet; issue 47's review: ``warnings.catch_warnings`` in one tile thread put
back the process's filter list on exit, dropping the filters set meanwhile elsewhere)."""

from __future__ import annotations

import threading
import warnings

import numpy as np
import pytest
import rasterio.io

from demtool import io as dio
from demtool import tiling
from demtool.io.quiet import ignoring
from demtool.refine.tiled import read_decimated


class _Sentinel(UserWarning):
    """The warning another thread ignores meanwhile."""


def _blocking(original, inside: threading.Event, release: threading.Event):
    def call(*args, **kwargs):
        if threading.current_thread() is not threading.main_thread():
            inside.set()
            assert release.wait(10)
        return original(*args, **kwargs)

    return call


@pytest.fixture()
def image_frame(tmp_path):
    """A not-georeferenced raster (the unit image frame GDAL warns about)."""
    return dio.write_raster(tmp_path / "frame.tif",
                            np.arange(64, dtype=np.float32).reshape(8, 8))


CALLS = {
    "tiling.read_window": ("read", lambda p: tiling.read_window(p, (0, 4, 0, 4))),
    "io.read_window": ("read", lambda p: dio.read_window(p, (0, 4, 0, 4))),
    "io.read_raster": ("read", lambda p: dio.read_raster(p)),
    "io.read_decimated": ("read", lambda p: dio.read_decimated(p, max_side=4)),
    "refine.tiled.read_decimated": ("read", lambda p: read_decimated(p, (8, 8), 16)),
    "io.open": ("open", lambda p: dio._open_dataset(p, "raster").close()),
    "io.write_raster": ("open", lambda p: dio.write_raster(
        p.with_name("written.tif"), np.zeros((4, 4), np.float32))),
}


@pytest.mark.parametrize("name", sorted(CALLS))
def test_a_reader_on_a_thread_keeps_the_filters_set_meanwhile(monkeypatch, image_frame,
                                                               name):
    """A thread reads (or writes) a raster; while it is inside, the main thread ignores
    another warning; that filter must still be there once the read is done."""
    patched, call = CALLS[name]
    inside, release = threading.Event(), threading.Event()
    if patched == "read":
        monkeypatch.setattr(rasterio.io.DatasetReader, "read",
                            _blocking(rasterio.io.DatasetReader.read, inside, release))
    else:
        monkeypatch.setattr(rasterio, "open", _blocking(rasterio.open, inside, release))
    errors: list[BaseException] = []

    def read() -> None:
        try:
            call(image_frame)
        except BaseException as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    with warnings.catch_warnings():  # this test's own changes end with it
        thread = threading.Thread(target=read)
        thread.start()
        try:
            assert inside.wait(10)
            warnings.simplefilter("ignore", _Sentinel)
        finally:
            release.set()
            thread.join(10)
        assert not errors, errors
        with warnings.catch_warnings(record=True) as shown:
            warnings.warn("meant to be ignored", _Sentinel, stacklevel=1)
        assert not shown, "the main thread's filter was dropped by the reader's exit"


def test_ignoring_is_shared_and_leaves_the_filters_as_they_were():
    from rasterio.errors import NotGeoreferencedWarning

    with warnings.catch_warnings():
        before = list(warnings.filters)
        with ignoring(NotGeoreferencedWarning):
            with ignoring(NotGeoreferencedWarning):  # a second holder: one entry
                assert sum(f[2] is NotGeoreferencedWarning for f in warnings.filters) \
                    == sum(f[2] is NotGeoreferencedWarning for f in before) + 1
            with warnings.catch_warnings(record=True) as shown:
                warnings.warn("x", NotGeoreferencedWarning, stacklevel=1)
            assert not shown  # still held by the first holder
        assert warnings.filters == before
        with warnings.catch_warnings(record=True) as shown:
            warnings.simplefilter("default")
            warnings.warn("y", NotGeoreferencedWarning, stacklevel=1)
        assert len(shown) == 1


def test_a_holder_after_a_swapped_list_still_ignores():
    """One holder is inside while a ``catch_warnings`` block ends (pytest's own, at a
    test's end, while a tile thread still writes): the list put back lacks the entry.  A
    later holder must put it back in force, not count itself in and stay unprotected
    (CI, issue 47: a fixture's write then raised GDAL's note as an error)."""
    from rasterio.errors import NotGeoreferencedWarning

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        outer = ignoring(NotGeoreferencedWarning)
        with warnings.catch_warnings():  # the block that ends while the holder is inside
            outer.__enter__()
        try:
            assert not any(f[2] is NotGeoreferencedWarning for f in warnings.filters)
            with ignoring(NotGeoreferencedWarning):
                warnings.warn("a unit transform", NotGeoreferencedWarning, stacklevel=1)
            # the entry put back stays while the outer holder is inside
            warnings.warn("a unit transform", NotGeoreferencedWarning, stacklevel=1)
        finally:
            outer.__exit__(None, None, None)
        with pytest.raises(NotGeoreferencedWarning):  # nothing left behind
            warnings.warn("a unit transform", NotGeoreferencedWarning, stacklevel=1)
