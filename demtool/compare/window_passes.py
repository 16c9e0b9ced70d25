"""The windowed comparison's passes over its windows: each raster read once, the later
passes on what the first one kept, the windows on two threads.

:func:`demtool.compare.run_windowed.compare_one` reads the DEM and the reference onto the
comparison grid window by window and computes the exact statistics in several passes
(:class:`demtool.compare.streaming.StreamStatistics`: the moments, then the order
statistics by narrowing).  Reading is the costly part (a DEM finer than the grid is
decoded and resampled, a grid in another CRS transformed cell by cell through PROJ), and
the passes only need each window's differences, so:

* **the grid** (:class:`Grid`): the read pass, which fills the alignment's decimated
  grid, keeps the DEM, the reference and the mask on the comparison grid
  (:data:`GRID_BYTES_PER_CELL`) when they fit in ``--max-memory-mb`` beside the
  alignment and the kept differences; the first pass then takes each window with its
  margins from it instead of reading the rasters again;
* **the kept differences** (:class:`Kept`): the first pass keeps each window's finite
  differences after alignment (grouped by slope class) and before it
  (:data:`KEPT_BYTES_PER_CELL` at most), while the budget holds; the later passes feed
  those to the order statistics, and read and compute again only the windows that did
  not fit;
* **threads** (when :func:`demtool.compare.threads.threaded`: a large grid and two
  usable threads, and numba's threading layer runs kernels from two threads): the
  windows are read and computed on two threads (:func:`demtool.tiling.rows.ordered_map`)
  while this one merges their results in the windows' order, and a later pass feeds the
  statistics on two threads, each statistic on one.

The numbers are those of reading every window again in every pass, to the bit: a cell's
value does not depend on the window it is read in
(:func:`demtool.compare.grids.source_pixels`), each window's moments are summarised
where it is computed and merged in the windows' order (:meth:`Moments.merge
<demtool.compare.streaming.Moments.merge>`), and the order statistics count and select,
which the order of the values does not change
(:meth:`~demtool.compare.streaming.StreamStatistics.add_again`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from demtool.errors import ParameterError

__all__ = ["GRID_BYTES_PER_CELL", "KEPT_BYTES_PER_CELL", "Grid", "Kept", "Streams",
           "WindowResult", "check_slope_bins", "decimate", "window_result"]

#: the DEM and the reference (float64) and the mask (bool) of one cell of the grid
GRID_BYTES_PER_CELL = 17
#: a cell's differences kept for the later passes: after and before alignment (float64)
KEPT_BYTES_PER_CELL = 16


def check_slope_bins(bins: Sequence[float]) -> None:
    """Refuse slope bins that are not increasing (as :func:`demtool.compare.compare_dems`):
    each difference must fall in at most one class."""
    edges = np.asarray(bins, dtype=np.float64)
    if edges.ndim != 1 or edges.size < 2 or np.any(np.diff(edges) <= 0):
        raise ParameterError(f"slope bins must be at least two increasing values, got "
                             f"{list(bins)}")


def decimate(values: np.ndarray, window: tuple[int, int, int, int], factor: int
             ) -> tuple[np.ndarray, slice, slice]:
    """The window's cells on the decimated grid (global rows and columns ≡ 0 mod f)."""
    r0, _, c0, _ = window
    local = values[(-r0) % factor::factor, (-c0) % factor::factor]
    rows = slice(-(-r0 // factor), -(-r0 // factor) + local.shape[0])
    cols = slice(-(-c0 // factor), -(-c0 // factor) + local.shape[1])
    return local, rows, cols


class Grid:
    """The DEM, the reference and the mask on the whole comparison grid, filled core by
    core in the read pass; :meth:`window` gives a window with its margins (views)."""

    def __init__(self, shape: tuple[int, int], mask: bool) -> None:
        self.dem = np.empty(shape)
        self.reference = np.empty(shape)
        self.mask = np.empty(shape, dtype=bool) if mask else None

    def put(self, core: tuple[int, int, int, int], dem: np.ndarray, reference: np.ndarray,
            mask: np.ndarray | None) -> None:
        r0, r1, c0, c1 = core
        self.dem[r0:r1, c0:c1] = dem
        self.reference[r0:r1, c0:c1] = reference
        if self.mask is not None:
            self.mask[r0:r1, c0:c1] = mask

    def window(self, outer: tuple[int, int, int, int]
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        r0, r1, c0, c1 = outer
        return (self.dem[r0:r1, c0:c1], self.reference[r0:r1, c0:c1],
                None if self.mask is None else self.mask[r0:r1, c0:c1])


@dataclass
class Kept:
    """One window's finite differences for the later passes.

    ``grouped``: after alignment, slope class by slope class then those in no class
    (class ``i`` is ``grouped[bounds[i]:bounds[i + 1]]``); ``before``: before alignment.
    """

    grouped: np.ndarray
    bounds: np.ndarray
    before: np.ndarray


@dataclass
class WindowResult:
    """What one window gives the passes (:func:`window_result`).

    ``moments``: :meth:`~demtool.compare.streaming.Moments.of` of its finite differences
    after alignment, before it and in each slope class (the first pass); ``pieces``:
    those arrays (a later pass's window computed again); ``kept``: :class:`Kept` or None;
    ``difference``: float32 core of ``difference.tif``; ``figures``: the decimated
    cells of each figure grid, with their rows and columns; ``considered``,
    ``covered``: the completeness counts.
    """

    core: tuple[int, int, int, int]
    moments: list[Any]
    pieces: list[np.ndarray] | None
    kept: Kept | None
    difference: np.ndarray | None
    figures: dict[str, tuple[np.ndarray, slice, slice]]
    considered: int
    covered: int


def window_result(values: Any, mask: np.ndarray | None, core: tuple[int, int, int, int],
                  bins: Sequence[float], factor: int, *, first: bool, keep: bool,
                  difference: bool) -> WindowResult:
    """A window's :class:`WindowResult` from its
    :class:`~demtool.compare.windowed.WindowValues` (``mask``: the core's, or None).

    ``first``: the first pass (moments, figures, completeness); ``keep``: build
    :class:`Kept` (else the pieces are returned for this pass); ``difference``: the
    float32 core for ``difference.tif``.
    """
    from demtool.compare.streaming import Moments

    after = values.difference[np.isfinite(values.difference)]
    before = values.before[np.isfinite(values.before)]
    parts, unclassified = values.slope_parts(bins)
    pieces = [after, before, *parts]
    moments = [Moments.of(piece) for piece in pieces] if first else []
    kept = None
    if keep:
        grouped = np.concatenate([*parts, unclassified])
        bounds = np.cumsum([0, *(p.size for p in parts), unclassified.size])
        kept = Kept(grouped, bounds, before)
    figures = {}
    if first:
        for name in ("aligned", "reference", "difference", "coverage"):
            figures[name] = decimate(getattr(values, name), core, factor)
        if mask is not None:
            figures["mask"] = decimate(mask, core, factor)
    return WindowResult(core=core, moments=moments, pieces=None if keep or first else pieces,
                        kept=kept, difference=(values.difference.astype(np.float32)
                                               if difference else None),
                        figures=figures, considered=values.considered if first else 0,
                        covered=values.covered if first else 0)


class Streams:
    """The exact statistics after alignment, before it and in each slope class."""

    def __init__(self, classes: int) -> None:
        from demtool.compare.streaming import StreamStatistics

        self.after, self.before = StreamStatistics(), StreamStatistics()
        self.classes = [StreamStatistics() for _ in range(classes)]

    @property
    def all(self) -> list[Any]:
        return [self.after, self.before, *self.classes]

    @property
    def done(self) -> bool:
        return all(s.done for s in self.all)

    def end_pass(self) -> None:
        for stream in self.all:
            stream.end_pass()

    def merge_first(self, result: WindowResult) -> None:
        """A window's first-pass moments (in the windows' order)."""
        for stream, moments in zip(self.all, result.moments, strict=True):
            stream.add_moments(moments)

    def add_pieces(self, result: WindowResult) -> None:
        """A later pass: a window computed again (not kept)."""
        for stream, piece in zip(self.all, result.pieces, strict=True):
            stream.add_again(piece)

    def add_kept(self, kept: Sequence[Kept], two: bool) -> None:
        """A later pass over the kept windows: each statistic fed every window on one
        thread; with ``two``, the statistics split in two groups of about equal values,
        one on a side thread."""
        from demtool.compare.threads import both

        work: list[tuple[Any, Callable[[Kept], np.ndarray], int]] = []
        if not self.after.done:
            work.append((self.after, lambda k: k.grouped, sum(k.grouped.size for k in kept)))
        if not self.before.done:
            work.append((self.before, lambda k: k.before, sum(k.before.size for k in kept)))
        for index, stream in enumerate(self.classes):
            if not stream.done:
                size = sum(int(k.bounds[index + 1] - k.bounds[index]) for k in kept)
                work.append((stream, lambda k, i=index: k.grouped[k.bounds[i]:k.bounds[i + 1]],
                             size))
        groups: tuple[list, list] = ([], [])
        loads = [0, 0]
        for item in sorted(work, key=lambda w: -w[2]):
            lighter = 0 if loads[0] <= loads[1] else 1
            groups[lighter].append(item)
            loads[lighter] += item[2]

        def feed(group: list) -> None:
            for stream, piece, _ in group:
                for window in kept:
                    stream.add_again(piece(window))

        both(lambda: feed(groups[0]), lambda: feed(groups[1]), on=two and all(groups))

