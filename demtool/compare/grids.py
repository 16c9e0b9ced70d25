"""Putting two DEMs on one grid: NaN-aware interpolation, shifts and reprojection.

Pixel coordinates follow demtool's convention: column ``x`` to the right, row ``y``
down, the centre of pixel ``[row, col]`` at ``(x, y) = (col, row)``.  Interpolators
return NaN wherever a tap with non-zero weight is NaN or outside the array, so holes
never leak invented heights into a comparison (they grow by at most one pixel for
bilinear, two for cubic).  The separable-kernel shifts (Gaussian, Lanczos) are in
:mod:`demtool.compare.shifts`.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from demtool.compare.shifts import lanczos_shift
from demtool.errors import ProcessingError
from demtool.logs import get_logger
from demtool.maps.frames import wrap_longitude
from demtool.tiling.rows import on_row_parts

__all__ = [
    "Grid",
    "resample_to_grid",
    "sample_bilinear",
    "same_grid",
    "sample_cubic",
    "shift_dem",
    "source_pixels",
]

log = get_logger(__name__)

#: Fewest positions :func:`sample_bilinear` gives a thread (a profile's stay on one).
SAMPLES_PER_PART = 1 << 14


@dataclass(frozen=True)
class Grid:
    """A raster grid: shape, pixel-to-map transform and CRS (None in an image frame).

    Attributes
    ----------
    shape : (int, int)
        (rows, columns).
    transform : affine.Affine
        Maps (column, row) of the pixel corner to map coordinates (metres; degrees when
        the CRS is geographic — see :func:`demtool.compare.planetary.metric_grid`).
    crs : rasterio.crs.CRS or None
        Coordinate reference system; None for image-frame / local rasters.
    """

    shape: tuple[int, int]
    transform: Any
    crs: Any = None

    @property
    def spacing(self) -> tuple[float, float]:
        """Pixel size (x, y) in the transform's units (metres, or degrees when
        :attr:`is_geographic`), positive."""
        t = self.transform
        return float(np.hypot(t.a, t.d)), float(np.hypot(t.b, t.e))

    @property
    def is_geographic(self) -> bool:
        """True when the CRS is geographic (the transform is in degrees)."""
        return self.crs is not None and bool(self.crs.is_geographic)

    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the grid's footprint in its own map coordinates."""
        rows, cols = self.shape
        corners = np.array([self.transform @ (c, r) for c in (0, cols) for r in (0, rows)])
        return (corners[:, 0].min(), corners[:, 1].min(), corners[:, 0].max(),
                corners[:, 1].max())


@njit(cache=True)
def _keys_weights(t: float) -> tuple[float, float, float, float]:
    # Keys (1981) cubic convolution kernel, a = -0.5 (eq. 15 of Keys, IEEE TASSP 29(6)).
    a = -0.5
    t1 = 1.0 + t
    t2 = 1.0 - t
    t3 = 2.0 - t
    w0 = a * t1**3 - 5 * a * t1**2 + 8 * a * t1 - 4 * a
    w1 = (a + 2) * t**3 - (a + 3) * t**2 + 1
    w2 = (a + 2) * t2**3 - (a + 3) * t2**2 + 1
    w3 = a * t3**3 - 5 * a * t3**2 + 8 * a * t3 - 4 * a
    return w0, w1, w2, w3


@njit(cache=True, nogil=True)  # serial over a range of samples, driven by on_row_parts
def _sample_cubic(values, rows, cols, out, start, stop):
    # rows, cols, out: flat (demtool.compare.grids._prepare); samples start … stop − 1
    height, width = values.shape
    for k in range(start, stop):
        y = rows[k]
        x = cols[k]
        if not (np.isfinite(x) and np.isfinite(y)):
            out[k] = np.nan
            continue
        r0 = int(np.floor(y))
        c0 = int(np.floor(x))
        wr = _keys_weights(y - r0)
        wc = _keys_weights(x - c0)
        total = 0.0
        bad = False
        for i in range(4):
            if wr[i] == 0.0:
                continue
            r = r0 - 1 + i
            for j in range(4):
                if wc[j] == 0.0:
                    continue
                c = c0 - 1 + j
                if r < 0 or r >= height or c < 0 or c >= width:
                    bad = True
                    break
                v = values[r, c]
                if not np.isfinite(v):
                    bad = True
                    break
                total += wr[i] * wc[j] * v
            if bad:
                break
        out[k] = np.nan if bad else total


