"""``dem --points-out``: the triangulated points as a cloud (PLY, LAS or LAZ).

The points are the ones the DEM was gridded from (after the behind-camera and ray-gap
tests).  On a body's map they are written in the DEM's own CRS — map x, y (metres) and
the height above the reference sphere — so PDAL, CloudCompare or QGIS put them on the
DEM; in a local frame (models without a body) in the models' frame, without CRS.
Per point: ``ray_gap`` (metres, the distance between the two rays at closest approach)
and, when the rectified left image ``left_rect.tif`` lies beside ``rectify.npz`` (where
``rectify`` writes it), ``brightness`` (its value at the point's pixel); LAS also
fills its standard ``intensity`` from it (:mod:`demtool.io.points`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["local_points", "map_points", "rectified_brightness"]

#: The rectified left image ``rectify`` writes beside ``rectify.npz``.
LEFT_RECT = "left_rect.tif"


def rectified_brightness(rectify_path: str | os.PathLike, rows: np.ndarray, cols: np.ndarray,
                         log: Any) -> np.ndarray | None:
    """The rectified left image's values at disparity pixels (rows, cols), or None (one
    log line) when no ``left_rect.tif`` of that canvas lies beside ``rectify_path``."""
    from demtool import io as dio

    path = Path(rectify_path).with_name(LEFT_RECT)
    if not path.is_file():
        log.info("--points-out: no %s beside %s: the points carry no brightness", LEFT_RECT,
                 rectify_path)
        return None
    image = dio.read_raster(path, what="rectified left image").data
    if rows.size and (rows.max() >= image.shape[0] or cols.max() >= image.shape[1]):
        log.warning("--points-out: %s (%d×%d px) is not the disparity's canvas: the points "
                    "carry no brightness", path, image.shape[1], image.shape[0])
        return None
    return image[rows, cols].astype(np.float32)


def map_points(result: Any, brightness: np.ndarray | None, *, source: str) -> dict[str, Any]:
    """The keyword arguments of :func:`demtool.io.points.write_points` for the points of
    a :class:`demtool.dem.sensors.MapDem` (``brightness``: per correspondence, indexed
    by ``result.point_index``)."""
    attributes = {"ray_gap": result.point_gaps}
    if brightness is not None:
        attributes["brightness"] = brightness[result.point_index]
    return {"xyz": result.points, "attributes": attributes, "crs": result.grid.crs,
            "description": f"demtool dem: triangulated points of {source}: map x, y (m, "
                           "the DEM's CRS), height above the reference sphere (m)",
            "descriptions": _DESCRIPTIONS}


def local_points(xyz: np.ndarray, gap: np.ndarray, brightness: np.ndarray | None, *,
                 source: str) -> dict[str, Any]:
    """The keyword arguments of :func:`demtool.io.points.write_points` for points in a
    local frame (no CRS)."""
    attributes = {"ray_gap": gap}
    if brightness is not None:
        attributes["brightness"] = brightness
    return {"xyz": xyz, "attributes": attributes, "crs": None,
            "description": f"demtool dem: triangulated points, metres, in the frame of the "
                           f"models of {source} (local frame, no CRS)",
            "descriptions": _DESCRIPTIONS}


_DESCRIPTIONS = {"ray_gap": "ray gap at closest approach, m",
                 "brightness": "left image value at the pixel"}
