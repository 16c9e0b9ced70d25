"""Pixels between the matched grid nodes: where to interpolate, and a sub-pixel refinement.

With a grid spacing ``s > 1`` :func:`demtool.match.match` runs NCC + LSM only on every
``s``-th row and column.  :func:`between_nodes` says which pixels lie between four
accepted nodes that agree (bilinear interpolation holds there) and which lie at a
disparity edge (matched themselves).  :func:`refine_translation` then refines the
interpolated disparity of every such pixel with its own template: a translation-only
inverse-compositional Gauss–Newton (IC-GN) on the zero-normalised SSD, from the
interpolated start, with the template's affine shape fixed to the local disparity
slope of the node grid.  The template gradients are computed once for the whole
image (Barron's four-point differences, as in :mod:`demtool.match.icgn`) and the 2 × 2
Hessian is a weighted sum of their products, so one iteration costs one resampling of
the right window: a few times cheaper than Grün's 8-parameter LSM at a node, and it
recovers the detail finer than the node spacing that the interpolation smooths away.

The IC-GN update with the warp ``W(u) = A u + t`` (``A`` fixed, ``t`` the translation)::

    e(u) = (f(u) − f̄) − (Δf / Δg) (g(W(u)) − ḡ)
    δ    = H⁻¹ Σ w ∇f(u) e(u),   H = Σ w ∇f ∇fᵀ
    t    ← t + A δ                                  (W ← W ∘ W(−δ)⁻¹)

References
----------
Baker, S., Matthews, I. (2004). Lucas-Kanade 20 years on: a unifying framework.
    IJCV 56(3), 221-255 (section 3.2, the inverse compositional algorithm).
Pan, B., Li, K., Tong, W. (2013). Fast, robust and accurate digital image correlation
    calculation without redundant computations. Experimental Mechanics 53, 1277-1289.
"""

from __future__ import annotations

import time
import warnings
from typing import NamedTuple

import numpy as np
from numba import njit

from demtool.logs import get_logger
from demtool.match.icgn import _cubic_value, _gradient
from demtool.match.lsm import cubic_support_mask, template_weights
from demtool.match.lsm_base import _FASTMATH
from demtool.match.ncc import integral_invalid
from demtool.tiling.rows import on_row_parts

log = get_logger(__name__)

#: Largest change (pixels) of a disparity that :func:`polish` accepts from its refinement;
#: a larger step from one Gauss–Newton iteration is not trusted.
POLISH_MAX_STEP = 0.5


