"""Compiled kernels of :mod:`demtool.dem.grid`: neighbour statistics and splatting.

**The k nearest samples of each sample, and their median and NMAD**
(:func:`neighbour_statistics`, for :func:`demtool.dem.grid.local_median_statistics`).
The samples of the disparity routes are millions of points on (a warp of) the pixel
grid, where scipy's KD-tree query and the (N, k) arrays of indices and values around it
took most of ``dem``'s time (2048² disparities: 9 s of 15).  Here the samples are sorted
into square buckets of about two samples each, every query searches rings of buckets
around its own until no unvisited bucket can hold a nearer sample, and the median and
NMAD are formed from the k values at once, without (N, k) arrays.  The neighbours are the
k nearest by Euclidean distance, ties broken by the lower sample index: the same set as a
KD-tree's wherever distances are distinct (scattered or warped positions), and a
reproducible one where samples on an exact grid sit at equal distances (a KD-tree takes
some of those arbitrarily).  The median of an even number of values is the mean of the
middle two, as ``np.median`` computes it.

**Splatting.**  :func:`bilinear_moments`: the per-cell weighted moments of
:func:`demtool.dem.grid.splat_bilinear`, in one pass.  The numpy formulation summed 36
``np.bincount`` images (9 moments × the 4 cells each sample reaches) through as many
temporary arrays of the samples: 1.7 s of a 2048² ``dem``.  This kernel adds the same
terms in the same order (per corner, samples in their order, each corner's sums then
added to the total), so the moments are the same bit for bit.  :func:`cell_medians`: the
median of the samples of each cell (:func:`demtool.dem.grid.splat_median`), from a
counting sort by cell and a stable sort within each cell (:func:`_stable_sort`),
instead of a lexsort of all samples: the same sorted values, so the same medians.

The kernels live in one file so that numba's cache, keyed by the file, never keeps one
compiled against an older version of a helper they share.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit

from demtool.imaging.robust import NMAD_FACTOR


@njit(nogil=True, cache=True)
def _insertion_sort(values):
    """Sort a short array in place, stably (equal values keep their order)."""
    for i in range(1, len(values)):
        value = values[i]
        j = i
        while j > 0 and values[j - 1] > value:
            values[j] = values[j - 1]
            j -= 1
        values[j] = value


# Mean samples per bucket.  A query scans its bucket's neighbours, so the work grows with
# Σ (samples per bucket)² (3 N for evenly spread samples); where positions crowd (clusters,
# repeated positions) beyond MAX_CROWDING · N, or MAX_BUCKET_SAMPLES into one bucket,
# scipy's KD-tree is used instead.
BUCKET_OCCUPANCY = 2.0
MAX_BUCKET_SAMPLES = 256
MAX_CROWDING = 32


def bucket_layout(pixels: np.ndarray) -> tuple[float, float, float, int, int]:
    """Origin, side and counts of the buckets for ``pixels`` (N, 2) finite (x, y).

    Side chosen for :data:`BUCKET_OCCUPANCY` samples a bucket over the bounding box,
    and at most about 4N buckets (samples along a line would otherwise ask for
    millions).

    Returns
    -------
    (x0, y0, side, nx, ny)
    """
    count = len(pixels)
    x0, y0 = float(pixels[:, 0].min()), float(pixels[:, 1].min())
    width = max(float(pixels[:, 0].max()) - x0, 0.0)
    height = max(float(pixels[:, 1].max()) - y0, 0.0)
    extent = max(width, height, 1e-9)
    side = math.sqrt(max(width * height, (extent * 1e-6) ** 2) * BUCKET_OCCUPANCY / count)
    side = max(side, extent * 1e-7)
    while True:
        nx, ny = int(width / side) + 1, int(height / side) + 1
        if nx * ny <= 4 * count + 16:
            return x0, y0, side, nx, ny
        side *= 1.5


@njit(nogil=True, cache=True, inline="always")
def _bucket_of(x, y, x0, y0, side, nx, ny):
    column = min(int((x - x0) / side), nx - 1)
    row = min(int((y - y0) / side), ny - 1)
    return row, column


@njit(nogil=True, cache=True)
def _sort_into_buckets(xs, ys, x0, y0, side, nx, ny):
    """Counting sort of the samples by bucket: ``order[starts[b]:starts[b + 1]]`` are the
    samples of bucket b = row·nx + column, in increasing index."""
    count = len(xs)
    bucket = np.empty(count, dtype=np.int64)
    starts = np.zeros(nx * ny + 1, dtype=np.int64)
    for i in range(count):
        row, column = _bucket_of(xs[i], ys[i], x0, y0, side, nx, ny)
        bucket[i] = row * nx + column
        starts[bucket[i] + 1] += 1
    for b in range(nx * ny):
        starts[b + 1] += starts[b]
    fill = np.empty(nx * ny, dtype=np.int64)  # (a loop: a slice's copy compiles longer)
    for b in range(nx * ny):
        fill[b] = starts[b]
    order = np.empty(count, dtype=np.int64)
    for i in range(count):
        order[fill[bucket[i]]] = i
        fill[bucket[i]] += 1
    return starts, order


@njit(nogil=True, cache=True, inline="always")
def _scan_bucket(xs, ys, qx, qy, query, starts, order, bucket, best_d, best_i, found, k):
    """Insert every sample of ``bucket`` but the query itself into the ascending lists
    ``best_d`` (squared distances), ``best_i`` (indices) of the ``found`` ≤ k nearest so
    far, if it is nearer than their last (or as near with a lower index); the new count.

    (Written out here: numba's inlining of a separate insertion function made the search
    four times slower.)
    """
    for j in range(starts[bucket], starts[bucket + 1]):
        index = order[j]
        if index == query:
            continue
        dx, dy = xs[index] - qx, ys[index] - qy
        distance = dx * dx + dy * dy
        if found == k:
            if distance > best_d[k - 1] or (distance == best_d[k - 1]
                                            and index > best_i[k - 1]):
                continue
            position = k - 1
        else:
            position = found
            found += 1
        while position > 0 and (best_d[position - 1] > distance or (
                best_d[position - 1] == distance and best_i[position - 1] > index)):
            best_d[position] = best_d[position - 1]
            best_i[position] = best_i[position - 1]
            position -= 1
        best_d[position] = distance
        best_i[position] = index
    return found


@njit(nogil=True, cache=True)
def _sorted_median(values):
    """Median of ``values`` (sorted in place), as np.median computes it; NaN if any is."""
    count = len(values)
    for i in range(count):
        if values[i] != values[i]:
            return np.nan
    _insertion_sort(values)
    half = count // 2
    if count % 2:
        return values[half]
    return (values[half - 1] + values[half]) / 2.0


@njit(nogil=True, cache=True)
def _neighbour_statistics(xs, ys, values, queries, k, x0, y0, side, nx, ny, starts, order,
                          nmad_factor, local_median, local_nmad):
    """Median and NMAD of the ``k`` nearest other samples of each sample in ``queries``."""
    best_d = np.empty(k)
    best_i = np.empty(k, dtype=np.int64)
    window = np.empty(k)
    for q in range(len(queries)):
        query = queries[q]
        qx, qy = xs[query], ys[query]
        row, column = _bucket_of(qx, qy, x0, y0, side, nx, ny)
        found = 0
        ring = 0
        while True:
            for r in range(max(row - ring, 0), min(row + ring, ny - 1) + 1):
                # the ring's first and last rows: all its columns; its rows between: the
                # first and last column (one call of the inlined scan: compiled once)
                edge = r == row - ring or r == row + ring
                first = max(column - ring, 0) if edge else column - ring
                for c in range(first, min(column + ring, nx - 1) + 1, 1 if edge else 2 * ring):
                    if c >= 0:
                        found = _scan_bucket(xs, ys, qx, qy, query, starts, order,
                                             r * nx + c, best_d, best_i, found, k)
            # unvisited buckets lie at least ring · side away: none can be nearer (or
            # as near: ties go to the lower index, and such a sample might have one)
            bound = ring * side
            if found == k and bound * bound > best_d[k - 1] * (1.0 + 1e-9):
                break
            if ring > nx + ny:
                break
            ring += 1
        for j in range(k):
            window[j] = values[best_i[j]]
        median = _sorted_median(window)
        for j in range(k):
            window[j] = abs(values[best_i[j]] - median)
        local_median[q] = median
        local_nmad[q] = nmad_factor * _sorted_median(window)


def neighbour_statistics(pixels: np.ndarray, values: np.ndarray, k: int, *,
                         at: np.ndarray | None = None, threads: int = 1
                         ) -> tuple[np.ndarray, np.ndarray] | None:
    """Median and NMAD of each sample's ``k`` nearest other samples.

    Parameters
    ----------
    pixels : (N, 2) float
        Finite sample positions (x, y), pixels.
    values : (N,) float64
    k : int
        Neighbours, 1 ≤ k ≤ N − 1.
    at : (M,) int, optional
        Only these samples' statistics (their neighbours are sought among all N).
    threads : int
        Threads the queries are split over.

    Returns
    -------
    (local_median, local_nmad), (N,) or (M,) float64; None where the positions crowd
    (:data:`MAX_BUCKET_SAMPLES`, :data:`MAX_CROWDING`): the caller then uses a KD-tree.
    """
    pixels = np.ascontiguousarray(pixels, dtype=np.float64)
    xs, ys = np.ascontiguousarray(pixels[:, 0]), np.ascontiguousarray(pixels[:, 1])
    values = np.ascontiguousarray(values, dtype=np.float64)
    x0, y0, side, nx, ny = bucket_layout(pixels)
    starts, order = _sort_into_buckets(xs, ys, x0, y0, side, nx, ny)
    occupancy = np.diff(starts)
    if (occupancy.max() > MAX_BUCKET_SAMPLES
            or float(np.dot(occupancy, occupancy)) > MAX_CROWDING * len(xs)):
        return None
    queries = (np.arange(len(values), dtype=np.int64) if at is None
               else np.ascontiguousarray(at, dtype=np.int64))
    local_median = np.empty(len(queries))
    local_nmad = np.empty(len(queries))
    parts = max(1, threads) if len(queries) > 10_000 else 1
    bounds = np.linspace(0, len(queries), parts + 1).round().astype(int)

    def run(part: int) -> None:
        lo, hi = bounds[part], bounds[part + 1]
        _neighbour_statistics(xs, ys, values, queries[lo:hi], int(k), x0, y0, side, nx, ny,
                              starts, order, NMAD_FACTOR, local_median[lo:hi],
                              local_nmad[lo:hi])

    if parts == 1:
        run(0)
    else:
        with ThreadPoolExecutor(max_workers=parts) as pool:
            list(pool.map(run, range(parts)))
    return local_median, local_nmad


# The four cells a sample at (x0 + fx, y0 + fy) reaches, in the order their sums are
# added: (step_x, step_y), bilinear weight (1 − fx)(1 − fy), fx(1 − fy), (1 − fx)fy, fx·fy.
CORNERS = ((0, 0), (1, 0), (0, 1), (1, 1))


@njit(nogil=True, cache=True)
def _corner_sums(x, y, z, height, width, step_x, step_y, sums):
    """Sums (9, H·W) of w, w·dx, w·dy, w·dx², w·dx·dy, w·dy², w·z, w·z·dx, w·z·dy over the
    samples whose corner (step_x, step_y) lies in the grid with weight > 0; dx, dy are
    the offsets sample − cell centre."""
    sums[:] = 0.0
    for j in range(len(x)):
        col0, row0 = np.floor(x[j]), np.floor(y[j])
        fx, fy = x[j] - col0, y[j] - row0
        wx = fx if step_x else 1 - fx
        wy = fy if step_y else 1 - fy
        w = wx * wy
        col, row = np.int64(col0) + step_x, np.int64(row0) + step_y
        if not (col >= 0 and col < width and row >= 0 and row < height and w > 0):
            continue
        cell = row * width + col
        dx, dy, zj = fx - step_x, fy - step_y, z[j]
        sums[0, cell] += w
        sums[1, cell] += w * dx
        sums[2, cell] += w * dy
        sums[3, cell] += w * dx * dx
        sums[4, cell] += w * dx * dy
        sums[5, cell] += w * dy * dy
        sums[6, cell] += w * zj
        sums[7, cell] += w * zj * dx
        sums[8, cell] += w * zj * dy


def bilinear_moments(x: np.ndarray, y: np.ndarray, z: np.ndarray,
                     shape: tuple[int, int]) -> np.ndarray:
    """Weighted moments per cell of bilinearly splatted samples.

    Parameters
    ----------
    x, y : (N,) float64
        Finite sample positions, pixels (cell centres at integers).
    z : (N,) float64
        Finite sample values.
    shape : (H, W)

    Returns
    -------
    (9, H·W) float64
        Σw, Σw·dx, Σw·dy, Σw·dx², Σw·dx·dy, Σw·dy², Σw·z, Σw·z·dx, Σw·z·dy over the
        samples reaching each cell (bilinear weights w; offsets sample − cell centre).
    """
    height, width = shape
    x, y, z = (np.ascontiguousarray(a, dtype=np.float64) for a in (x, y, z))
    # the first corner's sums are the total so far (0 + s is s: a sum from +0 is never −0)
    moments = np.empty((9, height * width))
    _corner_sums(x, y, z, height, width, *CORNERS[0], moments)
    sums = np.empty_like(moments)
    for step_x, step_y in CORNERS[1:]:
        _corner_sums(x, y, z, height, width, step_x, step_y, sums)
        moments += sums
    return moments


# Cells of more samples than this are sorted by merging sorted runs of this many.
SORT_RUN = 64


@njit(nogil=True, cache=True)
def _stable_sort(values, lo, hi, scratch):
    """Sort ``values[lo:hi]`` in place, stably: insertion-sorted runs of :data:`SORT_RUN`,
    then merged pairwise (bottom-up, through ``scratch[:hi - lo]``).

    Equal values keep their order, as in ``np.argsort(kind="mergesort")``, so the sorted
    values are the same bit for bit (+0.0 and −0.0 included).  Loops only: numba's
    argsort and the fancy indexing around it were most of the kernel's compile.
    """
    for start in range(lo, hi, SORT_RUN):
        stop = min(start + SORT_RUN, hi)
        for i in range(start + 1, stop):
            value = values[i]
            j = i
            while j > start and values[j - 1] > value:
                values[j] = values[j - 1]
                j -= 1
            values[j] = value
    width = SORT_RUN
    while width < hi - lo:
        for left in range(lo, hi, 2 * width):
            middle, right = min(left + width, hi), min(left + 2 * width, hi)
            i, j = left, middle
            for k in range(right - left):
                # the left run's value first when equal: stable
                if j >= right or (i < middle and values[i] <= values[j]):
                    scratch[k] = values[i]
                    i += 1
                else:
                    scratch[k] = values[j]
                    j += 1
            for k in range(right - left):
                values[left + k] = scratch[k]
        width *= 2


@njit(nogil=True, cache=True)
def _cell_medians(cells, values, counts, grid):
    """``grid[c]`` = median of ``values[cells == c]`` (0.5 · (lower + upper) middle values)
    for every cell with ``counts[c]`` > 0."""
    starts = np.zeros(len(counts) + 1, dtype=np.int64)
    largest = 0
    for c in range(len(counts)):
        starts[c + 1] = starts[c] + counts[c]
        largest = max(largest, counts[c])
    fill = np.empty(len(counts), dtype=np.int64)
    for c in range(len(counts)):
        fill[c] = starts[c]
    bucket = np.empty(len(values))
    for j in range(len(values)):  # in sample order: each cell's values stay in that order
        bucket[fill[cells[j]]] = values[j]
        fill[cells[j]] += 1
    scratch = np.empty(largest if largest > SORT_RUN else 0)  # merges only above a run
    for c in range(len(counts)):
        size = counts[c]
        if size == 0:
            continue
        lo = starts[c]
        _stable_sort(bucket, lo, lo + size, scratch)
        grid[c] = 0.5 * (bucket[lo + (size - 1) // 2] + bucket[lo + size // 2])


def cell_medians(cells: np.ndarray, values: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Median of the values falling in each cell.

    Parameters
    ----------
    cells : (N,) int64
        Flat cell index of each sample, 0 … C − 1.
    values : (N,) float64
        Finite sample values.
    counts : (C,) int64
        Samples per cell (``np.bincount(cells, minlength=C)``).

    Returns
    -------
    (C,) float64
        The mean of the two middle values (the middle one for an odd count); NaN where
        no sample fell.
    """
    grid = np.full(len(counts), np.nan)
    _cell_medians(np.ascontiguousarray(cells, dtype=np.int64),
                  np.ascontiguousarray(values, dtype=np.float64),
                  np.ascontiguousarray(counts, dtype=np.int64), grid)
    return grid
