"""The work of ``demtool fuse`` on the DEMs' overlap with the reference, on threads.

Before the cell-by-cell combination (:mod:`demtool.fuse.tiled`), :mod:`demtool.fuse.run`
co-registers each DEM to the reference on a window of their overlap and measures each
DEM against the others' consensus there.  This module reads those windows and computes
the consensus figures, each as independent pieces on the threads of
:func:`demtool.fuse.tiled.on_threads` (GDAL's decoding, numpy and the compiled kernels
release the GIL), with the numbers of one read per window and of the figures in turn:

* :func:`coreg_samples`: each DEM and the reference on the DEM's co-registration grid,
  the reference read once for windows that overlap, in two halves of rows;
* :func:`consensus_stack`: the DEMs, shifted, on the reference's window, each in two
  halves of rows;
* :func:`consensus_figures`: each DEM's NMAD against the others' median and the stack's
  NMAD (Huber's scale floor), beside each other.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

PathLike = str | os.PathLike

__all__ = ["consensus_figures", "consensus_stack", "coreg_samples"]


def coreg_samples(plans: dict[int, tuple[Any, tuple[int, int, int, int], int]],
                  dems: dict[int, tuple[Path, Any]], reference: tuple[PathLike, Any]
                  ) -> dict[int, tuple[np.ndarray | Exception, np.ndarray | Exception]]:
    """The co-registration's samples: each DEM and the reference on the DEM's window.

    Parameters
    ----------
    plans : {i: (grid, window, factor)}
        DEM i's co-registration grid (:func:`demtool.fuse.grids.coreg_grid`), its cells
        (row0, row1, col0, col1) and the grid's refinement factor.
    dems : {i: (path, GridSpec)}
    reference : (path, GridSpec)

    Returns
    -------
    {i: (dem, reference)}
        float64 samples (:func:`demtool.fuse.tiled.sample_on_grid`), or the
        :class:`demtool.errors.DemtoolError` its reading raised.  The reference is read
        once for the DEMs whose windows (on one grid) together cover no more cells than
        apart, on their windows' union (in two halves of rows), and each DEM's window cut
        from it: a cell's sample does not depend on the window it is read in, so these
        are the numbers of one read per DEM.  Every read (GDAL's decoding, the compiled
        sampler) runs on the threads of :func:`demtool.fuse.tiled.on_threads`.
    """
    from demtool.errors import DemtoolError
    from demtool.fuse.tiled import on_threads, sample_on_grid

    def area(w):
        return (w[1] - w[0]) * (w[3] - w[2])

    groups: list[list[Any]] = []  # [factor, grid, union of the windows, DEMs]
    for i, (grid, window, factor) in plans.items():
        for group in groups:
            union = (min(group[2][0], window[0]), max(group[2][1], window[1]),
                     min(group[2][2], window[2]), max(group[2][3], window[3]))
            if group[0] == factor and area(union) <= area(group[2]) + area(window):
                group[2] = union
                group[3].append(i)
                break
        else:
            groups.append([factor, grid, window, [i]])

    def read(task: tuple[str, int, int]) -> np.ndarray | Exception:
        kind, key, half = task
        try:
            if kind == "dem":
                grid, window, _ = plans[key]
                return sample_on_grid(dems[key][0], dems[key][1], grid, window)
            _, grid, (r0, r1, c0, c1), _ = groups[key]
            middle = (r0 + r1) // 2
            rows = (r0, middle) if half == 0 else (middle, r1)
            return sample_on_grid(reference[0], reference[1], grid, (*rows, c0, c1),
                                  what="reference DEM")
        except DemtoolError as exc:
            return exc

    # the reference in two halves of rows: with one read per DEM, the threads' reads
    # balance (one DEM's and the reference's window on three threads would not)
    tasks = [("dem", i, 0) for i in plans] + [("reference", g, half) for g in
                                               range(len(groups)) for half in (0, 1)]
    read_ = dict(zip(tasks, on_threads(read, tasks), strict=True))
    samples = {}
    for g, (_, _, union, members) in enumerate(groups):
        halves = [read_[("reference", g, half)] for half in (0, 1)]
        failed = [h for h in halves if isinstance(h, Exception)]
        ref = failed[0] if failed else np.concatenate(halves, axis=0)
        for i in members:
            r0, r1, c0, c1 = plans[i][1]
            cut = ref if isinstance(ref, Exception) else np.ascontiguousarray(
                ref[r0 - union[0]:r1 - union[0], c0 - union[2]:c1 - union[2]])
            samples[i] = (read_[("dem", i, 0)], cut)
    return samples


def consensus_stack(dems: Sequence[tuple[Path, Any, Sequence[float]]], target: Any,
                    window: tuple[int, int, int, int]) -> np.ndarray:
    """The DEMs, each shifted by its co-registration, on cells ``window`` of ``target``.

    Parameters
    ----------
    dems : sequence of (path, GridSpec, (dx_px, dy_px, dz))
    target : GridSpec
    window : (row0, row1, col0, col1)

    Returns
    -------
    (N, rows, cols) float64
        :func:`demtool.fuse.tiled.sample_on_grid` of each DEM.  Each DEM is read in two
        halves of rows, the 2 N halves on the threads of
        :func:`demtool.fuse.tiled.on_threads` (N = 3 DEMs on two threads would leave one
        idle for the last); a cell's sample does not depend on the window it is read in,
        so these are the numbers of one read per DEM.
    """
    from demtool.fuse.tiled import on_threads, sample_on_grid

    r0, r1, c0, c1 = window
    middle = (r0 + r1) // 2
    halves = ((r0, middle, c0, c1), (middle, r1, c0, c1))
    parts = on_threads(lambda task: sample_on_grid(*dems[task[0]][:2], target,
                                                   halves[task[1]], dems[task[0]][2]),
                       [(i, half) for i in range(len(dems)) for half in (0, 1)])
    return np.stack([np.concatenate(parts[2 * i:2 * i + 2], axis=0)
                     for i in range(len(dems))])


def consensus_figures(stack: np.ndarray, *, scale: bool) -> tuple[np.ndarray, float]:
    """Each DEM's NMAD against the others' median (:func:`demtool.fuse.core.consensus_nmad`)
    and, with ``scale``, the stack's NMAD (:func:`demtool.fuse.core.stack_nmad`; else 0).

    The N + 1 independent figures run on the threads of
    :func:`demtool.fuse.tiled.on_threads`, the stack's (two to three DEMs' worth) second:
    one thread takes it while the other takes the DEMs in turn, and the in-order map's
    bound (a result is awaited before the item two places after it is taken) never
    holds a DEM back behind it, so the threads end together.  Before, the N = 3 DEMs
    on two threads left one idle for the last, and the stack's NMAD ran after them on
    one.  The numbers of the functions above.
    """
    from demtool.fuse.core import nmad_against_others, stack_nmad
    from demtool.fuse.tiled import on_threads

    stack = np.asarray(stack, dtype=np.float64)
    valid = np.isfinite(stack)
    items: list[int | None] = list(range(len(stack)))
    if scale:
        items.insert(1, None)
    figures = dict(zip(items, on_threads(lambda i: stack_nmad(stack) if i is None else
                                         nmad_against_others(stack, i, valid), items),
                       strict=True))
    nmads = np.array([figures[i] for i in range(len(stack))], dtype=np.float64)
    return nmads, float(figures[None]) if scale else 0.0