def between_nodes(nodes: np.ndarray, shape: tuple[int, int], spacing: int,
                  tolerance: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where node disparities may be interpolated, and the pixels to match instead.

    Parameters
    ----------
    nodes : (n_rows, n_cols) float
        Disparities of the grid nodes (rows/cols multiples of ``spacing``), NaN =
        not accepted.
    shape : (H, W)
        Image shape.
    spacing : int
        Node spacing, pixels (> 1).
    tolerance : float
        Largest spread (max − min, pixels) of the four corner disparities that is
        interpolated; a larger spread marks a disparity edge.

    Returns
    -------
    weights : (4, H, W) float64
        Bilinear weights of the corners (i0 j0, i0 j1, i1 j0, i1 j1).
    corners : (4, H, W) int64
        Flat node index of each corner.
    smooth : (H, W) bool
        All four corners accepted and within ``tolerance`` of each other (or the
        pixel is an accepted node): bilinear interpolation holds.
    edge : (H, W) bool
        Not a node, not ``smooth``, but at least one corner accepted: the pixel is
        matched itself.
    """
    height, width = shape
    n_rows, n_cols = nodes.shape
    rows = np.arange(height)
    cols = np.arange(width)
    i0 = np.minimum(rows // spacing, n_rows - 1)
    j0 = np.minimum(cols // spacing, n_cols - 1)
    i1 = np.minimum(i0 + 1, n_rows - 1)
    j1 = np.minimum(j0 + 1, n_cols - 1)
    fy = ((rows - i0 * spacing) / spacing)[:, None]
    fx = ((cols - j0 * spacing) / spacing)[None, :]
    weights = np.stack(np.broadcast_arrays((1 - fy) * (1 - fx), (1 - fy) * fx, fy * (1 - fx),
                                           fy * fx))
    corners = np.stack(np.broadcast_arrays(i0[:, None] * n_cols + j0[None, :],
                                           i0[:, None] * n_cols + j1[None, :],
                                           i1[:, None] * n_cols + j0[None, :],
                                           i1[:, None] * n_cols + j1[None, :]))
    values = nodes.ravel()[corners]
    finite = np.isfinite(values)
    # pixels past the last node row/column have no second corner to interpolate with
    beyond = (rows > (n_rows - 1) * spacing)[:, None] | (cols > (n_cols - 1) * spacing)[None, :]
    on_node = ((rows % spacing == 0)[:, None] & (cols % spacing == 0)[None, :]) & ~beyond
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN corners
        spread = np.nanmax(values, axis=0) - np.nanmin(values, axis=0)
    smooth = (finite.all(axis=0) & (spread <= tolerance) & ~beyond) | (on_node & finite[0])
    edge = ~smooth & finite.any(axis=0) & ~on_node  # a rejected node was tried already
    return weights, corners, smooth, edge


def spread_nodes(nodes: np.ndarray, weights: np.ndarray, corners: np.ndarray,
                 smooth: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of per-node values where :func:`between_nodes` says smooth.

    Parameters
    ----------
    nodes : (n_rows, n_cols, ...) float
        A value (or a vector of values) per grid node; NaN = not accepted.
    weights, corners, smooth
        As returned by :func:`between_nodes` for an image of shape (H, W).

    Returns
    -------
    (H, W, ...) float64
        The interpolated values on ``smooth`` pixels, NaN elsewhere.
    """
    n_rows, n_cols = nodes.shape[:2]
    flat = nodes.reshape(n_rows * n_cols, -1)
    values = flat[corners]  # (4, H, W, K)
    total = np.sum(weights[..., None] * np.where(np.isfinite(values), values, 0.0), axis=0)
    out = np.where(smooth[..., None], total, np.nan)
    return out.reshape(smooth.shape + nodes.shape[2:])


@njit(cache=True, nogil=True, error_model="numpy")
def _gradients(left: np.ndarray, left_ok: np.ndarray, gx: np.ndarray, gy: np.ndarray,
               start: int, stop: int) -> None:
    """Barron four-point x and y derivatives of ``left`` at the valid pixels of rows
    ``start … stop − 1`` into ``gx``, ``gy`` (zeros: left at 0 elsewhere)."""
    width = left.shape[1]
    for r in range(start, stop):
        for c in range(width):
            if left_ok[r, c]:
                gx[r, c] = _gradient(left, left_ok, r, c, 0, 1)
                gy[r, c] = _gradient(left, left_ok, r, c, 1, 0)


def gradients(left: np.ndarray, left_ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Barron four-point x and y derivatives (per pixel) of ``left`` (H, W) float64 at
    every ``left_ok`` pixel, 0 elsewhere: two (H, W) float64 arrays."""
    gx = np.zeros(left.shape)
    gy = np.zeros(left.shape)
    on_row_parts(lambda start, stop: _gradients(left, left_ok, gx, gy, start, stop),
                 left.shape[0])
    return gx, gy


@njit(cache=True, inline="always")
def _box_clean(table: np.ndarray, r0: int, c0: int, r1: int, c1: int) -> bool:
    """True when rows r0 … r1 and columns c0 … c1 (inclusive) lie inside ``table``'s
    image and hold no invalid pixel (``table``: :func:`demtool.match.ncc.integral_invalid`)."""
    if r0 < 0 or c0 < 0 or r1 >= table.shape[0] - 1 or c1 >= table.shape[1] - 1:
        return False
    return (table[r1 + 1, c1 + 1] - table[r0, c1 + 1] - table[r1 + 1, c0]
            + table[r0, c0]) == 0


@njit(cache=True, fastmath=_FASTMATH)
def _refine_one(left, left_table, gx, gy, right, right_table4, row, col, x0, y0, a1, a2, b1,
                b2, half, iterations, weights, result):
    """Translation IC-GN of the template at (row, col); ``result`` = x, y, correlation, ok.

    ``left_table`` / ``right_table4``: summed-area tables of the invalid left pixels and
    of the right pixels without a valid 4 × 4 cubic support, so that each window is
    checked once, not per sample.  ``ok`` is 1.0 when every iteration found valid data
    and a non-singular Hessian, else 0.0 (and x, y are the start).  The correlation is
    that of the last resampled window (before the last update).
    """
    result[0] = x0
    result[1] = y0
    result[2] = np.nan
    result[3] = 0.0
    if not _box_clean(left_table, row - half, col - half, row + half, col + half):
        return
    sw = 0.0
    sf = 0.0
    sff = 0.0
    hxx = 0.0
    hxy = 0.0
    hyy = 0.0
    mx = 0.0  # Σ w fx
    my = 0.0
    cx = 0.0  # Σ w fx f
    cy = 0.0
    for v in range(-half, half + 1):
        for u in range(-half, half + 1):
            r = row + v
            c = col + u
            w = weights[v + half, u + half]
            f = left[r, c]
            fx = gx[r, c]
            fy = gy[r, c]
            sw += w
            sf += w * f
            sff += w * f * f
            hxx += w * fx * fx
            hxy += w * fx * fy
            hyy += w * fy * fy
            mx += w * fx
            my += w * fy
            cx += w * fx * f
            cy += w * fy * f
    f_mean = sf / sw
    var_f = sff - sf * f_mean
    det = hxx * hyy - hxy * hxy
    if var_f <= 1e-12 * max(1.0, sff) or det <= 1e-12 * max(1.0, hxx * hyy):
        return
    cx -= f_mean * mx  # Σ w fx (f − f̄)
    cy -= f_mean * my
    ex = half * (abs(a1) + abs(a2))  # half extents of the warped template
    ey = half * (abs(b1) + abs(b2))
    x = x0
    y = y0
    corr = np.nan
    for _ in range(iterations):
        if not _box_clean(right_table4, int(np.floor(y - ey)), int(np.floor(x - ex)),
                          int(np.floor(y + ey)), int(np.floor(x + ex))):
            return
        sg = 0.0
        sgg = 0.0
        sfg = 0.0
        sxg = 0.0
        syg = 0.0
        for v in range(-half, half + 1):
            for u in range(-half, half + 1):
                xs = x + a1 * u + a2 * v
                ys = y + b1 * u + b2 * v
                xi = int(np.floor(xs))
                yi = int(np.floor(ys))
                g = _cubic_value(right, xi, yi, xs - xi, ys - yi)
                w = weights[v + half, u + half]
                wg = w * g
                sg += wg
                sgg += wg * g
                sfg += wg * left[row + v, col + u]
                sxg += wg * gx[row + v, col + u]
                syg += wg * gy[row + v, col + u]
        g_mean = sg / sw
        var_g = sgg - sg * g_mean
        if var_g <= 1e-12 * max(1.0, sgg):
            return
        corr = (sfg - f_mean * sg) / np.sqrt(var_f * var_g)
        scale = np.sqrt(var_f / var_g)
        rx = cx - scale * (sxg - g_mean * mx)  # Σ w fx e
        ry = cy - scale * (syg - g_mean * my)
        dx = (hyy * rx - hxy * ry) / det
        dy = (hxx * ry - hxy * rx) / det
        x += a1 * dx + a2 * dy
        y += b1 * dx + b2 * dy
    result[0] = x
    result[1] = y
    result[2] = corr
    result[3] = 1.0


@njit(cache=True, nogil=True)
def _refine_batch(left, left_table, gx, gy, right, right_table4, rows, cols, x0, y0, affine,
                  half, iterations, weights, out, start, stop):
    """:func:`_refine_one` over templates ``start … stop − 1``; run over row parts by
    :func:`demtool.tiling.rows.on_row_parts`."""
    for k in range(start, stop):
        _refine_one(left, left_table, gx, gy, right, right_table4, rows[k], cols[k], x0[k],
                    y0[k], affine[k, 0], affine[k, 1], affine[k, 2], affine[k, 3], half,
                    iterations, weights, out[k])


class Refined(NamedTuple):
    """Result of :func:`refine_translation` for N template centres.

    Attributes
    ----------
    x_right, y_right : (N,) float64
        Refined position (column, row) in the right image, pixels; the start where
        ``ok`` is False.
    correlation : (N,) float64
        Weighted correlation coefficient of the template and the last resampled right
        window (−1 … 1); NaN where ``ok`` is False.
    ok : (N,) bool
        The template and every resampled window lay on valid data and had texture.
    """

    x_right: np.ndarray
    y_right: np.ndarray
    correlation: np.ndarray
    ok: np.ndarray


def refine_translation(left: np.ndarray, right: np.ndarray, rows: np.ndarray,
                       cols: np.ndarray, x_start: np.ndarray, y_start: np.ndarray,
                       affine: np.ndarray, *, template: int,
                       weighting: float, iterations: int = 1,
                       left_valid: np.ndarray | None = None,
                       right_valid: np.ndarray | None = None) -> Refined:
    """Refine approximate matches of left templates by translation-only IC-GN.

    Parameters
    ----------
    left, right : (H, W), (H2, W2) float
        Rectified grey images (any DN scale); NaN = nodata.  Not modified.
    rows, cols : (N,) int
        Template centres (row, column) in the left image.
    x_start, y_start : (N,) float
        Start position (column, row) of each centre in the right image, within a
        fraction of a pixel (e.g. interpolated between matched nodes).
    affine : (N, 4) float
        The template's affine shape in the right image, ``a1, a2, b1, b2`` of
        ``x' = x + a1 u + a2 v``, ``y' = y + b1 u + b2 v`` (Grün 1985, eq. 10; e.g.
        interpolated between the LSM solutions of the nodes); held fixed.
    template : int
        Template size, pixels (odd).
    weighting : float
        Gaussian observation weights of this σ, pixels (0 = uniform), as in
        :func:`demtool.match.lsm.lsm_match`.
    iterations : int
        Gauss–Newton iterations (each one resampling of the right window).
    left_valid, right_valid : (H, W), (H2, W2) bool, optional
        True where the pixel may be used (default: finite).

    Returns
    -------
    Refined
    """
    if template < 5 or template % 2 == 0:
        raise ValueError(f"template must be odd and >= 5, got {template}")
    if iterations < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations}")
    left = np.asarray(left, dtype=np.float64)
    right = np.asarray(right, dtype=np.float64)
    left_ok = np.isfinite(left) if left_valid is None else (left_valid & np.isfinite(left))
    right_ok = np.isfinite(right) if right_valid is None else (right_valid & np.isfinite(right))
    left_filled = np.where(left_ok, left, 0.0)
    right_filled = np.where(right_ok, right, 0.0)
    n = np.asarray(rows).shape[0]
    out = np.empty((n, 4), dtype=np.float64)
    if n:
        gx, gy = gradients(left_filled, left_ok)

        def f64(a):
            return np.ascontiguousarray(a, dtype=np.float64)

        args = (left_filled, integral_invalid(left_ok), gx, gy, right_filled,
                integral_invalid(cubic_support_mask(right_ok)),
                np.ascontiguousarray(rows, dtype=np.int64),
                np.ascontiguousarray(cols, dtype=np.int64), f64(x_start), f64(y_start),
                f64(affine).reshape(n, 4), template // 2, int(iterations),
                template_weights(template, weighting), out)
        on_row_parts(lambda start, stop: _refine_batch(*args, start, stop), n)
    return Refined(x_right=out[:, 0], y_right=out[:, 1], correlation=out[:, 2],
                   ok=out[:, 3] > 0.5)


def polish(left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
           correlation: np.ndarray, warp: np.ndarray, *, template: int, weighting: float,
           threshold: float, max_vertical: float, iterations: int, left_valid: np.ndarray,
           right_valid: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
    """Refine every disparity that has a template shape by :func:`refine_translation`.

    Matched pixels start from their own LSM solution, interpolated ones from the
    bilinear interpolation of the nodes' disparities and shapes.  A refined value
    replaces the start where the refinement found valid data, the correlation reaches
    ``threshold``, the disparity moved at most ``POLISH_MAX_STEP`` px and the row
    offset stays within ``max_vertical``; elsewhere the start is kept.

    Parameters
    ----------
    left, right : (H, W) float
        The rectified pair; NaN = nodata.
    disparity, correlation : (H, W) float
        Disparity (px, ``x_right = x_left − d``, NaN = none) and its correlation.
    warp : (H, W, 5) float
        Per pixel: the row offset ``y_right − row`` (px) and the affine shape
        ``a1, a2, b1, b2`` of its match (NaN = unknown: not refined).
    template, weighting, threshold, max_vertical
        As in :func:`demtool.match.match`.
    iterations : int
        Gauss–Newton iterations.
    left_valid, right_valid : (H, W) bool
        True where the pixel may be used.

    Returns
    -------
    disparity, correlation : (H, W) float64
        Updated copies.
    stats : dict
        Pixels tried and refined, the RMS change (px), seconds.
    """
    started = time.perf_counter()
    rows, cols = np.nonzero(np.isfinite(disparity) & np.isfinite(warp).all(axis=-1)
                            & left_valid)
    start = disparity[rows, cols]
    shape = warp[rows, cols]
    found = refine_translation(left, right, rows, cols, cols - start, rows + shape[:, 0],
                               shape[:, 1:], template=template, weighting=weighting,
                               iterations=iterations, left_valid=left_valid,
                               right_valid=right_valid)
    refined = cols - found.x_right
    with np.errstate(invalid="ignore"):
        ok = (found.ok & (found.correlation >= threshold)
              & (np.abs(refined - start) <= POLISH_MAX_STEP)
              & (np.abs(found.y_right - rows) <= max_vertical))
    disparity = np.array(disparity, dtype=np.float64)
    correlation = np.array(correlation, dtype=np.float64)
    disparity[rows[ok], cols[ok]] = refined[ok]
    correlation[rows[ok], cols[ok]] = found.correlation[ok]
    change = refined[ok] - start[ok]
    stats = {"tried": int(rows.size), "refined": int(ok.sum()),
             "rms_change_px": round(float(np.sqrt(np.mean(change ** 2))), 4) if ok.any()
             else None, "time_s": round(time.perf_counter() - started, 3)}
    log.info("refined %d of %d disparities (IC-GN, %d iteration(s)), RMS change %s px",
             stats["refined"], stats["tried"], iterations, stats["rms_change_px"])
    return disparity, correlation, stats
