"""Comparison figures (matplotlib, Agg backend): each function returns PNG bytes.

Figures take arrays on the comparison grid (row 0 at the top, x right, y down) and the
pixel spacing in metres; axes are in metres from the grid's top-left corner.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = [
    "coherence_figure",
    "completeness_figure",
    "default_profiles",
    "dems_figure",
    "difference_figure",
    "hillshade",
    "histogram_figure",
    "profile_samples",
    "profiles_figure",
    "symmetric_limit",
]

DPI = 110
#: most samples along a map's longer side: at least two per screen pixel of the widest
#: map panel (7 in at ``DPI``), so a larger grid drawn with "nearest" looks the same
#: from every second, third … cell; contours and resampling of a 2048² grid took
#: seconds (issue 28)
DISPLAY_SAMPLES = 1200


#: most samples along a DEM's longer side that its contours are traced on: about one per
#: screen pixel of a dems.png panel (4.5 in at ``DPI``, 495 px).  Traced on the map's
#: 1200 they were half the 4096² figure's time (2.1 of 4.5 s) for lines that differ by
#: under a pixel
CONTOUR_SAMPLES = 600


#: zlib level of the PNGs: 1 encodes a map figure several times faster than PIL's
#: default 6, for files about a third larger
PNG_COMPRESSION = 1


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _figure(width_in: float, height_in: float, *, left: float = 0.8, right: float = 0.25,
            bottom: float = 0.55, top: float = 0.4, hspace_in: float = 0.0,
            wspace_in: float = 0.0, rows: int = 1, columns: int = 1):
    """A figure (Agg, no pyplot state) of ``rows`` × ``columns`` axes inside fixed margins
    (inches; ``hspace_in``/``wspace_in`` between panels), and its axes (2-D array).

    Fixed margins instead of matplotlib's constrained layout: the layout engine measures
    every tick label and title once more before drawing, half the figure's time."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(width_in, height_in), dpi=DPI)
    FigureCanvasAgg(figure)
    panel_w = (width_in - left - right - (columns - 1) * wspace_in) / columns
    panel_h = (height_in - bottom - top - (rows - 1) * hspace_in) / rows
    axes = figure.subplots(rows, columns, squeeze=False, gridspec_kw={
        "left": left / width_in, "right": 1.0 - right / width_in,
        "bottom": bottom / height_in, "top": 1.0 - top / height_in,
        "wspace": wspace_in / panel_w, "hspace": hspace_in / panel_h})
    return figure, axes


def _png(figure) -> bytes:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=DPI,
                   pil_kwargs={"compress_level": PNG_COMPRESSION})
    return buffer.getvalue()


def _extent(shape: tuple[int, int], spacing: tuple[float, float]) -> list[float]:
    return [0.0, shape[1] * spacing[0], shape[0] * spacing[1], 0.0]


