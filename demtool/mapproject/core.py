"""Map projection of an image through its sensor model (ISIS ``cam2map``, ASP ``mapproject``).

Image → map, computed backwards (map → image), one tile of map cells at a time:

1. every cell centre of the map grid is a ground point: map x, y → planetocentric
   lon, lat (:func:`demtool.maps.map_to_lonlat`) → body-fixed XYZ on the body's
   reference sphere raised by the surface height there (the DEM's height, bilinear, or
   a constant ``--height``), demtool's map contract (heights above the sphere, radial);
2. the sensor model's ``ground_to_image`` gives the cell's image ``(line, sample)``;
3. the image is resampled there by bicubic convolution (Keys 1981, a = −0.5, GDAL's
   ``cubic``); NaN where the point is behind the sensor, outside the image or next to a
   NaN pixel.

Step 2 is the costly one for a line scanner (an iterative search of the exposure line).
Within a tile the map → image function is smooth in (x, y) and in the height, so it is
evaluated exactly on a coarse lattice of nodes (every ``step`` cells) at two or three
heights spanning the tile's surface, and interpolated: bilinear across the lattice,
Lagrange (linear or quadratic) across the heights.  The interpolation error is measured
against exact evaluations at random cells of every tile, and the lattice is refined
(``step`` halved, down to exact evaluation of every cell) until it is below
``tolerance`` pixels — ASP's ``mapproject`` does its projection the same way on a
coarser fixed lattice.

The resampling kernels (bicubic image, bilinear heights) live in
:mod:`demtool.mapproject.sampling` and are re-exported here.

References: Keys, R. (1981), Cubic convolution interpolation for digital image
processing, IEEE Trans. ASSP 29(6), 1153-1160; USGS ISIS ``cam2map``; NASA Ames Stereo
Pipeline ``mapproject`` (Beyer et al. 2018, Earth and Space Science 5).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numba import njit, prange

from demtool.logs import get_logger
from demtool.mapproject.sampling import (  # re-exported: the resampling kernels
    bicubic_sample,
    bilinear_heights,
    image_window,
    resample_tile,
)

log = get_logger(__name__)

__all__ = [
    "ImageCoordinates",
    "bicubic_sample",
    "bilinear_heights",
    "ground_footprint",
    "illumination_angles",
    "image_coordinates",
    "image_window",
    "native_gsd",
    "ortho_grid",
    "resample_tile",
    "sensor_body",
    "tile_misses_image",
    "tile_windows",
]


def sensor_body(sensor: Any):
    """The body (:class:`demtool.maps.Body`) of a sensor model's radii.

    Parameters
    ----------
    sensor : SensorModel
        With ``radii = (semi_major, semi_minor)`` in metres.

    Raises
    ------
    ValueError
        When the model has no body (a synthetic local-frame camera).
    """
    from demtool.maps import body_from_radii

    if sensor.radii is None:
        raise ValueError("the sensor model is in a local frame, not on a body")
    a, b = sensor.radii
    # an ISIS cube names its body (Bennu: PROJ lacks it; the radii are the model's own)
    body = body_from_radii(a, a, b, name=getattr(sensor, "body_name", None),
                           naif_id=getattr(sensor, "body_naif_id", None))
    if getattr(sensor, "height_reference", "sphere") == "ellipsoid":
        # an RPC's heights are geodetic, above its ellipsoid (WGS 84): so are its maps'
        from dataclasses import replace

        body = replace(body, height_reference="ellipsoid")
    return body


def _border(lines: int, samples: int, per_edge: int) -> tuple[np.ndarray, np.ndarray]:
    """(line, sample) along the image's outer edges, in order round the image."""
    t = np.linspace(0.0, 1.0, per_edge, endpoint=False)
    line = np.concatenate([np.zeros_like(t), t * lines, np.full_like(t, lines),
                           (1 - t) * lines])
    sample = np.concatenate([t * samples, np.full_like(t, samples), (1 - t) * samples,
                             np.zeros_like(t)])
    return line, sample