@njit(cache=True, nogil=True)  # serial over a range of samples, driven by on_row_parts
def _sample_bilinear(values, rows, cols, out, start, stop):
    # rows, cols, out: flat (demtool.compare.grids._prepare); samples start … stop − 1
    height, width = values.shape
    for k in range(start, stop):
        y = rows[k]
        x = cols[k]
        if not (np.isfinite(x) and np.isfinite(y)):
            out[k] = np.nan
            continue
        r0 = int(np.floor(y))
        c0 = int(np.floor(x))
        fy = y - r0
        fx = x - c0
        total = 0.0
        bad = False
        for i in range(2):
            wy = fy if i == 1 else 1.0 - fy
            if wy == 0.0:
                continue
            for j in range(2):
                wx = fx if j == 1 else 1.0 - fx
                if wx == 0.0:
                    continue
                r = r0 + i
                c = c0 + j
                if r < 0 or r >= height or c < 0 or c >= width or not np.isfinite(values[r, c]):
                    bad = True
                    break
                total += wy * wx * values[r, c]
            if bad:
                break
        out[k] = np.nan if bad else total


@njit(cache=True, nogil=True)  # serial over rows start … stop − 1 (on_row_parts)
def _shift_cubic(values, dx, dy, dz, out, start, stop):
    # out[r, c] = values[r - dy, c - dx] + dz: the cubic weights are the same for every
    # pixel, so they are computed once.
    height, width = values.shape
    # sample position r - dy = r + off_r + ty with off_r = floor(-dy), 0 <= ty < 1
    off_r = int(np.floor(-dy))
    off_c = int(np.floor(-dx))
    wr = _keys_weights(-dy - off_r)
    wc = _keys_weights(-dx - off_c)
    for r in range(start, stop):
        for c in range(width):
            total = 0.0
            bad = False
            for i in range(4):
                if wr[i] == 0.0:
                    continue
                rr = r + off_r - 1 + i
                if rr < 0 or rr >= height:
                    bad = True
                    break
                for j in range(4):
                    if wc[j] == 0.0:
                        continue
                    cc = c + off_c - 1 + j
                    if cc < 0 or cc >= width:
                        bad = True
                        break
                    v = values[rr, cc]
                    if not np.isfinite(v):
                        bad = True
                        break
                    total += wr[i] * wc[j] * v
                if bad:
                    break
            out[r, c] = np.nan if bad else total + dz


def _prepare(values: np.ndarray, rows: np.ndarray, cols: np.ndarray):
    """The raster as C-contiguous float64, the positions flattened (one signature per
    kernel to compile, whatever the positions' shape: the kernels read them flat) and the
    flat output; the caller reshapes the output to ``rows.shape``."""
    data = np.ascontiguousarray(values, dtype=np.float64)
    r = np.ascontiguousarray(rows, dtype=np.float64)
    c = np.ascontiguousarray(cols, dtype=np.float64)
    if r.shape != c.shape:
        raise ValueError(f"rows and cols differ in shape: {r.shape} vs {c.shape}")
    return data, r.reshape(-1), c.reshape(-1), np.empty(r.size, dtype=np.float64)


