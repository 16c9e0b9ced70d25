"""Internal overviews built by GDAL outside Python's GIL.

rasterio's ``DatasetWriter.build_overviews`` calls GDAL's ``GDALBuildOverviews`` while
holding the GIL: for the whole build (0.4–0.7 s for a 4096² float32 raster, ~1.6 s at
8192²) no other Python thread runs.  A raster written on a side thread (``compare``'s
difference beside its figures, ``dem``'s and ``fuse``'s outputs written at once) then
stops the calling thread's work until its overviews are done.

:func:`build_overviews_of_file` builds them on the closed file through GDAL's C API
(``GDALOpenEx`` in update mode, ``GDALBuildOverviews``, ``GDALClose``) called with
:mod:`ctypes`, which releases the GIL during each call.  The functions are looked up
through rasterio's own extension module, so they are the GDAL that rasterio loaded (one
library, its drivers, its configuration options: ``rasterio.Env`` around the call
applies).  The file's bytes are those of rasterio's in-place build on the open dataset
(tests/io/test_overviews.py).  Where the lookup fails (a platform whose loader does not
resolve a library's dependencies through its handle, e.g. Windows), :func:`gdal_c_api`
is None and :mod:`demtool.io.layout` builds in place with rasterio as before.

References: GDAL C API, ``GDALBuildOverviews`` and ``GDALOpenEx``
(https://gdal.org/api/raster_c_api.html); :mod:`ctypes` (foreign calls of a ``CDLL``
release the GIL).
"""

from __future__ import annotations

import ctypes
import functools
import os
from collections.abc import Sequence
from typing import Any

__all__ = ["build_overviews_of_file", "gdal_c_api"]

#: ``GDALOpenEx`` flags (gdal.h): raster datasets, in update mode, errors reported.
_GDAL_OF_UPDATE = 0x01
_GDAL_OF_RASTER = 0x02
_GDAL_OF_VERBOSE_ERROR = 0x40
#: ``CPLErr`` (cpl_error.h): CE_None, CE_Debug, CE_Warning, below CE_Failure.
_CE_FAILURE = 3
#: ``GDALClose`` returns a ``CPLErr`` since GDAL 3.7 (void before).
_CLOSE_RETURNS_ERROR = 3070000


@functools.lru_cache(maxsize=1)
def gdal_c_api() -> Any | None:
    """rasterio's GDAL as a :class:`ctypes.CDLL` with the few functions used here typed,
    or None when they cannot be found that way."""
    try:
        import rasterio._base

        library = ctypes.CDLL(rasterio._base.__file__)
        library.GDALOpenEx.restype = ctypes.c_void_p
        library.GDALOpenEx.argtypes = [ctypes.c_char_p, ctypes.c_uint, ctypes.c_void_p,
                                       ctypes.c_void_p, ctypes.c_void_p]
        library.GDALBuildOverviews.restype = ctypes.c_int
        library.GDALBuildOverviews.argtypes = [
            ctypes.c_void_p, ctypes.c_char_p, ctypes.c_int, ctypes.POINTER(ctypes.c_int),
            ctypes.c_int, ctypes.POINTER(ctypes.c_int), ctypes.c_void_p, ctypes.c_void_p]
        library.GDALVersionInfo.restype = ctypes.c_char_p
        library.GDALVersionInfo.argtypes = [ctypes.c_char_p]
        library.CPLGetLastErrorMsg.restype = ctypes.c_char_p
        library.CPLGetLastErrorMsg.argtypes = []
        library.CPLErrorReset.restype = None
        library.CPLErrorReset.argtypes = []
        version = int(library.GDALVersionInfo(b"VERSION_NUM"))
        library.GDALClose.restype = (ctypes.c_int if version >= _CLOSE_RETURNS_ERROR
                                     else None)
        library.GDALClose.argtypes = [ctypes.c_void_p]
    except (OSError, AttributeError, ImportError, ValueError):
        return None
    return library


def build_overviews_of_file(path: str | os.PathLike, factors: Sequence[int],
                            resampling: str) -> None:
    """Add internal overviews to the closed raster ``path``, outside the GIL.

    Parameters
    ----------
    path : path-like
        A GeoTIFF no dataset holds open for writing.
    factors : sequence of int
        Decimation factors (:func:`demtool.io.layout.overview_factors`).
    resampling : str
        GDAL's overview resampling name (``average``, ``nearest``, …).

    Raises
    ------
    RuntimeError
        :func:`gdal_c_api` is None (call rasterio's in-place build instead).
    rasterio.errors.RasterioError
        GDAL could not open the file or write the overviews (a full disk): GDAL's
        message.
    """
    from rasterio.errors import RasterioError

    library = gdal_c_api()
    if library is None:
        raise RuntimeError("GDAL's C API is not reachable through rasterio here")
    library.CPLErrorReset()
    handle = library.GDALOpenEx(os.fsencode(path),
                                _GDAL_OF_RASTER | _GDAL_OF_UPDATE | _GDAL_OF_VERBOSE_ERROR,
                                None, None, None)
    if not handle:
        raise RasterioError(_last_error(library, f"cannot reopen {path} to add overviews"))
    levels = (ctypes.c_int * len(factors))(*[int(f) for f in factors])
    failed = None
    try:
        if library.GDALBuildOverviews(handle, resampling.upper().encode(), len(levels),
                                      levels, 0, None, None, None) >= _CE_FAILURE:
            failed = _last_error(library, "building the overviews failed")
    finally:
        closed = library.GDALClose(handle)  # writes the overviews' directories
    if failed is None and closed is not None and closed >= _CE_FAILURE:
        failed = _last_error(library, "writing the overviews failed")
    if failed is not None:
        raise RasterioError(failed)


def _last_error(library: Any, fallback: str) -> str:
    message = library.CPLGetLastErrorMsg()
    text = message.decode("utf-8", "replace").strip() if message else ""
    return text or fallback
