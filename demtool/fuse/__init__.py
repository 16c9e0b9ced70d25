"""``fuse``: one DEM from several DEMs of one area (ASP ``dem_mosaic``-like).

* :mod:`~demtool.fuse.core` — border weights, per-cell outlier rejection, weighted
  median / mean, count, spread (NMAD) and combined error; co-registration shifts
  (compare's alignment).
* :mod:`~demtool.fuse.params` — :class:`FuseParams`.
* :mod:`~demtool.fuse.run` — :func:`run_fuse`, files in, files out.
* :mod:`~demtool.fuse.tiled` — the tiled job (Dask, bounded memory).

Names are imported lazily (PEP 562), so ``demtool fuse --help`` does not load numba.
"""

from demtool.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "core": ("METHODS", "FuseResult", "border_weights", "combine", "consensus_nmad",
             "estimate_shift"),
    "run": ("run_fuse",),
})