def sample_cubic(values: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Cubic-convolution interpolation (Keys 1981, a = −0.5) at fractional pixel positions.

    Parameters
    ----------
    values : (H, W) float array, NaN = invalid
        The raster.
    rows, cols : float arrays of one shape
        Positions (row = y down, col = x right) in pixels.

    Returns
    -------
    float64 array, the shape of ``rows``
        Interpolated values; NaN where any of the 4 × 4 taps with non-zero weight is
        NaN or outside the raster.  Exact at integer positions.
    """
    data, r, c, out = _prepare(values, rows, cols)
    on_row_parts(lambda start, stop: _sample_cubic(data, r, c, out, start, stop), r.size,
                 min_rows=SAMPLES_PER_PART)
    return out.reshape(np.shape(rows))


def sample_bilinear(values: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Bilinear interpolation at fractional pixel positions, NaN-aware.

    Same conventions as :func:`sample_cubic`, with the 2 × 2 taps.
    """
    data, r, c, out = _prepare(values, rows, cols)
    on_row_parts(lambda start, stop: _sample_bilinear(data, r, c, out, start, stop), r.size,
                 min_rows=SAMPLES_PER_PART)
    return out.reshape(np.shape(rows))


def shift_dem(dem: np.ndarray, dx_px: float, dy_px: float, dz: float = 0.0, *,
              method: str = "lanczos") -> np.ndarray:
    """Translate a DEM on its own grid: ``out[y, x] = dem[y − dy, x − dx] + dz``.

    Parameters
    ----------
    dem : (H, W) float array, metres, NaN = invalid
    dx_px, dy_px : float
        Translation in pixels, x right, y down (the content moves by this much).
    dz : float
        Height offset added, metres.
    method : {"lanczos", "cubic", "linear"}
        Lanczos-3 windowed sinc (default: the most faithful on rough terrain, holes grow
        by 3 px), Keys cubic convolution (2 px) or bilinear (1 px).

    Returns
    -------
    (H, W) float64
        Shifted DEM; NaN where the source is outside or has holes.
    """
    if method == "lanczos":
        return lanczos_shift(dem, dx_px, dy_px, lobes=3) + dz
    if method == "cubic":
        out = np.empty(dem.shape, dtype=np.float64)
        data = np.ascontiguousarray(dem, dtype=np.float64)
        on_row_parts(lambda start, stop: _shift_cubic(data, float(dx_px), float(dy_px),
                                                      float(dz), out, start, stop),
                     out.shape[0])
        return out
    if method == "linear":
        rows, cols = np.indices(dem.shape, dtype=np.float64)
        return sample_bilinear(dem, rows - dy_px, cols - dx_px) + dz
    raise ValueError(f"unknown method {method!r}: should be lanczos, cubic or linear")


def _check_same_body(src: Grid, dst: Grid) -> None:
    from demtool.maps import body_from_crs, same_body
    from demtool.maps.bodies import body_label

    first, second = body_from_crs(src.crs), body_from_crs(dst.crs)
    if not same_body(first, second):
        raise ProcessingError(f"cannot reproject from {body_label(first)} to "
                              f"{body_label(second)}: the rasters are of different bodies")


def _lon_centre(grid: Grid) -> float:
    """Longitude (degrees) of the centre of a geographic grid."""
    t = grid.transform
    rows, cols = grid.shape
    return float(t.a * 0.5 * cols + t.b * 0.5 * rows + t.c)


def _check_overlap(src: Grid, dst: Grid) -> None:
    if src.crs is not None and dst.crs is not None and src.crs != dst.crs:
        _check_same_body(src, dst)
        from rasterio.warp import transform_bounds

        sx0, sy0, sx1, sy1 = transform_bounds(src.crs, dst.crs, *src.bounds(), densify_pts=21)
    else:
        sx0, sy0, sx1, sy1 = src.bounds()
    dx0, dy0, dx1, dy1 = dst.bounds()
    if dst.is_geographic and (src.is_geographic or _reprojects(src, dst)):
        if sx1 < sx0:  # transform_bounds across the antimeridian: xmin > xmax
            sx1 += 360.0
        middle = 0.5 * (sx0 + sx1)  # the same ground written 360° apart overlaps
        shift = float(wrap_longitude(middle, 0.5 * (dx0 + dx1))) - middle
        sx0, sx1 = sx0 + shift, sx1 + shift
    if not (sx0 < dx1 and dx0 < sx1 and sy0 < dy1 and dy0 < sy1):
        def text(bounds):
            return "(" + ", ".join(f"{float(v):.6g}" for v in bounds) + ")"

        raise ProcessingError(
            f"the rasters do not overlap: bounds {text((sx0, sy0, sx1, sy1))} vs "
            f"{text((dx0, dy0, dx1, dy1))} (xmin, ymin, xmax, ymax in the target grid's "
            "coordinates); check that both are in the same frame or carry their CRS")


def _reprojects(src: Grid, dst: Grid) -> bool:
    """True when the two grids have different CRSs (an exact pyproj reprojection)."""
    return src.crs is not None and dst.crs is not None and src.crs != dst.crs


#: pyproj transformers made (about 0.2 s each), by the WKT of their two CRSs
_TRANSFORMERS: dict[tuple[str, str], Any] = {}
_TRANSFORMERS_LOCK = threading.Lock()
_TRANSFORMERS_KEPT = 8


def _transformer(from_crs: Any, to_crs: Any) -> Any:
    """The pyproj ``Transformer`` (``always_xy``) between two CRSs, made once per pair:
    a raster resampled window by window (or block by block) transforms many windows
    between the same two CRSs, and making the transformer costs more than transforming
    a million points.  pyproj (>= 3.1) makes a Transformer safe on several threads (each
    thread gets its own PROJ object on first use)."""
    key = (from_crs.to_wkt(), to_crs.to_wkt())
    with _TRANSFORMERS_LOCK:
        found = _TRANSFORMERS.get(key)
    if found is not None:
        return found
    from pyproj import Transformer

    from demtool.maps import to_pyproj_crs

    made = Transformer.from_crs(to_pyproj_crs(from_crs), to_pyproj_crs(to_crs), always_xy=True)
    with _TRANSFORMERS_LOCK:
        while len(_TRANSFORMERS) >= _TRANSFORMERS_KEPT:
            del _TRANSFORMERS[next(iter(_TRANSFORMERS))]
        return _TRANSFORMERS.setdefault(key, made)


def source_pixels(src: Grid, dst: Grid, window: tuple[int, int, int, int]
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Where the centres of ``dst``'s cells in ``window`` fall in ``src``, pixels.

    Parameters
    ----------
    src, dst : Grid
    window : (row0, row1, col0, col1)
        Cells of ``dst``, half-open.

    Returns
    -------
    rows, cols : (row1 − row0, col1 − col0) float64
        Array coordinates in ``src`` (the centre of pixel [r, c] at (r, c)): through the
        two affine transforms, or, when the CRSs differ, through an exact pyproj
        transformation (``always_xy``).  The numbers of a cell do not depend on the
        window it is computed in, so a raster resampled window by window equals the
        raster resampled whole (:func:`resample_to_grid`).
    """
    r0, r1, c0, c1 = window
    cc, rr = np.meshgrid(np.arange(c0, c1, dtype=np.float64) + 0.5,
                         np.arange(r0, r1, dtype=np.float64) + 0.5)
    if _reprojects(src, dst):
        transformer = _transformer(dst.crs, src.crs)
        t = dst.transform
        x, y = transformer.transform(t.a * cc + t.b * rr + t.c, t.d * cc + t.e * rr + t.f)
        x, y = np.asarray(x), np.asarray(y)
        if src.is_geographic:  # PROJ answers −180…180; the source may be 0…360
            x = wrap_longitude(x, _lon_centre(src))
        inverse = ~src.transform
        return (inverse.d * x + inverse.e * y + inverse.f - 0.5,
                inverse.a * x + inverse.b * y + inverse.c - 0.5)
    if src.is_geographic and dst.is_geographic:  # one CRS, longitudes maybe 360° apart
        t, inverse = dst.transform, ~src.transform
        x = wrap_longitude(t.a * cc + t.b * rr + t.c, _lon_centre(src))
        y = t.d * cc + t.e * rr + t.f
        return (inverse.d * x + inverse.e * y + inverse.f - 0.5,
                inverse.a * x + inverse.b * y + inverse.c - 0.5)
    # destination pixel centre (c + 0.5, r + 0.5) -> map -> source pixel centre coordinates
    to_src = ~src.transform @ dst.transform
    return (to_src.d * cc + to_src.e * rr + to_src.f - 0.5,
            to_src.a * cc + to_src.b * rr + to_src.c - 0.5)


def _reproject_bilinear(values: np.ndarray, src: Grid, dst: Grid,
                        rows_per_block: int = 256) -> np.ndarray:
    """Bilinear reprojection: each destination cell centre is transformed exactly (pyproj,
    ``always_xy``) into the source CRS and interpolated by :func:`sample_bilinear`.

    Unlike GDAL's warper this neither widens the kernel where the source footprint of a
    destination pixel looks larger (a rotated grid, a small scale change — GDAL then
    smooths the DEM by up to ~1.4 px) nor approximates the transformation (0.125 px), so a
    surface reprojected between two CRSs stays within bilinear interpolation's error.
    """
    rows, cols = dst.shape
    out = np.empty(dst.shape, dtype=np.float64)
    for start in range(0, rows, rows_per_block):
        stop = min(rows, start + rows_per_block)
        src_rows, src_cols = source_pixels(src, dst, (start, stop, 0, cols))
        out[start:stop] = sample_bilinear(values, src_rows, src_cols)
    return out


def same_grid(src: Grid, dst: Grid) -> bool:
    """True when :func:`resample_to_grid` copies (one shape, one transform, no CRS change)."""
    return (not _reprojects(src, dst) and tuple(src.shape) == tuple(dst.shape)
            and src.transform.almost_equals(dst.transform))


def resample_to_grid(values: np.ndarray, src: Grid, dst: Grid) -> np.ndarray:
    """Resample a raster onto another grid with NaN-aware bilinear interpolation.

    Parameters
    ----------
    values : (H, W) float array, NaN = invalid
        The raster on grid ``src``.
    src, dst : Grid
        Source and destination grids.  When both have a CRS and they differ, each
        destination pixel centre is transformed exactly into the source CRS (pyproj) and
        interpolated by :func:`sample_bilinear` (see :func:`_reproject_bilinear`);
        planetary CRSs (PROJ's ``IAU_2015`` codes, or any CRS on the body's datum) work
        alike, and CRSs of different bodies are refused.  Otherwise both transforms are taken
        to be in one map frame (image-frame rasters carry their spacing in their
        transforms) and each destination pixel centre is mapped to source pixel
        coordinates through the two affine transforms and interpolated by
        :func:`sample_bilinear` (exact, and without any resampling, when the grids are
        the same).

    Returns
    -------
    (rows, cols) of ``dst`` float64, NaN outside the source and in its holes.

    Raises
    ------
    ProcessingError
        When the two footprints do not overlap, or the CRSs are of different bodies.
    """
    if values.shape != tuple(src.shape):
        raise ValueError(f"values have shape {values.shape}, grid says {src.shape}")
    _check_overlap(src, dst)
    if _reprojects(src, dst):
        return _reproject_bilinear(values, src, dst)
    if (src.crs is None) != (dst.crs is None):
        log.warning("one raster has a CRS and the other has none: assuming both transforms "
                    "are in the same map coordinates")
    if same_grid(src, dst):
        return np.asarray(values, dtype=np.float64).copy()
    src_rows, src_cols = source_pixels(src, dst, (0, dst.shape[0], 0, dst.shape[1]))
    return sample_bilinear(values, src_rows, src_cols)
