"""Aggregated-cost volumes S reused between the SGM passes of a run's tiles.

Kept apart from :mod:`demtool.sgm.strips` so that the process planning the tiles
(:func:`demtool.sgm.tiled.sgm_tiled`) imports no compiled kernel.
"""

from __future__ import annotations

import contextvars
import math
import threading
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from demtool.sizes import release_free_memory


class VolumePool:
    """Aggregated-cost volumes S kept between the SGM passes of a run's tiles, one a
    thread (:func:`reusing_volumes`).

    A pass maps a fresh S otherwise, and the kernel clears every page of it on first
    touch: 270 MB for a 1024-px census tile with its margins and 96 disparities,
    0.1–0.25 of the tile's 0.8–1.1 CPU s (loaded 2-core VM).  Every row of S is stored
    before it is read (:func:`demtool.sgm.strips.match_strip`), so a volume holding an
    earlier tile's sums gives the same disparity.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._held: dict[int, np.ndarray] = {}
        self.mapped = 0  # volumes mapped new (the passes that could not reuse one)

    def take(self, shape: tuple[int, ...]) -> np.ndarray:
        """A uint16 array of ``shape``: the calling thread's kept volume when it is large
        enough (its contents arbitrary), else a new one (the kept one dropped first)."""
        size = math.prod(shape)
        with self._lock:
            flat = self._held.pop(threading.get_ident(), None)
        if flat is None or flat.size < size:
            del flat
            release_free_memory()
            flat = np.empty(size, dtype=np.uint16)
            self.mapped += 1
        return flat[:size].reshape(shape)

    def keep(self, volume: np.ndarray) -> None:
        """Keep ``volume`` (from :meth:`take`) for the calling thread's next pass."""
        flat = volume.base if volume.base is not None else volume
        with self._lock:
            self._held[threading.get_ident()] = flat.reshape(-1)

    def clear(self) -> None:
        """Drop every kept volume."""
        with self._lock:
            self._held.clear()


_POOL: contextvars.ContextVar[VolumePool | None] = contextvars.ContextVar(
    "demtool_sgm_volumes", default=None)


@contextmanager
def reusing_volumes() -> Iterator[VolumePool]:
    """Within the block (and the contexts copied from it: the tile threads of
    :mod:`demtool.tiling.local_threads`), SGM passes keep their volume S for the same
    thread's next pass instead of mapping a new one (:class:`VolumePool`); all are
    dropped at the end of the block."""
    pool = VolumePool()
    token = _POOL.set(pool)
    try:
        yield pool
    finally:
        _POOL.reset(token)
        pool.clear()


def current_pool() -> VolumePool | None:
    """The pool of the enclosing :func:`reusing_volumes` block, or None."""
    return _POOL.get()
