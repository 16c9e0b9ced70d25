"""Point clouds: PLY, and LAS/LAZ (ASPRS LAS 1.4) for PDAL, CloudCompare, QGIS and ASP.

:func:`write_points` picks the format from the file name: ``.ply`` (binary PLY,
:func:`demtool.io.write_ply`), ``.las`` or ``.laz`` (LAS 1.4, point format 6, written
with laspy; ``.laz`` compressed by LASzip through lazrs).  The point-cloud tools of the
field (PDAL, CloudCompare, ASP's ``point2las``) exchange LAS/LAZ.

LAS layout (ASPRS LAS 1.4 R15, https://www.asprs.org/wp-content/uploads/2019/07/LAS_1_4_r15.pdf):

* X, Y, Z are scaled 32-bit integers: the scale is 1 mm (0.1 mm for clouds under 200 m
  across), coarser by powers of ten only when an axis spans more than 2·10⁹ steps; the
  offset is the cloud's minimum rounded down to a whole scale step, so the written
  coordinates are within half a scale step of the given ones.
* The CRS, when the points are on a body's map, as an OGC WKT coordinate system VLR
  (record 2112 of ``LASF_Projection``, the global encoding's WKT bit set: what point
  formats 6–10 require), from pyproj (planetary IAU CRSs included); none for a local
  frame (the header's system identifier and the file's description say so).
* Per-point attributes (``ray_gap`` metres, an image's ``brightness``, …) as extra
  bytes (float32), self-described by the Extra Bytes VLR (record 4); ``intensity``,
  the standard 16-bit field viewers colour by, is ``brightness`` rescaled from its
  0.1–99.9 percentiles to 0–65535 when a brightness is given.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["POINT_FORMATS", "check_points_path", "write_las", "write_points"]

#: File suffixes :func:`write_points` writes.
POINT_FORMATS = (".ply", ".las", ".laz")


def _scale(low: float, high: float) -> float:
    """LAS coordinate scale: 1 mm (0.1 mm under 200 m), coarser only when the span needs
    more than 2·10⁹ integer steps."""
    span = max(float(high - low), 0.0)
    scale = 1e-4 if span < 200.0 else 1e-3
    while span / scale > 2e9:
        scale *= 10.0
    return scale


def _intensity(brightness: np.ndarray) -> np.ndarray:
    """``brightness`` rescaled from its 0.1–99.9 percentiles to uint16 0–65535."""
    finite = np.isfinite(brightness)
    out = np.zeros(brightness.shape, dtype=np.uint16)
    if not finite.any():
        return out
    low, high = np.percentile(brightness[finite], [0.1, 99.9])
    span = high - low if high > low else 1.0
    scaled = np.clip((brightness[finite] - low) / span, 0.0, 1.0) * 65535.0
    out[finite] = np.round(scaled).astype(np.uint16)
    return out


def write_las(path: str | os.PathLike, xyz: np.ndarray,
              attributes: Mapping[str, np.ndarray] | None = None, *, crs: Any = None,
              description: str = "", descriptions: Mapping[str, str] | None = None) -> Path:
    """Write a point cloud as LAS 1.4 (``.laz``: LASzip-compressed), atomically.

    Parameters
    ----------
    path : path-like
        ``.las`` or ``.laz``.
    xyz : (N, 3) float, metres
        Map x, y and height when ``crs`` is given; a local frame's x, y, z otherwise.
    attributes : mapping of name to (N,) array, optional
        Written as float32 extra bytes; ``brightness`` also fills the standard
        ``intensity`` (rescaled, see the module docstring).
    crs : CRS-like, optional
        The points' CRS (pyproj, rasterio, WKT or an authority code): a WKT VLR.
    description : str
        What the points are; stored in the header's system identifier (32 characters)
        and, whole, in a text VLR (``demtool``, record 1).
    descriptions : mapping of name to str, optional
        Each attribute's description in the Extra Bytes VLR (32 characters).

    Returns
    -------
    Path
    """
    import laspy

    from demtool.maps import to_pyproj_crs
    from demtool.outputs import atomic_path, write_error

    points = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    extra = {name: np.asarray(values, dtype=np.float32).ravel()
             for name, values in (attributes or {}).items()}
    for name, values in extra.items():
        if values.shape != (len(points),):
            raise ValueError(f"attribute {name!r} has {values.size} values for "
                             f"{len(points)} points")
    finite = np.isfinite(points).all(axis=1)
    points = points[finite]
    extra = {name: values[finite] for name, values in extra.items()}
    header = laspy.LasHeader(point_format=6, version="1.4")
    if len(points):
        low, high = points.min(axis=0), points.max(axis=0)
    else:
        low = high = np.zeros(3)
    header.scales = np.array([_scale(a, b) for a, b in zip(low, high, strict=True)])
    header.offsets = np.array([math.floor(a / s) * s for a, s in zip(low, header.scales,
                                                                     strict=True)])
    header.system_identifier = (description or "demtool")[:32]
    header.generating_software = "demtool"
    for name in extra:
        header.add_extra_dim(laspy.ExtraBytesParams(
            name=name, type=np.float32,
            description=((descriptions or {}).get(name) or name)[:32]))
    if crs is not None:
        header.add_crs(to_pyproj_crs(crs))
    if description:
        header.vlrs.append(laspy.VLR(user_id="demtool", record_id=1,
                                    description="what the points are",
                                    record_data=description.encode("utf-8")))
    las = laspy.LasData(header)
    las.x, las.y, las.z = points[:, 0], points[:, 1], points[:, 2]
    for name, values in extra.items():
        las[name] = values
    if "brightness" in extra:
        las.intensity = _intensity(extra["brightness"])
    compress = Path(path).suffix.lower() == ".laz"
    with atomic_path(path, suffix=".laz" if compress else ".las") as temporary:
        try:
            las.write(str(temporary), do_compress=compress)
        except laspy.errors.LaspyException as exc:
            raise write_error(path, exc) from None
    return Path(path)


def check_points_path(path: str | os.PathLike) -> str:
    """The point cloud's format suffix (:data:`POINT_FORMATS`); ParameterError naming the
    file otherwise."""
    from demtool.errors import ParameterError

    suffix = Path(path).suffix.lower()
    if suffix not in POINT_FORMATS:
        raise ParameterError(f"{path}: a point cloud is written as "
                             + ", ".join(POINT_FORMATS) + f", not {suffix or 'no suffix'}")
    return suffix


def write_points(path: str | os.PathLike, xyz: np.ndarray,
                 attributes: Mapping[str, np.ndarray] | None = None, *, crs: Any = None,
                 description: str = "", descriptions: Mapping[str, str] | None = None,
                 comments: Sequence[str] = ()) -> Path:
    """Write a point cloud in the format its suffix names (:data:`POINT_FORMATS`).

    ``.ply``: :func:`demtool.io.write_ply` (attributes as float properties,
    ``description`` and ``comments`` as comments, the CRS's WKT as a comment);
    ``.las``/``.laz``: :func:`write_las`.

    Raises
    ------
    ParameterError
        Another suffix.
    """
    suffix = check_points_path(path)
    if suffix == ".ply":
        from demtool import io as dio

        lines = [*([description] if description else []), *comments]
        if crs is not None:
            from demtool.maps import to_pyproj_crs

            lines.append("crs " + to_pyproj_crs(crs).to_wkt())
        return dio.write_ply(path, xyz, attributes, comments=lines)
    return write_las(path, xyz, attributes, crs=crs, description=description,
                     descriptions=descriptions)