def _on_surface(sensor: Any, line, sample, surface, height) -> np.ndarray:
    """Ground points of image points on ``surface`` raised by ``height`` (NaN where the
    ray misses): a sphere (radius) by ray intersection, a geodetic ellipsoid (an RPC's
    WGS 84) by the model's own image-to-ground at that height."""
    from demtool.maps.frames import GeodeticEllipsoid
    from demtool.sensors import ray_ellipsoid_intersection

    if isinstance(surface, GeodeticEllipsoid):
        with np.errstate(invalid="ignore"):
            return np.asarray(sensor.image_to_ground(line, sample, height), dtype=np.float64)
    ray = sensor.image_to_ray(line, sample)
    xyz, hit = ray_ellipsoid_intersection(ray.origin, ray.direction, surface, surface, height,
                                          return_hit=True)
    xyz[~hit] = np.nan
    return xyz


def ground_footprint(sensor: Any, radius: Any, height: float = 0.0, *,
                     per_edge: int = 16) -> np.ndarray:
    """Ground points of the image's outer edge on the body's surface raised by ``height``.

    Parameters
    ----------
    sensor : SensorModel
    radius : float or GeodeticEllipsoid
        The body's :attr:`~demtool.maps.Body.surface`: reference sphere radius, metres, or
        the ellipsoid of geodetic heights (an RPC's WGS 84).
    height : float
        Metres above that surface.
    per_edge : int
        Points per image edge.

    Returns
    -------
    (4 * per_edge, 3) float64
        Body-fixed metres, in order round the image; NaN rows where the ray misses.
    """
    line, sample = _border(sensor.lines, sensor.samples, per_edge)
    return _on_surface(sensor, line, sample, radius, height)


def native_gsd(sensor: Any, radius: Any, height: float = 0.0) -> float:
    """Ground sample distance of the image at its centre, metres.

    The geometric mean of the ground distances between the centre pixel and its
    neighbours along the line and along the sample, on the body's surface (``radius``:
    :attr:`~demtool.maps.Body.surface`) raised by ``height``.

    Raises
    ------
    ValueError
        When the image centre does not see the surface.
    """
    cl, cs = 0.5 * sensor.lines, 0.5 * sensor.samples
    line = np.array([cl, cl + 1.0, cl])
    sample = np.array([cs, cs, cs + 1.0])
    xyz = _on_surface(sensor, line, sample, radius, height)
    if not np.isfinite(xyz).all():
        raise ValueError("the image centre does not see the body")
    along = float(np.linalg.norm(xyz[1] - xyz[0]))
    across = float(np.linalg.norm(xyz[2] - xyz[0]))
    return math.sqrt(along * across)


def ortho_grid(sensor: Any, body: Any, *, height: float = 0.0, gsd: float | None = None,
               projection: str = "auto", bounds: tuple[float, float, float, float] | None
               = None, crs: Any = None):
    """The map grid of an orthoimage: the image's footprint (or ``bounds``) at ``gsd``.

    Parameters
    ----------
    sensor : SensorModel
    body : demtool.maps.Body
    height : float
        Metres above the body's surface (:attr:`~demtool.maps.Body.surface`) of the
        ground used for the footprint.
    gsd : float, optional
        Pixel size in metres; default: :func:`native_gsd` at the image centre.
    projection : {"auto", "equirectangular", "polar-stereographic"}
        Used when ``crs`` is None, centred on the footprint.
    bounds : (lon_min, lat_min, lon_max, lat_max), degrees, optional
        The area to cover instead of the footprint.
    crs : CRS-like, optional
        A given projected CRS on the body's sphere.

    Returns
    -------
    demtool.maps.MapGrid

    Raises
    ------
    ValueError
        When the footprint misses the body.
    """
    from demtool.maps import grid_from_lonlat, longitude_span, xyz_to_lonlat_height

    if gsd is None:
        gsd = native_gsd(sensor, body.surface, height)
    if bounds is not None:
        lon_min, lat_min, lon_max, lat_max = (float(v) for v in bounds)
        lon_min, lon_max = longitude_span(lon_min, lon_max)
        lon = np.array([lon_min, lon_max, lon_max, lon_min])
        lat = np.array([lat_min, lat_min, lat_max, lat_max])
    else:
        xyz = ground_footprint(sensor, body.surface, height)
        if not np.isfinite(xyz).all():
            raise ValueError("part of the image does not see the body (limb in view); give "
                             "--bounds")
        lon, lat, _ = xyz_to_lonlat_height(xyz, radii=body.surface)
    return grid_from_lonlat(body, lon, lat, gsd, projection=projection, crs=crs)


