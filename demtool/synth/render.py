"""Ray casting of a height field and rendering of views through sensor models (numba).

The height field is the DEM on the map grid (CONTRIBUTING.md): cell (row r, column c)
holds the height at the cell centre ``x = x_first + c·s``, ``y = y_first − r·s``
(world metres, X east, Y north, Z up) and is interpolated bilinearly in between.
A ray hits the surface where ``z(t) = h(x(t), y(t))``; the kernels march along the
ray in steps of at most half a cell horizontally and refine the first sign change by
regula falsi (Illinois) to ~1e-9 m, far below 0.1 px at any sensible ground sampling
distance.

Shading: the normal at the hit comes from the DEM gradient (central differences at
the nodes, interpolated bilinearly), the reflectance from
:func:`demtool.imaging.reflectance.lunar_lambert` with L from the per-pixel phase angle;
a hit is in cast shadow when the terrain rises above the ray from it toward the sun.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from demtool.imaging.reflectance import lunar_lambert
from demtool.sensors.base import SensorModel
from demtool.tiling.rows import on_row_parts

MARCH_STEP_CELLS = 0.5  # horizontal ray-marching step, in cells
REFINE_ITERATIONS = 100
REFINE_TOLERANCE_M = 1e-9  # clearance (vertical metres) or bracket length at the hit
SHADOW_BLOCK_CELLS = 8  # sun rays skip blocks of this many cells whose top they clear
SHADOW_EPSILON_M = 1e-4  # terrain must rise this far above a sun ray to cast a shadow
RAY_BLOCK_ROWS = 64  # image rows (× 512 pixels of a list) per image_to_ray call
BLOCK_PIXELS = 1 << 21  # pixels of one block of rows rendered at once (row_blocks)


class HeightField(NamedTuple):
    """A DEM prepared for ray casting (map grid, see module docstring).

    Attributes
    ----------
    dem : (H, W) float64
        Heights, metres.
    grad_x, grad_y : (H, W) float64
        ∂h/∂X (east) and ∂h/∂Y (north) at the nodes, central differences.
    x_first, y_first : float
        World X of column 0 and world Y of row 0 (cell centres), metres.
    spacing : float
        Cell size, metres.
    z_min, z_max : float
        Bounds of the heights (padded by a millimetre).
    block_max : (ceil((H-1)/B), ceil((W-1)/B)) float64
        Highest node of each block of B × B cells (B = ``SHADOW_BLOCK_CELLS``, node
        rows/columns ``B·i … B·i + B``): no bilinear height inside the block exceeds it,
        so sun rays above it skip the block.
    """

    dem: np.ndarray
    grad_x: np.ndarray
    grad_y: np.ndarray
    x_first: float
    y_first: float
    spacing: float
    z_min: float
    z_max: float
    block_max: np.ndarray


def block_maxima(heights: np.ndarray, block: int) -> np.ndarray:
    """Maximum of the nodes ``[B·i, B·i + B] × [B·j, B·j + B]`` of each block (B = block)."""
    rows, cols = heights.shape
    n_rows, n_cols = -(-(rows - 1) // block), -(-(cols - 1) // block)
    out = np.empty((n_rows, n_cols))
    for i in range(n_rows):
        band = heights[block * i: block * i + block + 1].max(axis=0)
        for j in range(n_cols):
            out[i, j] = band[block * j: block * j + block + 1].max()
    return out


def height_field(dem: np.ndarray, transform) -> HeightField:
    """Prepare ``dem`` (map grid, ``transform`` = Affine(s, 0, x_west, 0, −s, y_north))."""
    spacing = float(transform.a)
    if not np.isclose(-transform.e, spacing) or transform.b != 0 or transform.d != 0:
        raise ValueError("height_field: the DEM transform must be north-up with square cells")
    heights = np.ascontiguousarray(dem, dtype=np.float64)
    grad_rows, grad_cols = np.gradient(heights, spacing)
    return HeightField(
        dem=heights, grad_x=np.ascontiguousarray(grad_cols),
        grad_y=np.ascontiguousarray(-grad_rows),  # rows run south
        x_first=float(transform.c) + 0.5 * spacing, y_first=float(transform.f) - 0.5 * spacing,
        spacing=spacing, z_min=float(heights.min()) - 1e-3, z_max=float(heights.max()) + 1e-3,
        block_max=block_maxima(heights, SHADOW_BLOCK_CELLS))


# --------------------------------------------------------------------------------------
# numba kernels
# --------------------------------------------------------------------------------------


# _bilinear and _clearance are called kernels, not numba-inlined IR: the render kernels
# compile ~2 CPU s faster (no fast-math here, so the same arithmetic to the bit)
@njit(cache=True)
def _bilinear(grid, fc, fr):
    """Bilinear value at fractional (column, row); NaN outside the grid."""
    height, width = grid.shape
    if not (fc >= 0.0 and fr >= 0.0 and fc <= width - 1 and fr <= height - 1):
        return np.nan
    c0 = min(int(fc), width - 2)
    r0 = min(int(fr), height - 2)
    a = fc - c0
    b = fr - r0
    return ((grid[r0, c0] * (1.0 - a) + grid[r0, c0 + 1] * a) * (1.0 - b)
            + (grid[r0 + 1, c0] * (1.0 - a) + grid[r0 + 1, c0 + 1] * a) * b)


@njit(cache=True)
def _clearance(ox, oy, oz, dx, dy, dz, t, dem, x_first, y_first, spacing):
    """Ray height above the terrain at parameter t (+inf outside the DEM)."""
    h = _bilinear(dem, (ox + t * dx - x_first) / spacing, (y_first - (oy + t * dy)) / spacing)
    if np.isnan(h):
        return np.inf
    return oz + t * dz - h


@njit(cache=True)
def _intersect(ox, oy, oz, dx, dy, dz, dem, x_first, y_first, spacing, z_min, z_max):
    """Ray parameter of the first hit of origin + t·direction with the surface, or NaN."""
    if dz >= 0.0:
        return np.nan
    t_start = max((oz - z_max) / -dz, 0.0)
    t_end = (oz - z_min) / -dz
    horizontal = math.sqrt(dx * dx + dy * dy)
    span = t_end - t_start
    step = span
    if horizontal * span > MARCH_STEP_CELLS * spacing:
        step = MARCH_STEP_CELLS * spacing / horizontal
    t_prev = t_start
    f_prev = _clearance(ox, oy, oz, dx, dy, dz, t_prev, dem, x_first, y_first, spacing)
    if f_prev <= 0.0:
        return t_prev
    while t_prev < t_end:
        t = min(t_prev + step, t_end)
        f = _clearance(ox, oy, oz, dx, dy, dz, t, dem, x_first, y_first, spacing)
        if f <= 0.0:
            return _refine_root(ox, oy, oz, dx, dy, dz, t_prev, f_prev, t, f, dem, x_first,
                                y_first, spacing)
        t_prev = t
        f_prev = f
    return np.nan


@njit(cache=True)
def _refine_root(ox, oy, oz, dx, dy, dz, lo, f_lo, hi, f_hi, dem, x_first, y_first, spacing):
    """Root of the clearance in [lo, hi] (f_lo > 0 ≥ f_hi) by the Illinois method.

    Regula falsi with the Illinois modification (Dowell & Jarratt 1971, BIT 11, 168–174):
    the bracket always holds the crossing; bisection steps are used where the secant is
    unusable (a bracket end outside the DEM).  Stops at |clearance| < REFINE_TOLERANCE_M
    or a bracket shorter than that.
    """
    side = 0
    for _ in range(REFINE_ITERATIONS):
        if hi - lo < REFINE_TOLERANCE_M:
            break
        mid = 0.5 * (lo + hi)
        if np.isfinite(f_lo) and f_lo - f_hi > 0.0:
            secant = (lo * f_hi - hi * f_lo) / (f_hi - f_lo)
            if lo < secant < hi:
                mid = secant
        f_mid = _clearance(ox, oy, oz, dx, dy, dz, mid, dem, x_first, y_first, spacing)
        if abs(f_mid) < REFINE_TOLERANCE_M:
            return mid
        if f_mid < 0.0:
            hi, f_hi = mid, f_mid
            if side == -1:
                f_lo *= 0.5
            side = -1
        else:
            lo, f_lo = mid, f_mid
            if side == 1:
                f_hi *= 0.5
            side = 1
    return 0.5 * (lo + hi)


@njit(cache=True)
def _in_shadow(px, py, pz, sx, sy, sz, dem, block_max, x_first, y_first, spacing, z_max):
    """True when the terrain blocks the ray from (px, py, pz) toward the sun s.

    Marches in eighth-cell steps over the first cell, then half-cell steps; where the
    ray is above the highest node of the current block of ``SHADOW_BLOCK_CELLS`` cells
    it jumps to the block's exit (the ray only rises, so nothing in the block can
    block it).
    """
    horizontal = math.sqrt(sx * sx + sy * sy)
    if horizontal < 1e-12:
        return False
    step = MARCH_STEP_CELLS * spacing / horizontal
    dc = sx / spacing  # columns per unit of u
    dr = -sy / spacing  # rows per unit of u
    n_rows, n_cols = block_max.shape
    fine_until = 2.0 * step  # first cell: eighth-cell steps, for blockers right beside p
    u = 0.25 * step
    while True:
        z = pz + u * sz
        if z > z_max:
            return False
        fc = (px + u * sx - x_first) / spacing
        fr = (y_first - (py + u * sy)) / spacing
        h = _bilinear(dem, fc, fr)
        if np.isnan(h):
            return False
        if h > z + SHADOW_EPSILON_M:
            return True
        bi = min(int(fr) // SHADOW_BLOCK_CELLS, n_rows - 1)
        bj = min(int(fc) // SHADOW_BLOCK_CELLS, n_cols - 1)
        if z > block_max[bi, bj] + SHADOW_EPSILON_M:
            exit_u = np.inf
            if dc > 0.0:
                exit_u = min(exit_u, ((bj + 1) * SHADOW_BLOCK_CELLS - fc) / dc)
            elif dc < 0.0:
                exit_u = min(exit_u, (bj * SHADOW_BLOCK_CELLS - fc) / dc)
            if dr > 0.0:
                exit_u = min(exit_u, ((bi + 1) * SHADOW_BLOCK_CELLS - fr) / dr)
            elif dr < 0.0:
                exit_u = min(exit_u, (bi * SHADOW_BLOCK_CELLS - fr) / dr)
            u += max(exit_u + 1e-6 / horizontal, 1e-3 * step)
        else:
            u += 0.25 * step if u < fine_until else step


@njit(cache=True, nogil=True, error_model="numpy")
def _render_geometry(origins, directions, depth_axis, along_axis, dem, block_max, grad_x,
                     grad_y, albedo, x_first, y_first, spacing, z_min, z_max, sun, depth, hit,
                     mu0, mu, phase, rho, shadow, start, stop):
    """Rows ``start … stop − 1`` of :func:`view_geometry`'s arrays (``depth`` … ``shadow``,
    filled with NaN / False before: a pixel whose ray misses keeps them)."""
    width = origins.shape[1]
    for r in range(start, stop):
        for c in range(width):
            ox, oy, oz = origins[r, c, 0], origins[r, c, 1], origins[r, c, 2]
            dx, dy, dz = directions[r, c, 0], directions[r, c, 1], directions[r, c, 2]
            norm = math.sqrt(dx * dx + dy * dy + dz * dz)
            dx /= norm
            dy /= norm
            dz /= norm
            t = _intersect(ox, oy, oz, dx, dy, dz, dem, x_first, y_first, spacing, z_min, z_max)
            if np.isnan(t):
                continue
            x = ox + t * dx
            y = oy + t * dy
            z = oz + t * dz
            hit[r, c, 0] = x
            hit[r, c, 1] = y
            hit[r, c, 2] = z
            if along_axis:
                depth[r, c] = t * (depth_axis[0] * dx + depth_axis[1] * dy + depth_axis[2] * dz)
            else:
                depth[r, c] = t
            fc = (x - x_first) / spacing
            fr = (y_first - y) / spacing
            gx = _bilinear(grad_x, fc, fr)
            gy = _bilinear(grad_y, fc, fr)
            n_norm = math.sqrt(gx * gx + gy * gy + 1.0)
            nx, ny, nz = -gx / n_norm, -gy / n_norm, 1.0 / n_norm
            cos_i = nx * sun[0] + ny * sun[1] + nz * sun[2]
            mu0[r, c] = cos_i
            mu[r, c] = -(nx * dx + ny * dy + nz * dz)
            cos_phase = -(sun[0] * dx + sun[1] * dy + sun[2] * dz)
            phase[r, c] = math.degrees(math.acos(max(-1.0, min(1.0, cos_phase))))
            rho[r, c] = _bilinear(albedo, fc, fr)
            shadow[r, c] = cos_i <= 0.0 or _in_shadow(x, y, z, sun[0], sun[1], sun[2], dem,
                                                      block_max, x_first, y_first, spacing,
                                                      z_max)


@njit(cache=True, nogil=True, error_model="numpy")
def _cast_rays(origins, directions, dem, x_first, y_first, spacing, z_min, z_max, t, start,
               stop):
    """Ray parameters ``t[start:stop]`` of the first hits (NaN: a miss), per unit of
    ``directions``' length."""
    for i in range(start, stop):
        d = directions[i]
        norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        t[i] = _intersect(origins[i, 0], origins[i, 1], origins[i, 2], d[0] / norm,
                          d[1] / norm, d[2] / norm, dem, x_first, y_first, spacing, z_min,
                          z_max) / norm


