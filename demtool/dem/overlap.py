"""Which cells of a map grid a sensor sees: exact, with most cells decided on a lattice.

:func:`demtool.dem.sensors.overlap_mask` asks, for every cell of a DEM's map grid, whether
its centre (at one height) falls inside each image: a ground-to-image projection per cell
and sensor, iterative for a line scanner (≈ 0.9 M points/s on two cores: 9 s for the two
sensors of a 2048² map, minutes for a CTX strip).  Away from the images' edges the answer
does not depend on the last pixel, so :func:`cells_seen` projects exactly only

- the nodes of a lattice every ``step`` cells, whose bilinear interpolation decides the
  cells lying more than ``margin_px`` inside or outside the image;
- the cells within that margin of an edge (and those beside a node without an image),
  which are projected one by one;
- the centre of every lattice square, where a bilinear interpolation errs most: if the
  interpolation is off by more than a quarter of the margin anywhere there (a mapping
  that bends within a lattice square), every cell is projected instead.

The result is the exact per-cell answer (a cell is decided on the lattice only when the
interpolated position is ``margin_px`` from the edge, four times the largest error
measured between the nodes); tests compare it with the cell-by-cell projection.  One
case it cannot see: a sensor without an image in a patch narrower than a lattice square
that misses every node and square centre (a gap in the ephemeris inside the image), whose
cells would count as seen.
"""

from __future__ import annotations

import numpy as np

from demtool.logs import get_logger

log = get_logger(__name__)

LATTICE_STEP = 16  # cells between exactly projected nodes
MARGIN_PX = 2.0  # image pixels from an edge within which cells are projected one by one


def cell_xyz(grid, rows: np.ndarray, cols: np.ndarray, height: float) -> np.ndarray:
    """Body-fixed XYZ (..., 3) of the centres of cells (rows, cols) raised by ``height``:
    :func:`demtool.maps.grids.grid_xyz`'s values for those cells."""
    from demtool.maps.projections import map_to_xyz

    t = grid.transform
    cc = np.asarray(cols, dtype=np.float64) + 0.5
    rr = np.asarray(rows, dtype=np.float64) + 0.5
    return map_to_xyz(grid.crs, t.a * cc + t.b * rr + t.c, t.d * cc + t.e * rr + t.f,
                      float(height))


def inside_image(model, line: np.ndarray, sample: np.ndarray) -> np.ndarray:
    """Finite image coordinates within the image (CSM pixel edges 0 … lines, samples)."""
    return (np.isfinite(line) & np.isfinite(sample) & (line >= 0) & (sample >= 0)
            & (line <= model.lines) & (sample <= model.samples))


def _nodes(size: int, step: int) -> np.ndarray:
    return np.unique(np.r_[np.arange(0, size, step), size - 1])


def _bilinear(values: np.ndarray, node_rows: np.ndarray, node_cols: np.ndarray,
              shape: tuple[int, int]) -> np.ndarray:
    """Bilinear interpolation of lattice values (len(node_rows), len(node_cols)) to every
    cell; a NaN node makes every cell of its four squares NaN."""
    def weights(nodes, size):
        cells = np.arange(size)
        interval = np.clip(np.searchsorted(nodes, cells, side="right") - 1, 0,
                           len(nodes) - 2)
        lo, hi = nodes[interval], nodes[interval + 1]
        return interval, (cells - lo) / (hi - lo)

    if len(node_rows) < 2 or len(node_cols) < 2:
        raise ValueError("the lattice needs two nodes each way")
    i, t = weights(node_rows, shape[0])
    j, u = weights(node_cols, shape[1])
    along = values[:, j] * (1.0 - u) + values[:, j + 1] * u  # (node rows, columns)
    return along[i] * (1.0 - t)[:, None] + along[i + 1] * t[:, None]


def cells_seen(model, grid, height: float, *, step: int = LATTICE_STEP,
               margin_px: float = MARGIN_PX) -> np.ndarray:
    """Cells of ``grid`` whose centre, ``height`` metres above the sphere, ``model`` sees.

    Parameters
    ----------
    model : SensorModel
        With ``ground_to_image`` (CSM line, sample), ``lines`` and ``samples``.
    grid : demtool.maps.MapGrid
    height : float
        Metres above the grid's sphere.
    step : int
        Lattice spacing, cells.
    margin_px : float
        Cells whose interpolated image position lies within this many pixels of an edge
        are projected one by one.

    Returns
    -------
    (rows, columns) bool, the same as projecting every cell (see the module docstring).
    """
    rows, cols = grid.shape
    if rows < 4 * step or cols < 4 * step:
        rr, cc = np.mgrid[:rows, :cols]
        return inside_image(model, *model.ground_to_image(cell_xyz(grid, rr, cc, height)))
    node_rows, node_cols = _nodes(rows, step), _nodes(cols, step)
    nr, nc = np.meshgrid(node_rows, node_cols, indexing="ij")
    node_line, node_sample = model.ground_to_image(cell_xyz(grid, nr, nc, height))
    # the centres of the lattice squares: where bilinear interpolation errs most
    mid_rows = (node_rows[:-1] + node_rows[1:]) // 2
    mid_cols = (node_cols[:-1] + node_cols[1:]) // 2
    mr, mc = np.meshgrid(mid_rows, mid_cols, indexing="ij")
    exact_line, exact_sample = model.ground_to_image(cell_xyz(grid, mr, mc, height))
    with np.errstate(invalid="ignore"):
        line = _bilinear(node_line, node_rows, node_cols, grid.shape)
        sample = _bilinear(node_sample, node_rows, node_cols, grid.shape)
        error = np.hypot(line[mr, mc] - exact_line, sample[mr, mc] - exact_sample)
        both = np.isfinite(error)
        bent = (np.isfinite(line[mr, mc]) != np.isfinite(exact_line)) & np.isfinite(line[mr, mc])
        largest = float(error[both].max()) if both.any() else 0.0
        if bent.any() or largest > margin_px / 4:
            log.debug("overlap lattice off by %.3g px (%d squares without an image at their "
                      "centre): every cell projected", largest, int(bent.sum()))
            rr, cc = np.mgrid[:rows, :cols]
            return inside_image(model,
                                *model.ground_to_image(cell_xyz(grid, rr, cc, height)))
        seen = ((line >= margin_px) & (sample >= margin_px)
                & (line <= model.lines - margin_px) & (sample <= model.samples - margin_px))
        unseen = ((line < -margin_px) | (sample < -margin_px)
                  | (line > model.lines + margin_px) | (sample > model.samples + margin_px))
    near = np.nonzero(~(seen | unseen))  # near an edge, or beside a node without an image
    seen[near] = inside_image(model, *model.ground_to_image(
        cell_xyz(grid, near[0], near[1], height)))
    return seen
