"""Imported by the forkserver of a local Dask cluster's workers (``SgmTileJob.preload``):
loads the compiled kernels of a census match once, before the workers are forked.

Each worker process otherwise loads them from numba's cache at its first tile (about a
second of CPU each: LLVM links every kernel); forked from a server that loaded them, the
workers start matching at once.  The server is started while the calling process plans
the tiles (:func:`demtool.tiling.distributed.prestart_local_workers`), so the loading
overlaps that work instead of delaying the first tiles.  Importing this module never
fails: a kernel that cannot load here loads in the worker as before.
"""

from __future__ import annotations


def load_kernels() -> bool:
    """Match a small random pair (census, the default filters and fill); True when it ran."""
    try:
        import numpy as np

        from demtool.sgm.matcher import sgm

        rng = np.random.default_rng(0)
        left = rng.normal(500.0, 20.0, size=(48, 96)).astype(np.float32)
        right = np.roll(left, -4, axis=1)
        left[0, 0] = np.nan  # the kernels of invalid pixels too
        sgm(left, right, min_disparity=0, num_disparities=24, cost="census", workers=1)
    except Exception:  # noqa: BLE001 - a warm-up only: the worker loads what failed
        return False
    return True


LOADED = load_kernels()
