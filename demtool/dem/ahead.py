"""Modules a later, serial step of ``demtool dem`` needs, imported ahead on a thread of
their own while the run's parallel work goes on.

The tiled sensor-model route (:mod:`demtool.dem.tiled_map_run`) imports the gap fill's
modules (:mod:`demtool.imaging.interpolate`: ``scipy.sparse.linalg``; ``scipy.ndimage``)
only once its measured grid is done: the coarse global fill on the calling thread
while the tile threads wait, then the first fill tile of each thread, one of them
waiting for the other's import.  Those imports are Python (they hold the GIL), about
0.6 CPU s on a 2-core VM, and they ran with nothing beside them.  Imported on the
calling thread once the first points tile is done, while the others run (numba kernels
that release the GIL; :func:`import_after_first_tile`), they take the cores' spare time
instead.  An import that fails here is left to fail again where the module is used,
with its usual error.

The untiled map-projected route (:mod:`demtool.dem.run_mapprojected`) imports the same
modules in its grid phase, on the thread of the heights' medians and the gap fill
(:func:`demtool.dem.sensors.dem_on_map`), the phase's longer chain; they are imported
beside its ray computations instead, on a thread of their own (:func:`import_ahead`).
"""

from __future__ import annotations

import threading
from collections.abc import Iterable

#: the modules of the fill (:func:`demtool.dem.tiled_grids.prepare_fill`,
#: :func:`demtool.dem.tiled_grids.fill_core`, :func:`demtool.dem.grid.fill_and_smooth`)
FILL_MODULES = ("demtool.imaging.interpolate", "scipy.ndimage")


def import_ahead(names: Iterable[str]) -> threading.Thread:
    """Import ``names`` on a daemon thread (started); returns the thread.

    Join it before other threads may import the same packages: Python's module locks
    make a thread importing a module meanwhile wait for this one's import, but two
    threads importing one package's modules in crossing orders may each get the
    other's half-initialised module (importlib's answer to the deadlock).  The callers
    start it where the other threads import none of them (the untiled route's ortho
    rays: demtool's own modules and numba's) and join it before the step that uses
    them (long done by then: the join costs nothing).
    """
    import sys

    from demtool.tiling.side_threads import start_side_thread

    todo = [name for name in names if name not in sys.modules]
    return start_side_thread(_import_all, "demtool-import-ahead", args=(todo,))


def import_after_first_tile(names: Iterable[str]):
    """An ``on_tile`` callback of :func:`demtool.tiling.distributed.run_tiles` that
    imports ``names`` on the calling thread once the first tile is done, while the
    workers compute the next ones (the calling thread only waits for them there).

    On the calling thread rather than a thread of its own: an extra thread alive beside
    the tile threads gets a malloc arena of its own, and the tiled run's peak resident
    memory rose by 40-490 MB (2048²; the later passes' threads reuse arenas that hold
    freed memory).  The first call (the tiles found in the cache) imports nothing.
    """
    todo, calls = list(names), [0]

    def on_tile() -> None:
        calls[0] += 1
        if calls[0] == 2:
            _import_all(todo)

    return on_tile


def _import_all(names: Iterable[str]) -> None:
    """Import ``names``; one that fails is left to fail again where it is used."""
    import importlib

    for name in names:
        try:
            importlib.import_module(name)
        except Exception:  # noqa: BLE001 - raised again where the module is used
            continue