def _run_kernel(kernel, *args):
    """Call a numba kernel; a Ctrl-C/SIGTERM that lands inside it stays an interrupt.

    When a Python signal handler raises while numba's dispatcher is returning, the
    dispatcher reports ``SystemError: ... returned a result with an exception set``
    with the interrupt as its cause; re-raise the interrupt so the command line
    rolls back its outputs and reports the interruption as such.
    """
    try:
        return kernel(*args)
    except SystemError as exc:
        cause: BaseException | None = exc
        for _ in range(100):  # the interrupt may sit several SystemErrors deep
            cause = cause.__cause__ or cause.__context__
            if cause is None:
                break
            if isinstance(cause, KeyboardInterrupt):
                raise cause from None
        raise


# --------------------------------------------------------------------------------------
# Public functions
# --------------------------------------------------------------------------------------


def intersect_rays(field: HeightField, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """First intersections of rays with the height field.

    Parameters
    ----------
    field : HeightField
        From :func:`height_field`.
    origins : (N, 3) float
        Ray origins, world metres (above the terrain).
    directions : (N, 3) float
        Ray directions (any length, pointing down toward the terrain).

    Returns
    -------
    (N, 3) float64
        World coordinates of the hits, metres; NaN for rays that miss the DEM.
    """
    o = np.ascontiguousarray(np.atleast_2d(origins), dtype=np.float64)
    d = np.ascontiguousarray(np.atleast_2d(directions), dtype=np.float64)
    o = np.broadcast_to(o, d.shape).copy() if o.shape != d.shape else o
    t = np.empty(o.shape[0])
    _run_kernel(on_row_parts, lambda start, stop: _cast_rays(
        o, d, field.dem, field.x_first, field.y_first, field.spacing, field.z_min,
        field.z_max, t, start, stop), o.shape[0])
    return o + t[:, None] * d


def pixel_rays(camera: SensorModel, *, placement=None, pixels: np.ndarray | None = None,
               rows: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rays of a sensor model's pixels in the scene's local frame, through the interface.

    Parameters
    ----------
    camera : SensorModel
        Any model (:meth:`~demtool.sensors.SensorModel.image_to_ray`): a pinhole in the
        local frame, or a body-fixed frame or line-scan model (each pixel its own origin
        for a line scanner).
    placement : demtool.synth.body.Placement, optional
        Where the local frame sits on the body, for body-fixed models; None for models
        already in the local frame.
    pixels : (N, 2) float, optional
        Pixel positions (u, v) = (column, row) of the pixel centres; default every pixel
        of the image, row by row.
    rows : (first, stop), optional
        Only the image rows ``first … stop − 1`` (every pixel of them), when
        ``pixels`` is None.

    Returns
    -------
    origins, directions : (h, w, 3) (every pixel; h = stop − first with ``rows``) or
        (N, 3) float64
        Local frame, metres; directions unit vectors.
    """
    if pixels is None:
        first, stop = (0, camera.lines) if rows is None else rows
        rows, cols = np.meshgrid(np.arange(first, stop, dtype=np.float64),
                                 np.arange(camera.samples, dtype=np.float64), indexing="ij")
    else:
        uv = np.atleast_2d(np.asarray(pixels, dtype=np.float64))
        cols, rows = uv[:, 0], uv[:, 1]
    origins = np.empty(np.shape(rows) + (3,))
    directions = np.empty(np.shape(rows) + (3,))
    step = RAY_BLOCK_ROWS if pixels is None else RAY_BLOCK_ROWS * 512
    for start in range(0, len(rows), step):  # blocks keep the temporaries in cache
        block = slice(start, start + step)
        ray = camera.image_to_ray(rows[block] + 0.5, cols[block] + 0.5)  # CSM: centre 0.5
        origins[block], directions[block] = ray.origin, ray.direction
    if placement is not None:
        origins = placement.to_local(origins)
        directions = placement.directions_to_local(directions)
    return np.ascontiguousarray(origins), np.ascontiguousarray(directions)


def pixel_hits(field: HeightField, camera: SensorModel, pixels: np.ndarray, *,
               placement=None) -> np.ndarray:
    """Local points (N, 3) where the rays of ``pixels`` (N, 2) (u, v) hit the terrain."""
    origins, directions = pixel_rays(camera, placement=placement, pixels=pixels)
    return intersect_rays(field, origins, directions)


class ViewGeometry(NamedTuple):
    """Per-pixel geometry of one rendered view, all (h, w), NaN where the ray misses.

    Attributes
    ----------
    depth : float64
        Camera z of the hit (metres along the optical axis) for a pinhole or a frame
        camera, as used by :meth:`PinholeCamera.backproject`; the range (metres along
        the ray) for a line scanner.
    hit : (h, w, 3) float64
        Local-frame coordinates of the hit, metres.
    mu0, mu : float64
        Cosines of the incidence and emission angles at the hit (DEM normal).
    phase_deg : float64
        Phase angle (sun–surface–camera), degrees.
    albedo : float64
        Normal albedo at the hit.
    shadow : bool
        True where the hit gets no direct sunlight: it faces away from the sun
        (attached shadow, μ0 ≤ 0) or the terrain blocks the sun (cast shadow).
    """

    depth: np.ndarray
    hit: np.ndarray
    mu0: np.ndarray
    mu: np.ndarray
    phase_deg: np.ndarray
    albedo: np.ndarray
    shadow: np.ndarray


def view_geometry(field: HeightField, albedo: np.ndarray, camera: SensorModel,
                  sun_vector: np.ndarray, *, placement=None,
                  rows: tuple[int, int] | None = None) -> ViewGeometry:
    """Cast every pixel's ray of ``camera`` onto the height field and shade-prepare it.

    The rays come from the sensor model's interface (:func:`pixel_rays`), so a pinhole,
    a frame camera or a line scanner renders the same way.

    Parameters
    ----------
    field : HeightField
        The terrain, from :func:`height_field`.
    albedo : (H, W) float
        Normal albedo on the same map grid as the DEM.
    camera : SensorModel
        The view; pixel (row r, column c) is centred at CSM (line, sample) =
        (r + 0.5, c + 0.5).
    sun_vector : (3,) float
        Unit vector toward the sun, local frame.
    placement : demtool.synth.body.Placement, optional
        The local frame on the body, for body-fixed models.
    rows : (first, stop), optional
        Only image rows ``first … stop − 1`` (the arrays are then stop − first rows
        high): large images are rendered in blocks of rows (:func:`row_blocks`).
    """
    origins, directions = pixel_rays(camera, placement=placement, rows=rows)
    sun = np.asarray(sun_vector, dtype=np.float64)
    sun = sun / np.linalg.norm(sun)
    axis = getattr(camera, "axis", None) if placement is None else None  # a pinhole's z
    if axis is None and getattr(camera, "boresight", None) is not None:  # a frame camera's
        axis = camera.boresight if placement is None else \
            placement.directions_to_local(camera.boresight)
    height, width = origins.shape[0], origins.shape[1]
    result = (np.full((height, width), np.nan), np.full((height, width, 3), np.nan),
              *(np.full((height, width), np.nan) for _ in range(4)),
              np.zeros((height, width), dtype=np.bool_))
    args = (origins, directions,
            np.zeros(3) if axis is None else np.ascontiguousarray(axis, dtype=np.float64),
            axis is not None, field.dem, field.block_max, field.grad_x, field.grad_y,
            np.ascontiguousarray(albedo, dtype=np.float64), field.x_first, field.y_first,
            field.spacing, field.z_min, field.z_max, sun, *result)
    _run_kernel(on_row_parts, lambda start, stop: _render_geometry(*args, start, stop),
                height)
    return ViewGeometry(*result)


def row_blocks(lines: int, samples: int, pixels: int = BLOCK_PIXELS) -> list[tuple[int, int]]:
    """Row ranges ``(first, stop)`` of about ``pixels`` pixels each covering ``lines`` rows
    (one block for an image of up to ``pixels`` pixels).

    A block's per-pixel geometry takes about 150 bytes a pixel (rays, hits, angles):
    ``BLOCK_PIXELS`` = 2²¹ keeps it near 300 MB whatever the image size.
    """
    step = max(1, pixels // max(1, samples))
    return [(first, min(first + step, lines)) for first in range(0, lines, step)]


def reflectance(geometry: ViewGeometry) -> np.ndarray:
    """Lunar-Lambert reflectance (McEwen 1991, eq. 4) of a view; 0 in shadow.

    Returns
    -------
    (h, w) float64
        ``R = ρ (2L μ0/(μ0+μ) + (1−L) μ0)`` with L(α) from the per-pixel phase angle;
        NaN where the ray missed the DEM.
    """
    values = lunar_lambert(np.nan_to_num(geometry.mu0), np.nan_to_num(geometry.mu),
                           np.nan_to_num(geometry.phase_deg), np.nan_to_num(geometry.albedo))
    values = np.where(geometry.shadow, 0.0, values)
    return np.where(np.isnan(geometry.depth), np.nan, values)


def expose(reflectance_map: np.ndarray, *, dn_per_reflectance: float, gain_e_per_dn: float,
           read_noise_dn: float, bit_depth: int, noise: bool,
           rng: np.random.Generator) -> np.ndarray:
    """Turn reflectance into quantised digital numbers with photon and read noise.

    The expected signal ``S = R · dn_per_reflectance`` (DN) becomes ``S · gain``
    electrons, drawn from a Poisson distribution, converted back to DN, plus Gaussian
    read noise (σ = ``read_noise_dn``); the result is rounded and clipped to
    0 … 2^bit_depth − 1.

    Returns
    -------
    (h, w) float32
        Digital numbers (integer-valued), NaN where ``reflectance_map`` is NaN.
    """
    signal = np.nan_to_num(reflectance_map) * dn_per_reflectance
    if noise:
        electrons = rng.poisson(np.clip(signal * gain_e_per_dn, 0.0, None))
        signal = electrons / gain_e_per_dn + rng.normal(0.0, read_noise_dn, signal.shape)
    counts = np.clip(np.rint(signal), 0, 2**bit_depth - 1).astype(np.float32) + np.float32(0)
    counts[np.isnan(reflectance_map)] = np.nan
    return counts
