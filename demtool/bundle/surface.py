"""A reference DEM as ground control of a sensor block (``bundle --reference-dem``).

Tie points fix the shape of a block, not its datum: a similarity (3 translations, 3
rotations, a scale) of all sensors and points leaves every image unchanged, so with
pose priors alone the block sits where the priors' mean puts it.  Mapping teams tie
the block to a reference terrain instead (LOLA for the Moon, MOLA for Mars); ASP's
``bundle_adjust --heights-from-dem`` (and ``--reference-terrain``) does it by
constraining the tie points' heights to the DEM.  Here every tie point ``X`` gets one
more residual, its height above the body's reference sphere minus the DEM's height at
its longitude and latitude (bilinear),

    r(X) = (h(X) − h_DEM(lon(X), lat(X))) / σ_DEM,

with a Huber loss, so the block's height, tilt and scale follow the DEM, and where the
terrain has relief (slopes) its horizontal position and azimuth too: a horizontal
shift ``d`` of the block changes the residuals by ``∇h_DEM · d``.

:class:`ReferenceSurface` is pure (arrays in, arrays out): the DEM's heights (a window
around the block, held in memory), its map transform and CRS on the body's sphere.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from demtool.mapproject.core import bilinear_heights
from demtool.maps import enu_frame, lonlat_to_map, wrap_longitude, xyz_to_lonlat_height

#: forward-difference step of the height residual's gradient, metres
GRADIENT_STEP_M = 0.01
#: a tie point's height error from a DEM's interpolation, in post spacings × local slope,
#: where the DEM is too small to measure it (:func:`interpolation_factor`): the RMS
#: distance to the nearest post of a square grid is 0.38 post (an upper value: it leaves
#: nothing to the curvature term)
INTERPOLATION_FACTOR = 0.4
#: fewest held-out posts for :func:`interpolation_factor`
MIN_HELD_OUT = 16
#: posts a side of the window :func:`interpolation_factor` is measured on, at least
#: (:func:`measuring_window`): 41 x 41 posts hold 1240 out, which fixes an RMS ratio to
#: about 1 / sqrt(2 · 1240) = 2 %; LOLA's 22 km posts under a 63 km footprint hold 56 out
FACTOR_POSTS = 41


@dataclass(frozen=True)
class ReferenceSurface:
    """A reference DEM on the body's map, for height residuals of body-fixed points.

    Attributes
    ----------
    heights : (H, W) float64
        Metres above the body's reference sphere (radial), NaN = no data.
    transform : affine.Affine
        Map transform of ``heights`` (pixel corner convention, as rasterio's).
    crs : pyproj.CRS
        The DEM's CRS on the body's sphere (projected, or geographic: x = lon, y = lat
        in degrees).
    radius : float
        The body's reference sphere radius, metres (heights of points are measured
        radially above it).
    sigma : float
        Standard deviation of the DEM's heights (noise, and any interpolation error
        not covered by ``post_m``), metres.
    post_m : float
        Post spacing of the DEM, metres (0: the interpolation error is left to
        ``sigma``).  A tie point's height σ is then :meth:`point_sigmas`: ``sigma``
        and ``slope_factor`` × post × local slope added in quadrature.
    slope_factor : float
        The DEM's interpolation error in post spacings × local slope beyond what its
        curvature explains (:func:`interpolation_factor` measures it on the DEM itself).
    curvature : (H, W) float64 or None
        Bilinear interpolation's error bound at each post, metres
        (:func:`curvature_error`: post² / 8 × the local second derivative, per axis);
        None: no curvature term.
    """

    heights: np.ndarray
    transform: Any
    crs: Any
    radius: float
    sigma: float
    post_m: float = 0.0
    slope_factor: float = 0.4
    curvature: np.ndarray | None = None

    def pixels(self, xyz) -> tuple[np.ndarray, np.ndarray]:
        """Fractional (row, col) of ``heights`` below body-fixed points (..., 3) metres
        (pixel centres at integers)."""
        lon, lat, _ = xyz_to_lonlat_height(np.asarray(xyz, dtype=np.float64),
                                           radii=self.radius)
        if self.crs.is_geographic:
            t = self.transform
            x = wrap_longitude(lon, t.c + 0.5 * t.a * self.heights.shape[1])
            y = lat
        else:
            x, y = lonlat_to_map(self.crs, lon, lat)
        inv = ~self.transform
        col = inv.a * x + inv.b * y + inv.c - 0.5
        row = inv.d * x + inv.e * y + inv.f - 0.5
        return row, col

    def dem_heights(self, xyz) -> np.ndarray:
        """DEM heights (metres above the sphere, bilinear) below body-fixed points
        (..., 3) metres; NaN off the DEM or on its no-data cells."""
        row, col = self.pixels(xyz)
        good = np.isfinite(row) & np.isfinite(col)
        out = np.full(np.shape(row), np.nan)
        if np.any(good):
            out[good] = bilinear_heights(self.heights, row[good], col[good])
        return out

    def post_spacing_m(self, xyz) -> float:
        """The DEM's post spacing (metres) at a body-fixed point (3,): the geometric mean
        of its cells' ground extents there."""
        xyz = np.asarray(xyz, dtype=np.float64).reshape(3)
        east, north, _ = local_axes(xyz)
        row, col = self.pixels(np.stack([xyz, xyz + east, xyz + north]))
        along = np.array([[col[1] - col[0], row[1] - row[0]], [col[2] - col[0], row[2] - row[0]]])
        return float(1.0 / np.sqrt(abs(np.linalg.det(along))))

    def coarsened(self, factor: int, *, rows_per_chunk: int = 256) -> ReferenceSurface:
        """This DEM averaged over ``factor × factor`` posts (a pyramid level; a block with
        fewer than half its posts on data is no data), read in chunks of block rows so a
        large window needs no full-size temporary."""
        if factor <= 1:
            return self
        from affine import Affine

        rows, cols = (n // factor for n in self.heights.shape)
        out = np.full((rows, cols), np.nan)
        for r0 in range(0, rows, rows_per_chunk):
            r1 = min(rows, r0 + rows_per_chunk)
            blocks = self.heights[r0 * factor:r1 * factor, :cols * factor].reshape(
                r1 - r0, factor, cols, factor)
            valid = np.isfinite(blocks)
            count = valid.sum(axis=(1, 3))
            total = np.where(valid, blocks, 0.0).sum(axis=(1, 3))
            with np.errstate(invalid="ignore", divide="ignore"):
                out[r0:r1] = np.where(count * 2 >= factor * factor, total / count, np.nan)
        return ReferenceSurface(out, self.transform @ Affine.scale(factor), self.crs,
                                self.radius, self.sigma, self.post_m * factor,
                                self.slope_factor,
                                None if self.curvature is None else curvature_error(out))

    def point_sigmas(self, xyz, gradient=None) -> np.ndarray:
        """Standard deviation (P,) metres of the DEM's height at body-fixed points (P, 3):
        ``sqrt(sigma² + (slope_factor · post_m · slope)² + curvature²)``.

        A gridded DEM (LOLA, MOLA) is a smoothed sample of the ground at its posts, and
        a tie point between posts is compared with the DEM's bilinear interpolation.
        Where the ground the DEM resolves is curved, that interpolation errs by up to
        ``h²/8 · |f''|`` per axis (linear interpolation's error bound, ``|f − p| ≤
        h²/8 · max|f''|`` over a post interval ``h``; Burden & Faires, Numerical
        Analysis, Thm 3.3; for the tensor-product bilinear interpolant the two axes'
        bounds add, de Boor, A Practical Guide to Splines, ch. XVII), the curvature
        term: large on crater floors and rims, where the interpolant lies above or below
        the ground, and nil on planar slopes, which bilinear interpolation reproduces.
        What the DEM cannot show lies within a post and changes the height by a share of
        the local slope times the post spacing, the slope term (cf. ASP
        ``bundle_adjust --heights-from-dem-uncertainty``, which the user sets by hand);
        ``slope_factor`` is the share the curvature term leaves unexplained, measured on
        the DEM itself (:func:`interpolation_factor`).  Slope and curvature are the
        DEM's own, at its posts (``gradient``: the height residuals' gradient of
        :meth:`residuals_and_gradient`, whose horizontal part is minus the DEM's
        gradient; the curvature bound interpolated bilinearly between posts).
        """
        xyz = np.asarray(xyz, dtype=np.float64)
        if self.post_m <= 0 and self.curvature is None:
            return np.full(len(xyz), float(self.sigma))
        variance = np.full(len(xyz), float(self.sigma) ** 2)
        if self.post_m > 0:
            if gradient is None:
                _, gradient = self.residuals_and_gradient(xyz)
            up = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
            horizontal = gradient - np.sum(gradient * up, axis=1, keepdims=True) * up
            slope = np.linalg.norm(np.where(np.isfinite(horizontal), horizontal, 0.0), axis=1)
            variance += (self.slope_factor * self.post_m * slope) ** 2
        if self.curvature is not None:
            row, col = self.pixels(xyz)
            good = np.isfinite(row) & np.isfinite(col)
            bound = np.zeros(len(xyz))
            if np.any(good):
                bound[good] = bilinear_heights(self.curvature, row[good], col[good])
            variance += np.where(np.isfinite(bound), bound, 0.0) ** 2
        return np.sqrt(variance)

    def normalised_residuals(self, xyz) -> np.ndarray:
        """Height residuals of :meth:`residuals` in units of :meth:`point_sigmas`."""
        xyz = np.asarray(xyz, dtype=np.float64)
        if self.post_m <= 0 and self.curvature is None:
            return self.residuals(xyz) / self.sigma
        r, gradient = self.residuals_and_gradient(xyz)
        return r / self.point_sigmas(xyz, gradient)

    def residuals(self, xyz) -> np.ndarray:
        """``h(X) − h_DEM(X)`` of body-fixed points (P, 3), metres; NaN off the DEM."""
        xyz = np.asarray(xyz, dtype=np.float64)
        _, _, height = xyz_to_lonlat_height(xyz, radii=self.radius)
        return height - self.dem_heights(xyz)

    def residuals_and_gradient(self, xyz) -> tuple[np.ndarray, np.ndarray]:
        """Height residuals (P,) metres and their gradient (P, 3) with respect to the
        points (forward differences of :data:`GRADIENT_STEP_M`); NaN rows off the DEM."""
        xyz = np.asarray(xyz, dtype=np.float64)
        base = self.residuals(xyz)
        gradient = np.empty(xyz.shape)
        for k in range(3):
            moved = xyz.copy()
            moved[:, k] += GRADIENT_STEP_M
            gradient[:, k] = (self.residuals(moved) - base) / GRADIENT_STEP_M
        return base, gradient


def curvature_error(heights: np.ndarray) -> np.ndarray:
    """Bilinear interpolation's error bound at each post of a DEM, metres.

    Linear interpolation over an interval ``h`` errs by at most ``h²/8 · max|f''|``
    (Burden & Faires, Numerical Analysis, Thm 3.3); bilinear interpolation, the tensor
    product of two, by at most the sum of the bounds along its two axes.  With the
    second derivative taken as the DEM's second difference over its posts,
    ``f'' ≈ Δ²h / h²``, each axis's bound is ``|Δ²h| / 8`` whatever the spacing (so
    a geographic grid's unequal axes need none either).

    Parameters
    ----------
    heights : (H, W) float64
        The DEM, metres (NaN = no data).

    Returns
    -------
    (H, W) float64
        ``(|h[r, c−1] − 2 h[r, c] + h[r, c+1]| + |h[r−1, c] − 2 h[r, c] + h[r+1, c]|) / 8``;
        a border post takes its inner neighbour's second difference, an axis shorter than
        3 posts adds nothing, NaN next to no data.
    """
    h = np.asarray(heights, dtype=np.float64)
    total = np.zeros(h.shape)
    for axis in (0, 1):
        if h.shape[axis] < 3:
            continue
        moved = np.moveaxis(h, axis, 0)
        second = np.empty(moved.shape)
        second[1:-1] = moved[2:] - 2.0 * moved[1:-1] + moved[:-2]
        second[0], second[-1] = second[1], second[-2]
        total += np.abs(np.moveaxis(second, 0, axis))
    return total / 8.0


def _held_out(values: np.ndarray) -> np.ndarray:
    """Bilinear prediction of the odd-row or odd-column posts of ``values`` from its
    even rows and columns (NaN at the even posts themselves)."""
    pred = np.full(values.shape, np.nan)
    v = values
    pred[1::2, 1::2] = 0.25 * (v[:-1:2, :-1:2] + v[2::2, :-1:2] + v[:-1:2, 2::2] + v[2::2, 2::2])
    pred[1::2, ::2] = 0.5 * (v[:-1:2, ::2] + v[2::2, ::2])
    pred[::2, 1::2] = 0.5 * (v[::2, :-1:2] + v[::2, 2::2])
    return pred


def interpolation_factor(heights: np.ndarray) -> float:
    """A DEM's interpolation error in post spacings × local slope beyond its curvature
    term, measured on itself.

    The posts of odd rows or columns are held out and predicted (bilinearly: the mean
    of their two or four neighbours) from the grid of even rows and columns, twice as
    coarse.  The coarse grid's own curvature bound (:func:`curvature_error`, interpolated
    to the held-out posts as the heights are) accounts for part of the error; the rest,
    RMS over RMS (2 posts × local slope), is the factor at that spacing (0 where the
    curvature accounts for all of it), taken for the DEM's own (a terrain whose relief
    grows with the scale in proportion, self-similar; Mandelbrot 1982, and the fractal
    lunar topography of Rosenburg et al. 2011, JGR 116, E02001, Hurst exponents
    0.76–0.95 at 0.1–10 km, where it is close to proportional).
    :data:`INTERPOLATION_FACTOR` where fewer than :data:`MIN_HELD_OUT` posts can be held
    out.

    Parameters
    ----------
    heights : (H, W) float64
        The DEM, metres (NaN = no data); the slope is taken per post, so only the
        ratio matters and no spacing is needed.
    """
    h = np.asarray(heights, dtype=np.float64)
    rows, cols = (n - 1 - (n - 1) % 2 for n in h.shape)  # the last even index
    if rows < 2 or cols < 2:
        return INTERPOLATION_FACTOR
    h = h[:rows + 1, :cols + 1]
    gy, gx = np.gradient(h)
    slope = np.hypot(gx, gy)  # metres per post
    error = h - _held_out(h)
    coarse = np.full(h.shape, np.nan)
    coarse[::2, ::2] = curvature_error(h[::2, ::2])
    curved = _held_out(coarse)
    use = np.isfinite(error) & np.isfinite(slope) & np.isfinite(curved)
    if use.sum() < MIN_HELD_OUT or not np.any(slope[use] > 0):
        return INTERPOLATION_FACTOR
    unexplained = max(float(np.sum(error[use] ** 2) - np.sum(curved[use] ** 2)), 0.0)
    return float(np.sqrt(unexplained / np.sum((2.0 * slope[use]) ** 2)))


def measuring_window(window: tuple[int, int, int, int], shape: tuple[int, int],
                     posts: int = FACTOR_POSTS) -> tuple[int, int, int, int]:
    """``window`` (row0, row1, col0, col1, half-open) of a DEM of ``shape`` grown about
    its centre to at least ``posts`` a side where the DEM allows (a window already
    larger stays as it is): the posts :func:`interpolation_factor` is measured on."""
    out = []
    for (start, stop), size in zip((window[:2], window[2:]), shape, strict=True):
        if stop - start < posts:
            start = max(0, min((start + stop - posts) // 2, size - posts))
            stop = min(size, start + posts)
        out += [start, stop]
    return tuple(out)


def local_axes(xyz) -> np.ndarray:
    """(3, 3): rows the east, north and up unit vectors at a body-fixed point (3,)
    (:func:`demtool.maps.enu_frame`; radial up)."""
    xyz = np.asarray(xyz, dtype=np.float64).reshape(3)
    lon, lat, _ = xyz_to_lonlat_height(xyz, radii=float(np.linalg.norm(xyz)))
    return enu_frame(lon, lat)


@dataclass(frozen=True)
class SurfaceShift:
    """A translation that puts a point cloud onto a reference DEM
    (:func:`register_points`).

    Attributes
    ----------
    shift : (3,) float64
        Body-fixed metres to add to the points (and to the sensors that see them).
    east_m, north_m, up_m : float
        The same in the local frame at the points' centre.
    spread_m, spread_before_m : float
        Robust spread (1.4826 × median absolute deviation) of the points' height
        residuals after and before the shift, metres.
    searched_m : float
        Radius of the horizontal search, metres.
    used : bool
        Whether an adjustment started from it (:func:`demtool.bundle.priors.
        adjust_with_priors` keeps it only where its solution costs less).
    """

    shift: np.ndarray
    east_m: float
    north_m: float
    up_m: float
    spread_m: float
    spread_before_m: float
    searched_m: float
    used: bool = True


#: shifts per axis and side of each level of the horizontal search
SEARCH_STEPS = 10


def _spread(surface: ReferenceSurface, points: np.ndarray, offsets: np.ndarray,
            min_fraction: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Median and robust spread of the height residuals (S,) of ``points`` (P, 3) moved
    by each of ``offsets`` (S, 3); spread inf where fewer than ``min_fraction`` of the
    points lie on the DEM's data."""
    moved = points[None, :, :] + offsets[:, None, :]
    r = surface.residuals(moved.reshape(-1, 3)).reshape(len(offsets), len(points))
    enough = np.mean(np.isfinite(r), axis=1) >= min_fraction
    median = np.full(len(offsets), np.nan)
    spread = np.full(len(offsets), np.inf)
    if np.any(enough):
        median[enough] = np.nanmedian(r[enough], axis=1)
        spread[enough] = 1.4826 * np.nanmedian(np.abs(r[enough] - median[enough, None]),
                                               axis=1)
    return median, spread


def register_points(surface: ReferenceSurface, points: np.ndarray, *, radius_m: float,
                    max_points: int = 4000, seed: int = 0) -> SurfaceShift | None:
    """The translation within ``radius_m`` (horizontally) that best puts points onto the
    DEM: the least robust spread of their height residuals, then their median height
    offset removed.

    The least-squares adjustment ties points to the DEM through its local slopes, so it
    only finds the DEM's fit from within a fraction of the terrain's smallest features;
    sensor positions off by more (SPICE of a narrow-angle camera, tens to hundreds of
    pixels) converge on a wrong fit with perfect residuals.  As ASP aligns a cloud to a
    reference DEM before ``bundle_adjust`` (``pc_align`` with ``--max-displacement``),
    the cloud is first registered by a search: a grid of 2·SEARCH_STEPS + 1 shifts per
    axis over the whole radius on the DEM averaged over posts as long as the grid's
    step (a pyramid level, so a coarse step sees no aliased detail), then around the
    best with steps a quarter as long, down to a quarter of the DEM's post spacing.

    Parameters
    ----------
    surface : ReferenceSurface
    points : (P, 3) float64
        Body-fixed metres (e.g. tie points triangulated with the prior models).
    radius_m : float
        Horizontal search radius, metres (the priors' ground uncertainty, 3 σ).
    max_points : int
        Points used (an even subsample of more).
    seed : int
        Seed of that subsample.

    Returns
    -------
    SurfaceShift or None
        None when fewer than half of the points lie on the DEM at every shift.
    """
    points = np.asarray(points, dtype=np.float64)
    points = points[np.all(np.isfinite(points), axis=1)]
    if len(points) > max_points:
        points = points[np.random.default_rng(seed).choice(len(points), max_points,
                                                           replace=False)]
    if len(points) < 3:
        return None
    centre = points.mean(axis=0)
    east, north, up = local_axes(centre)
    post = surface.post_spacing_m(centre)
    _, spread0 = _spread(surface, points, np.zeros((1, 3)))
    best = np.zeros(2)
    half, step = radius_m, max(radius_m / SEARCH_STEPS, 0.25 * post)
    while True:
        coarse = surface.coarsened(int(step // post))
        k = int(np.ceil(half / step))
        grid = np.arange(-k, k + 1) * step
        de, dn = np.meshgrid(best[0] + grid, best[1] + grid, indexing="ij")
        inside = np.hypot(de, dn) <= radius_m + 1e-9
        de, dn = de[inside], dn[inside]
        _, spread = _spread(coarse, points, de[:, None] * east + dn[:, None] * north)
        if not np.isfinite(spread).any():
            return None
        # equal spreads (flat ground, no data to tell) keep the shift nearest the last
        # level's best, then nearest the priors
        pick = int(np.argmin(spread + 1e-9 * np.hypot(de - best[0], dn - best[1])
                             + 1e-9 * np.hypot(de, dn)))
        best = np.array([de[pick], dn[pick]])
        if step <= 0.25 * post:
            break
        half, step = 2.0 * step, max(step / 4.0, 0.25 * post)
    horizontal = best[0] * east + best[1] * north
    median, spread = _spread(surface, points, horizontal[None, :])
    if not np.isfinite(spread[0]):
        return None
    shift = horizontal - median[0] * up
    return SurfaceShift(shift=shift, east_m=float(best[0]), north_m=float(best[1]),
                        up_m=float(-median[0]), spread_m=float(spread[0]),
                        spread_before_m=float(spread0[0]), searched_m=float(radius_m))


def huber_weights(normalised: np.ndarray, threshold: float) -> np.ndarray:
    """IRLS weights of a Huber loss of residuals in sigma units (Huber 1964): 1 inside
    ``threshold``, ``threshold / |r|`` outside; 0 for NaN residuals (no DEM)."""
    r = np.abs(np.asarray(normalised, dtype=np.float64))
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(r <= threshold, 1.0, threshold / r)
    return np.where(np.isfinite(r), w, 0.0)


def huber_cost(normalised: np.ndarray, threshold: float) -> float:
    """Σ ρ(r) of residuals in sigma units, ρ the Huber loss scaled as r² inside the
    threshold (NaN residuals count 0)."""
    r = np.abs(np.asarray(normalised, dtype=np.float64))
    r = r[np.isfinite(r)]
    return float(np.sum(np.where(r <= threshold, r ** 2, 2 * threshold * r - threshold ** 2)))


def surface_normal_equations(surface: ReferenceSurface, points: np.ndarray, *,
                             threshold: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The reference DEM's share of the point blocks of the normal equations.

    Returns
    -------
    v : (P, 3, 3) float64
        ``w J Jᵀ / σ²`` to add to each point's block.
    g : (P, 3) float64
        ``−w J r / σ²`` to add to each point's gradient side.
    residuals : (P,) float64
        Height residuals, metres (NaN off the DEM).
    """
    r, jac = surface.residuals_and_gradient(points)
    sigma = surface.point_sigmas(points, jac)
    w = huber_weights(r / sigma, threshold) / sigma ** 2
    jac = np.where(np.isfinite(jac), jac, 0.0)
    rr = np.where(np.isfinite(r), r, 0.0)
    v = w[:, None, None] * jac[:, :, None] * jac[:, None, :]
    g = -(w * rr)[:, None] * jac
    return v, g, r
