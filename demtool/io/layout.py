"""How demtool lays out the GeoTIFFs it writes: tiled with internal overviews, or COG.

Every raster a stage writes goes through :func:`raster_output` (from
:func:`demtool.io.write_raster`, :func:`demtool.io.raster_writer` and
:func:`demtool.tiling.write_tiled_raster`), so every stage's rasters open in GIS tools
the same way:

* **Tiled** GeoTIFF (256 × 256 blocks when both sides reach a block), as before.
* **Internal overviews** (reduced-resolution copies inside the file, GDAL's
  ``BuildOverviews``, what ``gdaladdo`` writes; built on the closed file outside
  Python's GIL, :mod:`demtool.io.overviews`) when the larger side exceeds
  :data:`OVERVIEW_MIN_SIDE` pixels: factors 2, 4, 8, … until the smallest overview
  fits in one block, as ``gdaladdo`` chooses levels when given none (GDAL ≥ 3.2).  QGIS
  and any GDAL reader then draw a zoomed-out view of a 20 000² DEM from a few blocks.
  Smaller rasters get none: they are read whole in a blink, and their bytes stay as
  they were.
* **Overview resampling for the data**: ``average`` (heights, disparities, images,
  errors: the mean of the valid cells beneath, NaN nodata excluded), ``nearest`` for
  categorical bands — masks, counts and class labels (:data:`CATEGORICAL_BANDS`, by
  band name, or ``resampling=`` explicitly) — whose averages would be values no cell
  holds (a 0.5 "interpolated" flag, a class 2.5).
* **Cloud Optimized GeoTIFF** with ``demtool --cog STAGE …`` (:func:`raster_layout`):
  the file is written as above, then copied by GDAL's COG driver (overviews with the
  same resampling, DEFLATE with the floating-point predictor, 512-px blocks, the
  image data after the header and the overviews — readable block by block over HTTP
  range requests).  Tags and band descriptions travel with the copy.

References: GDAL GTiff driver and ``gdaladdo`` (https://gdal.org/programs/gdaladdo.html),
GDAL COG driver (https://gdal.org/drivers/raster/cog.html).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Mapping, Sequence
from contextvars import ContextVar
from pathlib import Path
from typing import Any

__all__ = ["CATEGORICAL_BANDS", "COMPRESSION_CONFIG", "LAYOUTS", "OVERVIEW_MIN_SIDE",
           "THREADED_COMPRESSION_PIXELS", "current_layout", "overview_factors",
           "overview_resampling", "raster_layout", "raster_output"]

#: Raster layouts: ``gtiff`` (tiled GeoTIFF, internal overviews above a size) or ``cog``.
LAYOUTS = ("gtiff", "cog")
#: Block side of tiled GeoTIFFs, pixels.
BLOCK = 256
#: Rasters whose larger side is at most this many pixels get no overviews.
OVERVIEW_MIN_SIDE = 512
#: Band names (``band_names=`` of the writers) whose overviews take the nearest value.
CATEGORICAL_BANDS = frozenset({"interpolated", "mask", "count", "class", "label"})
#: GDAL's COG creation options (https://gdal.org/drivers/raster/cog.html).
COG_OPTIONS = {"compress": "DEFLATE", "level": 1, "predictor": "YES", "blocksize": 512,
               "overviews": "IGNORE_EXISTING", "bigtiff": "IF_SAFER",
               "num_threads": "ALL_CPUS"}
#: GDAL configuration while building internal overviews: every core, and the DEFLATE or
#: ZSTD level and the predictor of the full-resolution data.  The overviews are built on
#: the closed file (:mod:`demtool.io.overviews`), which no longer knows the levels it was
#: created with: GDAL's defaults would be DEFLATE level 6, ZSTD level 9 (2.7x the CPU of
#: level 1 for 1 % fewer bytes on an 8192² orthoimage) and no predictor.
OVERVIEW_CONFIG = {"GDAL_NUM_THREADS": "ALL_CPUS", "ZLEVEL_OVERVIEW": 1,
                   "ZSTD_LEVEL_OVERVIEW": 1, "PREDICTOR_OVERVIEW": 3}

#: Rasters of at least this many pixels are compressed on every core: GDAL's GTiff driver
#: reads ``GDAL_NUM_THREADS`` (the default of its ``NUM_THREADS`` creation option) when the
#: dataset is created, and then compresses its blocks and builds its overviews on worker
#: threads instead of the writing thread, with the same bytes (on a 12 545 × 5 097 LRO NAC
#: orthoimage the writing thread's work after the last tile fell from 2.5 to 0.7 s; a
#: 2094 × 1997 float32 DEM 0.45 → 0.30 s wall at the same CPU, on 2 cores).  Below it the
#: worker threads' start and hand-over cost CPU for little wall: at 1 Mpx 0.10 → 0.075 s
#: wall for +0.015 CPU s, at 512² nothing (the demo's rasters, where CPU is what counts).
THREADED_COMPRESSION_PIXELS = 2 * 1024 * 1024
#: GDAL's configuration while a large raster is created (:data:`THREADED_COMPRESSION_PIXELS`).
COMPRESSION_CONFIG = {"GDAL_NUM_THREADS": "ALL_CPUS"}

_LAYOUT: ContextVar[str] = ContextVar("demtool_raster_layout", default="gtiff")


@contextlib.contextmanager
def raster_layout(layout: str) -> Iterator[None]:
    """Write every raster inside the block in ``layout`` (one of :data:`LAYOUTS`).

    ``demtool --cog`` enters ``raster_layout("cog")`` for the stage it runs.
    """
    if layout not in LAYOUTS:
        raise ValueError(f"unknown raster layout {layout!r}: should be one of "
                         + ", ".join(LAYOUTS))
    token = _LAYOUT.set(layout)
    try:
        yield
    finally:
        _LAYOUT.reset(token)


def current_layout() -> str:
    """The layout rasters are written in now (``gtiff`` unless :func:`raster_layout`)."""
    return _LAYOUT.get()


def overview_factors(height: int, width: int, *, min_side: int | None = None,
                     block: int = BLOCK) -> list[int]:
    """Decimation factors of a raster's internal overviews (empty for small rasters).

    Parameters
    ----------
    height, width : int
        Raster size, pixels.
    min_side : int, optional
        No overviews when ``max(height, width) <= min_side`` (default
        :data:`OVERVIEW_MIN_SIDE`).
    block : int
        The levels go on until the smallest overview's larger side is at most a block.

    Returns
    -------
    list of int
        ``[2, 4, …, 2**k]`` with ``ceil(max(height, width) / 2**k) <= block``.
    """
    side = max(int(height), int(width))
    if side <= (OVERVIEW_MIN_SIDE if min_side is None else min_side):
        return []
    factors = [2]
    while -(-side // factors[-1]) > block:
        factors.append(factors[-1] * 2)
    return factors


def overview_resampling(band_names: Sequence[str] | None) -> str:
    """``nearest`` when every named band is categorical (:data:`CATEGORICAL_BANDS`), else
    ``average``."""
    names = [str(n).lower() for n in band_names or []]
    if names and all(n in CATEGORICAL_BANDS for n in names):
        return "nearest"
    return "average"


def _build_overviews_in_place(dataset: Any, factors: list[int], resampling: str) -> None:
    """rasterio's build on the open dataset (under the GIL): where GDAL's C API is not
    reachable (:func:`demtool.io.overviews.gdal_c_api`)."""
    import rasterio
    from rasterio.enums import Resampling

    with rasterio.Env(**OVERVIEW_CONFIG):
        dataset.build_overviews(factors, Resampling[resampling])


def _compression_threads(profile: Mapping[str, Any]) -> contextlib.AbstractContextManager:
    """:data:`COMPRESSION_CONFIG` for a raster of at least
    :data:`THREADED_COMPRESSION_PIXELS` pixels (a no-op below)."""
    import rasterio

    pixels = int(profile.get("width", 0)) * int(profile.get("height", 0))
    if pixels < THREADED_COMPRESSION_PIXELS:
        return contextlib.nullcontext()
    return rasterio.Env(**COMPRESSION_CONFIG)


def _copy_as_cog(source: Path, target: Path, resampling: str) -> None:
    from rasterio.shutil import copy

    copy(str(source), str(target), driver="COG", overview_resampling=resampling.upper(),
         **COG_OPTIONS)


@contextlib.contextmanager
def raster_output(path: str | os.PathLike, profile: Mapping[str, Any], *,
                  band_names: Sequence[str] | None = None,
                  tags: Mapping[str, str] | None = None,
                  resampling: str | None = None) -> Iterator[Any]:
    """Open a GeoTIFF for writing; lay it out and move it into place when the block ends.

    Yields the rasterio dataset (mode ``w``) of a temporary file beside ``path``
    (:func:`demtool.outputs.atomic_path`); the caller writes the pixels.  When the block
    succeeds, the tags and band descriptions are set, the overviews built and, in the
    ``cog`` layout, the file copied through GDAL's COG driver; then it is moved into
    place (inside an output transaction: at its end).  GDAL's write errors (disk full)
    become one :class:`demtool.errors.OutputError` line naming ``path``; nothing is left
    behind.

    Parameters
    ----------
    path : path-like
        The final file name.
    profile : mapping
        rasterio's creation profile (driver GTiff).
    band_names : sequence of str, optional
        Band descriptions; they choose the overviews' resampling unless ``resampling``.
    tags : mapping of str to str, optional
        Dataset tags.
    resampling : {"average", "nearest", ...}, optional
        The overviews' resampling (rasterio's ``Resampling`` names); default
        :func:`overview_resampling` of ``band_names``.
    """
    import rasterio
    from rasterio._err import CPLE_BaseError
    from rasterio.errors import NotGeoreferencedWarning, RasterioError

    from demtool.io.overviews import build_overviews_of_file, gdal_c_api
    from demtool.io.quiet import ignoring
    from demtool.outputs import atomic_path, write_error

    method = resampling or overview_resampling(band_names)
    cog = current_layout() == "cog"
    # A unit image-frame transform is "not georeferenced" to GDAL; that is intended.
    # (demtool.io.quiet, not catch_warnings: a streamed output is written while tiles
    # read on other threads)
    with atomic_path(path, suffix=".tif") as temporary, ignoring(NotGeoreferencedWarning):
        stage = temporary.with_name(temporary.name + ".gtiff.tif") if cog else temporary
        try:
            with _compression_threads(profile):  # read when the file is created
                dst = rasterio.open(stage, "w", **profile)
            with dst:
                yield dst
                if tags:
                    dst.update_tags(**tags)
                for index, name in enumerate(band_names or [], start=1):
                    dst.set_band_description(index, name)
                factors = [] if cog else overview_factors(dst.height, dst.width)
                # on the closed file, outside the GIL (demtool.io.overviews): the same bytes
                outside_gil = bool(factors) and gdal_c_api() is not None
                if factors:
                    dst.update_tags(ns="rio_overview", resampling=method)
                    if not outside_gil:
                        _build_overviews_in_place(dst, factors, method)
            if outside_gil:
                with rasterio.Env(**OVERVIEW_CONFIG):
                    build_overviews_of_file(stage, factors, method)
            if cog:
                _copy_as_cog(stage, temporary, method)
        except (RasterioError, CPLE_BaseError) as exc:  # GDAL's write errors (disk full)
            raise write_error(path, exc) from None
        finally:
            if cog:
                with contextlib.suppress(OSError):
                    stage.unlink()