def display_stride(shape: tuple[int, int], samples: int | None = None) -> int:
    """Every how many cells a map of ``shape`` is drawn: 1 up to ``samples`` cells along
    its longer side (None: :data:`DISPLAY_SAMPLES`), else the least step that keeps it
    within ``samples``."""
    return max(1, -(-max(shape) // (DISPLAY_SAMPLES if samples is None else samples)))


def _map_image(axis, values: np.ndarray, spacing: tuple[float, float], stride: int,
               shown: np.ndarray | None = None, **style):
    """``imshow`` of every ``stride``-th cell of ``values`` (cell i·stride standing for the
    cells i·stride … (i + 1)·stride − 1; ``shown``: those cells, when the caller has
    them), the axes limited to the whole grid."""
    if shown is None:
        shown = values[::stride, ::stride]
    image = axis.imshow(shown, extent=_extent(shown.shape, (spacing[0] * stride,
                                                            spacing[1] * stride)),
                        interpolation="nearest", **style)
    axis.set_xlim(0.0, values.shape[1] * spacing[0])
    axis.set_ylim(values.shape[0] * spacing[1], 0.0)
    return image


def _gradient_at(values: np.ndarray, stride: int, axis: int) -> np.ndarray:
    """``np.gradient(values, axis=axis)`` at the cells ``[::stride, ::stride]``, computed
    there only: the same differences of the same neighbours (central, halved, inside;
    one-sided at the first and last cell), so the same numbers."""
    other = (slice(None), slice(None, None, stride)) if axis == 0 else \
        (slice(None, None, stride), slice(None))
    lines = values[other]  # every cell along ``axis``, every stride-th across it
    count = lines.shape[axis]
    at = np.arange(0, count, stride)
    after = np.take(lines, np.minimum(at + 1, count - 1), axis=axis)
    before = np.take(lines, np.maximum(at - 1, 0), axis=axis)
    divisor = np.where((at == 0) | (at == count - 1), 1.0, 2.0)  # np.gradient's 2 h, h
    return (after - before) / (divisor[:, None] if axis == 0 else divisor[None, :])


def hillshade(dem: np.ndarray, spacing: tuple[float, float] = (1.0, 1.0), *,
              azimuth_deg: float = 315.0, altitude_deg: float = 45.0,
              stride: int = 1) -> np.ndarray:
    """Lambertian hillshade in [0, 1] (NaN at holes), light from ``azimuth_deg``.

    Azimuth is clockwise from up (north for a north-up grid); the grid's y axis points
    down (row order).  With ``stride`` > 1, the shade of the cells
    ``[::stride, ::stride]`` only (each from its neighbours on the whole grid: the
    values of the whole grid's shade there), for a map drawn from those cells.
    """
    values = np.asarray(dem, dtype=np.float64)
    if stride > 1 and min(values.shape) >= 2:
        grad_row, grad_col = _gradient_at(values, stride, 0), _gradient_at(values, stride, 1)
    else:
        grad_row, grad_col = np.gradient(values)
        grad_row, grad_col = grad_row[::stride, ::stride], grad_col[::stride, ::stride]
    dzdx = grad_col / spacing[0]
    dzdy_up = -grad_row / spacing[1]
    az, alt = np.radians(azimuth_deg), np.radians(altitude_deg)
    light = np.array([np.sin(az) * np.cos(alt), np.cos(az) * np.cos(alt), np.sin(alt)])
    norm = np.sqrt(1.0 + dzdx**2 + dzdy_up**2)
    shade = (-dzdx * light[0] - dzdy_up * light[1] + light[2]) / norm
    return np.clip(shade, 0.0, 1.0)


def symmetric_limit(values: np.ndarray) -> float:
    """The 98th percentile of |values| over the finite ones (the difference map's colour
    limits ±; 1.5 × it, the histogram's range): 1 when none, the largest when it is 0."""
    finite = np.abs(values[np.isfinite(values)])
    if finite.size == 0:
        return 1.0
    limit = float(np.percentile(finite, 98))
    return limit if limit > 0 else float(max(finite.max(), 1e-6))


def difference_figure(difference: np.ndarray, spacing: tuple[float, float], *,
                      title: str = "", stats: dict[str, Any] | None = None,
                      limit: float | None = None) -> bytes:
    """Difference map, diverging colour map with symmetric limits (±98th pct of |dh|:
    ``limit``, :func:`symmetric_limit` of ``difference``, when the caller has it)."""
    limit = symmetric_limit(difference) if limit is None else limit
    figure, axes = _figure(7, 6, right=0.2, top=0.6)
    axis = axes[0, 0]
    image = _map_image(axis, difference, spacing, display_stride(difference.shape),
                       cmap="RdBu_r", vmin=-limit, vmax=limit)
    axis.set_facecolor("0.8")
    figure.colorbar(image, ax=axis, label="DEM − reference (m)", extend="both")
    axis.set_xlabel("x (m)")
    axis.set_ylabel("y (m, down)")
    text = title
    if stats:
        text += (f"\nRMSE {stats['rmse']:.3g} m, NMAD {stats['nmad']:.3g} m, "
                 f"mean {stats['mean']:.3g} m")
    axis.set_title(text.strip())
    return _png(figure)


def dems_figure(dems: Sequence[tuple[str, np.ndarray]], spacing: tuple[float, float], *,
                contours: int = 20) -> bytes:
    """Each DEM colour-coded over its hillshade with ``contours`` equally spaced contours.

    One panel per (name, DEM); all share the colour scale and contour levels (the
    NavCam study's figure 4 style).
    """
    strides = [display_stride(dem.shape) for _, dem in dems]
    shown = [dem[::stride, ::stride] for (_, dem), stride in zip(dems, strides, strict=True)]
    # the colour scale of the cells shown; both order statistics from one partition
    finite = np.concatenate([cells[np.isfinite(cells)] for cells in shown])
    low, high = (float(v) for v in np.percentile(finite, [0.5, 99.5])) \
        if finite.size else (0.0, 1.0)
    if high <= low:
        high = low + 1e-6
    levels = np.linspace(low, high, contours + 2)[1:-1]
    count = len(dems)
    figure, axes = _figure(5.2 * count, 5, columns=count, right=0.2, wspace_in=0.5)
    image = None
    for axis, (name, dem), stride in zip(axes[0], dems, strides, strict=True):
        # the shown cells' shade from their neighbours on the whole grid: they keep
        # their relief (4.4 CPU s of a 4096² figure when every cell was shaded)
        shade = hillshade(dem, spacing, stride=stride)
        axis.set_facecolor("0.85")
        _map_image(axis, dem, spacing, stride, shown=shade, cmap="gray", vmin=0, vmax=1)
        image = _map_image(axis, dem, spacing, stride, cmap="terrain", vmin=low,
                           vmax=high, alpha=0.55)
        step = display_stride(dem.shape, CONTOUR_SAMPLES)
        traced = dem[::step, ::step]
        x = (np.arange(traced.shape[1]) * step + 0.5) * spacing[0]
        y = (np.arange(traced.shape[0]) * step + 0.5) * spacing[1]
        if np.isfinite(traced).sum() > 4:
            axis.contour(x, y, np.ma.masked_invalid(traced), levels=levels, colors="k",
                         linewidths=0.5)
        axis.set_title(name)
        axis.set_xlabel("x (m)")
    axes[0][0].set_ylabel("y (m, down)")
    figure.colorbar(image, ax=list(axes[0]), label="height (m)", shrink=0.85)
    return _png(figure)


def default_profiles(shape: tuple[int, int]) -> list[tuple[float, float, float, float]]:
    """One horizontal and one vertical line through the centre, in pixels (x0, y0, x1, y1)."""
    rows, cols = shape
    cy, cx = (rows - 1) / 2.0, (cols - 1) / 2.0
    return [(0.0, cy, cols - 1.0, cy), (cx, 0.0, cx, rows - 1.0)]


def profile_samples(dem: np.ndarray, line: tuple[float, float, float, float],
                    spacing: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Heights along a line (pixels x0, y0, x1, y1), one sample per pixel of length.

    Returns distance along the line (metres) and bilinearly interpolated heights
    (NaN at holes and outside).
    """
    from demtool.compare.grids import sample_bilinear

    x0, y0, x1, y1 = line
    length_px = float(np.hypot(x1 - x0, y1 - y0))
    count = max(2, int(np.ceil(length_px)) + 1)
    t = np.linspace(0.0, 1.0, count)
    xs, ys = x0 + t * (x1 - x0), y0 + t * (y1 - y0)
    distance = t * float(np.hypot((x1 - x0) * spacing[0], (y1 - y0) * spacing[1]))
    return distance, sample_bilinear(dem, ys, xs)


def profiles_figure(dems: Sequence[tuple[str, np.ndarray]],
                    lines: Sequence[tuple[float, float, float, float]],
                    spacing: tuple[float, float]) -> bytes:
    """Height profiles of every DEM along each line (one panel per line)."""
    figure, axes = _figure(9, 3.2 * len(lines), rows=len(lines), top=0.35, bottom=0.5,
                           hspace_in=0.85)
    for axis, line in zip(axes[:, 0], lines, strict=True):
        for index, (name, dem) in enumerate(dems):
            distance, heights = profile_samples(dem, line, spacing)
            axis.plot(distance, heights, label=name, linewidth=1.6 if index == 0 else 1.0,
                      color="k" if index == 0 else None)
        axis.set_title("profile ({:.0f}, {:.0f}) → ({:.0f}, {:.0f}) px".format(*line))
        axis.set_xlabel("distance along the profile (m)")
        axis.set_ylabel("height (m)")
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8)
    return _png(figure)


def histogram_figure(difference: np.ndarray, *, stats: dict[str, Any] | None = None,
                     title: str = "", limit: float | None = None) -> bytes:
    """Histogram of the differences with a normal curve of the NMAD for comparison
    (within 1.5 × ``limit`` of their median; ``limit``: :func:`symmetric_limit` of
    ``difference``, when the caller has it)."""
    values = difference[np.isfinite(difference)]
    figure, axes = _figure(7, 4.5, top=0.6)
    axis = axes[0, 0]
    if values.size:
        limit = (symmetric_limit(values) if limit is None else limit) * 1.5
        # the reported median when the caller has the statistics (the normal curve's centre)
        centre = stats["median"] if stats and np.isfinite(stats.get("median", np.nan)) \
            else np.median(values)
        inside = values[np.abs(values - centre) <= limit]
        axis.hist(inside, bins=100, density=True, color="0.55", label="DEM − reference")
        if stats and stats.get("nmad"):
            grid = np.linspace(inside.min(), inside.max(), 400)
            nmad = stats["nmad"]
            axis.plot(grid, np.exp(-0.5 * ((grid - stats["median"]) / nmad) ** 2)
                      / (nmad * np.sqrt(2 * np.pi)), "r-", label="normal (median, NMAD)")
            axis.axvline(stats["mean"], color="b", linestyle="--", label="mean")
    axis.set_xlabel("DEM − reference (m)")
    axis.set_ylabel("density")
    if stats:
        title = (title + f"\nn={stats['count']}, RMSE {stats['rmse']:.3g} m, "
                 f"NMAD {stats['nmad']:.3g} m, LE90 {stats['le90']:.3g} m").strip()
    axis.set_title(title)
    axis.legend(fontsize=8)
    return _png(figure)


def completeness_figure(coverage: np.ndarray, spacing: tuple[float, float], *,
                        percent: float, title: str = "") -> bytes:
    """Where the DEM has a value (grey) and where it lacks one (red) over the reference."""
    from matplotlib.colors import ListedColormap

    figure, axes = _figure(7, 6)
    axis = axes[0, 0]
    axis.set_facecolor("white")
    _map_image(axis, coverage, spacing, display_stride(coverage.shape),
               cmap=ListedColormap(["tab:red", "0.7"]), vmin=0, vmax=1)
    axis.set_title(f"{title} completeness {percent:.2f} % (red: no DEM value)".strip())
    axis.set_xlabel("x (m)")
    axis.set_ylabel("y (m, down)")
    return _png(figure)


def coherence_figure(frequency: np.ndarray, coherence: np.ndarray, *,
                     cutoff_per_m: float | None, threshold: float = 0.5,
                     title: str = "") -> bytes:
    """Coherence against wavelength, with the threshold and the coherent cut-off."""
    figure, axes = _figure(7, 4.5)
    axis = axes[0, 0]
    axis.semilogx(1.0 / frequency, coherence, "k.-", markersize=3)
    axis.axhline(threshold, color="r", linestyle="--", linewidth=1,
                 label=f"threshold {threshold}")
    if cutoff_per_m:
        axis.axvline(1.0 / cutoff_per_m, color="b", linewidth=1,
                     label=f"effective resolution {1.0 / cutoff_per_m:.3g} m")
    axis.invert_xaxis()
    axis.set_xlabel("wavelength (m)")
    axis.set_ylabel("coherence")
    axis.set_ylim(0, 1.05)
    axis.grid(alpha=0.3, which="both")
    axis.set_title(title)
    axis.legend(fontsize=8)
    return _png(figure)
