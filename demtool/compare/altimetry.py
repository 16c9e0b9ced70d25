"""A DEM against laser altimetry shots (LOLA, MOLA): differences and alignment.

The shots are points, not a grid, so the DEM is sampled at each shot (bilinear, on the
DEM's own grid; a shot whose four neighbouring posts are not all valid is "no data",
one outside the grid "outside") and compared as ``DEM − shot``, heights above the DEM's
reference sphere (``radius − R``).

Alignment, as ASP's ``pc_align`` (translation) followed by ``geodiff``: the translation
``d = (dx, dy, dz)`` (map metres east and north, metres up) that moves the DEM onto the
shots minimises ``Σ (DEM(pᵢ − (dx, dy)) + dz − hᵢ)²`` (Gauss–Newton with the DEM's
bilinear gradient; Nuth & Kääb 2011 solve the same for a DEM against a DEM), shots
beyond 3 NMAD of the median residual left out at each step.  Its uncertainty is the
formal one, ``s² (JᵀJ)⁻¹`` with ``s`` the residuals' standard deviation (shots taken as
independent; along a track they are correlated over the DEM's posts, so read it as a
lower bound).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def sample_bilinear(dem: np.ndarray, col, row) -> np.ndarray:
    """Bilinear DEM values at fractional pixel positions (``col`` x right, ``row`` y
    down, pixel centres at integers); NaN outside or next to NaN posts."""
    dem = np.asarray(dem, dtype=np.float64)
    col = np.asarray(col, dtype=np.float64)
    row = np.asarray(row, dtype=np.float64)
    h, w = dem.shape
    c0 = np.floor(col).astype(np.int64)
    r0 = np.floor(row).astype(np.int64)
    inside = (c0 >= 0) & (r0 >= 0) & (c0 + 1 < w) & (r0 + 1 < h)
    c0c, r0c = np.clip(c0, 0, max(w - 2, 0)), np.clip(r0, 0, max(h - 2, 0))
    fc, fr = col - c0c, row - r0c
    v = ((1 - fr) * ((1 - fc) * dem[r0c, c0c] + fc * dem[r0c, c0c + 1])
         + fr * ((1 - fc) * dem[r0c + 1, c0c] + fc * dem[r0c + 1, c0c + 1]))
    return np.where(inside, v, np.nan)


@dataclass(frozen=True)
class ShotAlignment:
    """The translation that moves the DEM onto the shots.

    ``shift_m`` (3,): east, north, up, metres (added to the DEM's positions and
    heights); ``sigma_m`` (3,): its formal standard deviation; ``used``: shots in the
    final fit; ``residuals``: (N,) DEM − shot after the shift (NaN where not sampled);
    ``converged``; ``horizontal``: whether the horizontal shift was solved (else only
    ``dz``, and ``note`` says why).
    """

    shift_m: np.ndarray
    sigma_m: np.ndarray
    used: int
    residuals: np.ndarray
    converged: bool
    horizontal: bool = True
    note: str = ""


def align_to_shots(dem: np.ndarray, col, row, heights, *, post_m: tuple[float, float],
                   iterations: int = 30) -> ShotAlignment:
    """Translation of the DEM onto shots at pixel positions ``col``, ``row`` (N,) with
    heights ``heights`` (N,, metres); ``post_m``: the grid's (x, y) spacing in metres
    (x east, y north: a row step is ``−post_m[1]`` north).  See the module docstring."""
    col = np.asarray(col, dtype=np.float64)
    row = np.asarray(row, dtype=np.float64)
    heights = np.asarray(heights, dtype=np.float64)
    px, py = post_m
    shift = np.zeros(3)
    converged = False
    keep = np.ones(len(col), dtype=bool)
    for _ in range(iterations):
        c = col - shift[0] / px
        r = row + shift[1] / py
        value = sample_bilinear(dem, c, r)
        gx = (sample_bilinear(dem, c + 0.5, r) - sample_bilinear(dem, c - 0.5, r)) / px
        gy = (sample_bilinear(dem, c, r - 0.5) - sample_bilinear(dem, c, r + 0.5)) / py
        res = value + shift[2] - heights
        ok = np.isfinite(res) & np.isfinite(gx) & np.isfinite(gy)
        if np.count_nonzero(ok) < 3:
            break
        median = np.median(res[ok])
        nmad = 1.4826 * np.median(np.abs(res[ok] - median))
        keep = ok & (np.abs(res - median) <= max(3 * nmad, 1e-9))
        jac = np.column_stack([-gx, -gy, np.ones_like(gx)])[keep]
        step, *_ = np.linalg.lstsq(jac, -res[keep], rcond=None)
        shift = shift + step
        if np.all(np.abs(step[:2]) < 1e-4 * np.array([px, py])) and abs(step[2]) < 1e-4:
            converged = True
            break
    c, r = col - shift[0] / px, row + shift[1] / py
    value = sample_bilinear(dem, c, r)
    residuals = value + shift[2] - heights
    gx = (sample_bilinear(dem, c + 0.5, r) - sample_bilinear(dem, c - 0.5, r)) / px
    gy = (sample_bilinear(dem, c, r - 0.5) - sample_bilinear(dem, c, r + 0.5)) / py
    ok = keep & np.isfinite(residuals) & np.isfinite(gx) & np.isfinite(gy)
    sigma = np.full(3, np.nan)
    if np.count_nonzero(ok) > 3:
        jac = np.column_stack([-gx, -gy, np.ones_like(gx)])[ok]
        s2 = float(np.var(residuals[ok], ddof=3))
        try:
            sigma = np.sqrt(np.diag(s2 * np.linalg.inv(jac.T @ jac)))
        except np.linalg.LinAlgError:
            pass
    determined = converged and np.all(np.isfinite(sigma)) and \
        np.all(sigma[:2] <= 0.5 * np.array([px, py]))
    if determined:
        return ShotAlignment(shift_m=shift, sigma_m=sigma, used=int(np.count_nonzero(ok)),
                             residuals=residuals, converged=converged)
    note = ("the horizontal shift did not converge" if not converged else
            f"the shots determine the horizontal shift only to {sigma[0]:.3g} x "
            f"{sigma[1]:.3g} m (more than half a post)") + ": only the vertical shift is solved"
    return _vertical_only(dem, col, row, heights, note)


def _vertical_only(dem, col, row, heights, note: str) -> ShotAlignment:
    """The DEM's vertical shift alone: minus the median of DEM − shot (3-NMAD trimmed)."""
    diff = sample_bilinear(dem, col, row) - heights
    ok = np.isfinite(diff)
    if not np.any(ok):
        return ShotAlignment(np.zeros(3), np.full(3, np.nan), 0, diff, False, False, note)
    median = np.median(diff[ok])
    nmad = 1.4826 * np.median(np.abs(diff[ok] - median))
    keep = ok & (np.abs(diff - median) <= max(3 * nmad, 1e-9))
    dz = -float(np.median(diff[keep]))
    n = int(np.count_nonzero(keep))
    sigma = 1.2533 * float(np.std(diff[keep])) / np.sqrt(max(n, 1))  # of a median
    return ShotAlignment(np.array([0.0, 0.0, dz]), np.array([np.nan, np.nan, sigma]), n,
                         diff + dz, True, False, note)


def difference_statistics(diff) -> dict:
    """Statistics of DEM − shot differences (metres; NaN ignored)."""
    d = np.asarray(diff, dtype=np.float64)
    d = d[np.isfinite(d)]
    if not len(d):
        return {"count": 0}
    median = float(np.median(d))
    return {"count": int(len(d)), "mean_m": float(d.mean()), "median_m": median,
            "std_m": float(d.std()), "rmse_m": float(np.sqrt(np.mean(d ** 2))),
            "nmad_m": float(1.4826 * np.median(np.abs(d - median))),
            "le90_m": float(np.percentile(np.abs(d), 90)),
            "min_m": float(d.min()), "max_m": float(d.max())}