def tile_windows(shape: tuple[int, int], tile: int) -> list[tuple[int, int, int, int]]:
    """Tiles ``(row0, row1, col0, col1)`` of at most ``tile`` × ``tile`` cells, row-major."""
    rows, cols = shape
    return [(r, min(r + tile, rows), c, min(c + tile, cols))
            for r in range(0, rows, tile) for c in range(0, cols, tile)]


def _cell_xy(transform: Any, rows: np.ndarray, cols: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
    """Map x, y of cell centres (rows, cols broadcast)."""
    t = transform
    cc, rr = np.meshgrid(np.asarray(cols, dtype=np.float64) + 0.5,
                         np.asarray(rows, dtype=np.float64) + 0.5)
    return t.a * cc + t.b * rr + t.c, t.d * cc + t.e * rr + t.f


class ImageCoordinates(NamedTuple):
    """Image coordinates of a tile's cells.

    line, sample : (h, w) float64
        CSM image coordinates (first pixel centre at 0.5); NaN where not seen or no height.
    step : int
        Lattice spacing used (cells; 1 = every cell exact).
    max_error_px : float
        Largest interpolation error found at the check cells, pixels (0 when exact).
    """

    line: np.ndarray
    sample: np.ndarray
    step: int
    max_error_px: float


@njit(cache=True, parallel=True, nogil=True)
def _interpolate_lattice(node_line, node_sample, levels, heights, step, out_line,
                         out_sample):
    """Bilinear across the node lattice, Lagrange across the height levels.

    node_* : (L, nr, nc); levels : (L,); heights : (h, w); out_* : (h, w).
    """
    n_levels = levels.shape[0]
    h, w = heights.shape
    nr, nc = node_line.shape[1], node_line.shape[2]
    for i in prange(h):
        fi = i / step
        i0 = min(int(fi), nr - 2)
        ti = fi - i0
        for j in range(w):
            z = heights[i, j]
            if not math.isfinite(z):
                out_line[i, j] = np.nan
                out_sample[i, j] = np.nan
                continue
            fj = j / step
            j0 = min(int(fj), nc - 2)
            tj = fj - j0
            acc_l = 0.0
            acc_s = 0.0
            for k in range(n_levels):
                weight = 1.0
                for m in range(n_levels):
                    if m != k:
                        weight *= (z - levels[m]) / (levels[k] - levels[m])
                a = node_line[k, i0, j0]
                b = node_line[k, i0, j0 + 1]
                c = node_line[k, i0 + 1, j0]
                d = node_line[k, i0 + 1, j0 + 1]
                acc_l += weight * ((1 - ti) * ((1 - tj) * a + tj * b)
                                   + ti * ((1 - tj) * c + tj * d))
                a = node_sample[k, i0, j0]
                b = node_sample[k, i0, j0 + 1]
                c = node_sample[k, i0 + 1, j0]
                d = node_sample[k, i0 + 1, j0 + 1]
                acc_s += weight * ((1 - ti) * ((1 - tj) * a + tj * b)
                                   + ti * ((1 - tj) * c + tj * d))
            out_line[i, j] = acc_l
            out_sample[i, j] = acc_s


def tile_misses_image(sensor: Any, crs: Any, transform: Any,
                      window: tuple[int, int, int, int], low: float, high: float, *,
                      per_edge: int = 8, margin: float = 4.0) -> bool:
    """True when a map tile certainly shows nothing of the image.

    The tile's outline (``per_edge`` cells per edge, at the lowest and highest surface
    heights) is projected into the image; when every outline point converges and lies
    beyond one and the same image edge (by more than ``margin`` pixels), the tile misses
    the image (the map → image function of a tile does not fold).  Saves the costly
    non-converging searches of the cells far off a narrow image.
    """
    r0, r1, c0, c1 = window
    t = np.linspace(0.0, 1.0, per_edge)
    rows = np.concatenate([r0 + t * (r1 - r0), np.full_like(t, r1), r0 + t * (r1 - r0),
                           np.full_like(t, r0)])
    cols = np.concatenate([np.full_like(t, c0), c0 + t * (c1 - c0), np.full_like(t, c1),
                           c0 + t * (c1 - c0)])
    x = transform.a * cols + transform.b * rows + transform.c
    y = transform.d * cols + transform.e * rows + transform.f
    lines, samples = [], []
    for level in {float(low), float(high)}:
        line, sample = _exact(sensor, crs, x, y, np.full(x.shape, level))
        lines.append(line)
        samples.append(sample)
    line, sample = np.concatenate(lines), np.concatenate(samples)
    if not (np.isfinite(line).all() and np.isfinite(sample).all()):
        return False
    return bool((line < -margin).all() or (line > sensor.lines + margin).all()
                or (sample < -margin).all() or (sample > sensor.samples + margin).all())


def _exact(sensor, crs, x, y, heights):
    from demtool.maps import map_to_xyz

    xyz = map_to_xyz(crs, x, y, heights)
    line, sample = sensor.ground_to_image(xyz.reshape(-1, 3))
    return line.reshape(x.shape), sample.reshape(x.shape)


def image_coordinates(sensor: Any, crs: Any, transform: Any,
                      window: tuple[int, int, int, int], heights: np.ndarray, *,
                      step: int = 16, tolerance: float = 0.01, check_cells: int = 200,
                      seed: int = 0) -> ImageCoordinates:
    """Image coordinates of the cells of one map tile (see the module docstring).

    Parameters
    ----------
    sensor : SensorModel
    crs, transform
        The map grid's projected CRS (on the body's sphere) and its transform.
    window : (row0, row1, col0, col1)
        The tile, grid cells.
    heights : (row1 − row0, col1 − col0) float
        Surface height of every cell, metres above the sphere; NaN = no surface.
    step : int
        Initial lattice spacing, cells (≥ 1).
    tolerance : float
        Largest interpolation error accepted, image pixels.
    check_cells : int
        Random cells checked against the exact projection per tile.
    seed : int
        Seed of the choice of check cells.

    Returns
    -------
    ImageCoordinates
    """
    r0, r1, c0, c1 = window
    heights = np.asarray(heights, dtype=np.float64)
    h, w = r1 - r0, c1 - c0
    if heights.shape != (h, w):
        raise ValueError(f"heights have shape {heights.shape}, window is {(h, w)}")
    finite = np.isfinite(heights)
    nan = np.full((h, w), np.nan)
    if not finite.any():
        return ImageCoordinates(nan, nan.copy(), max(step, 1), 0.0)
    lo, hi = float(heights[finite].min()), float(heights[finite].max())
    rng = np.random.default_rng(seed)
    draw = rng.integers(0, h * w, 4 * check_cells)
    draw = np.unique(draw[finite.ravel()[draw]])[:check_cells]
    check_r, check_c = np.divmod(draw, w)
    tx = transform
    check_x = tx.a * (c0 + check_c + 0.5) + tx.b * (r0 + check_r + 0.5) + tx.c
    check_y = tx.d * (c0 + check_c + 0.5) + tx.e * (r0 + check_r + 0.5) + tx.f
    check_h = heights[check_r, check_c]
    if hi - lo < 1e-3:
        levels = np.array([lo])
    elif hi - lo < 50.0:
        levels = np.array([lo, hi])
    else:
        levels = np.array([lo, 0.5 * (lo + hi), hi])
    step = max(int(step), 1)
    exact_line = exact_sample = None
    while step >= 2 and min(h, w) > 1:
        n_r = max(int(math.ceil((h - 1) / step)) + 1, 2)
        n_c = max(int(math.ceil((w - 1) / step)) + 1, 2)
        node_x, node_y = _cell_xy(transform, r0 + step * np.arange(n_r),
                                  c0 + step * np.arange(n_c))
        # one projection call for every level's nodes (and, first, the check cells)
        xs = [np.tile(node_x.ravel(), len(levels))]
        ys = [np.tile(node_y.ravel(), len(levels))]
        hs = [np.repeat(levels, node_x.size)]
        if exact_line is None:
            xs.append(check_x)
            ys.append(check_y)
            hs.append(check_h)
        line_all, sample_all = _exact(sensor, crs, np.concatenate(xs), np.concatenate(ys),
                                      np.concatenate(hs))
        n_nodes = len(levels) * node_x.size
        if exact_line is None:
            exact_line, exact_sample = line_all[n_nodes:], sample_all[n_nodes:]
        node_line = line_all[:n_nodes].reshape((len(levels),) + node_x.shape)
        node_sample = sample_all[:n_nodes].reshape((len(levels),) + node_x.shape)
        line = np.empty((h, w))
        sample = np.empty((h, w))
        _interpolate_lattice(node_line, node_sample, levels, heights, float(step), line,
                             sample)
        got_l, got_s = line[check_r, check_c], sample[check_r, check_c]
        both = np.isfinite(exact_line) & np.isfinite(got_l)
        error = float(np.max(np.hypot(got_l - exact_line, got_s - exact_sample)[both],
                             initial=0.0))
        if error <= tolerance:
            return ImageCoordinates(line, sample, step, error)
        log.debug("tile %s: lattice step %d off by %.3g px; refining", window, step, error)
        step //= 2
    x, y = _cell_xy(transform, np.arange(r0, r1), np.arange(c0, c1))
    line, sample = _exact(sensor, crs, x, y, heights)
    return ImageCoordinates(line, sample, 1, 0.0)


def illumination_angles(sensor: Any, xyz: np.ndarray, line: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Incidence, emission and phase angles at ground points, degrees.

    Incidence is the angle between the sun and the reference sphere's normal (the
    radius vector) at the point, emission between the direction to the sensor (its
    position at the exposure of ``line``) and the normal, phase between the sun and the
    sensor (ISIS ``phocube``'s ``Incidence``, ``Emission``, ``Phase``).

    Parameters
    ----------
    sensor : SensorModel
    xyz : S + (3,) float, body-fixed metres
    line : S float, CSM image line of each point (NaN: angles NaN)

    Returns
    -------
    incidence, emission, phase : S float32, degrees
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    line = np.asarray(line, dtype=np.float64)
    ok = np.isfinite(line) & np.isfinite(xyz).all(axis=-1)
    safe = np.where(ok, line, 0.5 * sensor.lines)
    normal = xyz / np.linalg.norm(xyz, axis=-1, keepdims=True)
    sun = sensor.sun_position(safe) - xyz
    view = sensor.camera_center(safe) - xyz
    sun /= np.linalg.norm(sun, axis=-1, keepdims=True)
    view /= np.linalg.norm(view, axis=-1, keepdims=True)

    def angle(u, v):
        return np.degrees(np.arccos(np.clip(np.sum(u * v, axis=-1), -1.0, 1.0)))

    out = []
    for pair in ((sun, normal), (view, normal), (sun, view)):
        values = angle(*pair)
        values[~ok] = np.nan
        out.append(values.astype(np.float32))
    return out[0], out[1], out[2]
