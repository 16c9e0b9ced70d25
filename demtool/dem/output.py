"""The rasters a triangulated DEM route writes: the DEM (with the interpolation band under
``--mask-band``), the ``--interpolated-mask`` and the ``--error-out`` ray gaps, on one grid.

Shared by the body-map routes (:func:`demtool.dem.run_sensors.write_map_dem`) and the
local-frame route (:mod:`demtool.dem.run_local`); call it inside the run's transaction.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np


def write_dem_rasters(run: Any, params: Any, out: str | os.PathLike, result: Any, *,
                      transform: Any, crs: Any, tags: dict[str, str],
                      side_tags: dict[str, Any], mask_path: str | os.PathLike | None,
                      error_path: str | os.PathLike | None) -> list[Path]:
    """Write OUT, and the mask and error rasters when asked; return the paths written.

    ``result`` carries ``dem`` (H, W) float metres (NaN = none), ``filled`` (H, W) bool
    (interpolated cells) and ``error`` (H, W) float metres (median ray gap);
    ``side_tags`` are the frame or body tags the mask and error rasters carry too.

    Two or three rasters are written at once, on threads (their compression and
    overviews are GDAL's, run outside the GIL: :mod:`demtool.io.overviews`; each thread's
    GDAL options are its own, :func:`demtool.io.layout.raster_output`): the same files as
    one after the other.
    """
    from demtool import io as dio

    prov = run.provenance
    filled = result.filled.astype(np.float32)
    filled[np.isnan(result.dem)] = np.nan
    data = np.stack([result.dem, filled]) if params.mask_band else result.dem
    band_names = ["height", "interpolated"] if params.mask_band else ["height"]
    writes = [(out, data, tags, band_names)]
    if mask_path is not None:
        writes.append((mask_path, filled, prov.tags(meaning="1 = interpolated, 0 = measured",
                                                    **side_tags), ["interpolated"]))
    if error_path is not None:
        writes.append((error_path, result.error,
                       prov.tags(meaning="median ray gap of the cell's points",
                                 units="metres", **side_tags), ["ray_gap"]))

    def write(item) -> Path:
        path, values, raster_tags, names = item
        dio.write_raster(path, values, transform=transform, crs=crs, tags=raster_tags,
                         band_names=names)
        return Path(path)

    from demtool.mapproject.threads import available_threads, ordered_map

    # (one raster: ordered_map's one thread is a plain loop on the calling thread)
    return list(ordered_map(write, writes, threads=min(len(writes), available_threads())))
