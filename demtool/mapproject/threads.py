"""Every core of one process on the map-projected stages' untiled paths.

``mapproject``'s in-process loop and ``dem --mapprojected``'s raw coordinates run
independent pieces of work (map tiles; batches of ground points) on a pool of threads,
each piece with its share of numba's threads.  The compiled kernels they call release
the GIL (``nogil=True``), numpy's array loops and GDAL's reads and writes do too, so
the threads overlap in every part of the work, not only inside the parallel kernels.
Results come back in submission order and each piece is computed exactly as it would
be alone, so the output does not depend on the number of threads.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from demtool.tiling.rows import ordered_map  # noqa: F401 - the stages' import of it

#: ground points per batch of :func:`ground_to_image_threaded` (below it: one batch)
MIN_BATCH = 32_768


def available_threads() -> int:
    """Threads the calling thread should use: its numba thread count (by default
    ``NUMBA_NUM_THREADS``, the cores this process may run on; less in a tile engine's
    worker that shares the machine, :meth:`demtool.tiling.TileJob.compute`'s
    ``threads``)."""
    import numba

    return max(1, int(numba.get_num_threads()))


def batched(function: Callable[..., tuple[np.ndarray, ...]], *arrays: np.ndarray,
            threads: int | None = None, min_batch: int | None = None
            ) -> tuple[np.ndarray, ...]:
    """``function(*arrays)`` evaluated in batches along the arrays' first axis on every
    core, each batch's results written into whole arrays on its own thread.

    For functions that treat each element on its own (a sensor model's ground-to-image:
    a line scanner's secant search stops point by point; ray intersections), so the
    result equals one call on all elements.  The batches are ``4 × threads`` (at least
    ``min_batch`` elements each) so elements that take longer spread over the threads.

    Parameters
    ----------
    function : callable
        Takes the arrays (sliced alike) and returns a tuple of arrays whose first axis
        is the elements' (every batch the same dtypes and trailing shapes).
    *arrays : (N, ...) arrays
    threads : int, optional
        Default :func:`available_threads`.
    min_batch : int, optional
        Default :data:`MIN_BATCH`.

    Returns
    -------
    tuple of arrays, as ``function`` returns them for all N elements.
    """
    n = len(arrays[0])
    threads = available_threads() if threads is None else max(1, int(threads))
    min_batch = MIN_BATCH if min_batch is None else min_batch
    batches = min(4 * threads, n // max(int(min_batch), 1))
    if threads == 1 or batches < 2:
        return tuple(function(*arrays))
    bounds = np.linspace(0, n, batches + 1).astype(np.int64)
    results: list[np.ndarray] = []
    made = threading.Lock()

    def batch(k: int) -> None:
        # each batch writes into whole arrays (made of the first finished batch's dtypes
        # and trailing shapes) instead of the calling thread concatenating them after
        lo, hi = bounds[k], bounds[k + 1]
        found = [np.asarray(part) for part in function(*(a[lo:hi] for a in arrays))]
        with made:
            if not results:
                results.extend(np.empty((n, *part.shape[1:]), dtype=part.dtype)
                               for part in found)
        for result, part in zip(results, found, strict=True):
            result[lo:hi] = part

    for _ in ordered_map(batch, range(batches), threads=threads):
        pass
    return tuple(results)


def ground_to_image_threaded(sensor: Any, xyz: np.ndarray, *, threads: int | None = None,
                             min_batch: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``sensor.ground_to_image(xyz)`` in batches of points on every core (:func:`batched`;
    the same values as one call).

    Parameters
    ----------
    sensor : demtool.sensors.base.SensorModel
    xyz : (N, 3) float64
        Body-fixed metres.
    threads : int, optional
        Default :func:`available_threads`.

    Returns
    -------
    line, sample : (N,) float64, CSM image coordinates (NaN where not seen).
    """
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    warm(sensor)
    line, sample = batched(sensor.ground_to_image, xyz, threads=threads, min_batch=min_batch)
    return line, sample


@contextlib.contextmanager
def phase(timings: dict[str, float], name: str) -> Iterator[None]:
    """Add the block's wall seconds to ``timings[name]`` and the process's CPU seconds
    (every thread's) to ``timings[name + "_cpu"]`` (a sidecar's ``timings_s``: their
    ratio is the cores the phase used)."""
    import time

    wall, cpu = time.perf_counter(), time.process_time()
    try:
        yield
    finally:
        timings[name] = round(timings.get(name, 0.0) + time.perf_counter() - wall, 3)
        key = f"{name}_cpu"
        timings[key] = round(timings.get(key, 0.0) + time.process_time() - cpu, 3)


def warm(sensor: Any) -> None:
    """Fill a sensor model's lazily cached state (a line scanner's affine first guess)
    in this thread, before threads share the model."""
    guess = getattr(sensor, "_affine_guess", None)
    if callable(guess):
        with contextlib.suppress(ValueError):
            guess()


def load_tile_kernels(sensor: Any = None) -> bool:
    """Load the tiles' compiled kernels (numba's cache) by calling them on a few cells,
    with the argument types the tiles call them with (so no other specialisation is
    compiled; tests/mapproject/test_kernels_ahead.py checks the types): the lattice
    interpolation and the bicubic resampling, the image window's bounds and, for a line
    scanner (``sensor`` with ``_detector_view_fast``), its ground-to-image pose kernel.
    True when every one ran; a kernel that fails here loads at the first tile as before.

    Reads ``sensor``'s arrays only (none of its lazily cached state)."""
    try:
        from demtool.mapproject.core import _interpolate_lattice
        from demtool.mapproject.sampling import image_window, resample_tile

        nodes = np.zeros((1, 2, 2))
        heights = np.zeros((2, 2))
        _interpolate_lattice(nodes, nodes.copy(), np.zeros(1), heights, 2.0,
                             np.empty((2, 2)), np.empty((2, 2)))
        resample_tile(np.zeros((4, 4), dtype=np.float32), (0, 0), np.full((2, 2), 2.0),
                      np.full((2, 2), 2.0), 4, 4)
        lines, samples = (4, 4) if sensor is None else (sensor.lines, sensor.samples)
        image_window(np.full((2, 2), 1.0), np.full((2, 2), 1.0), lines, samples)
        view = getattr(sensor, "_detector_view_fast", None)
        if callable(view):
            # a point between the sensor and the body's centre (values unused)
            below = 0.5 * np.asarray(sensor.positions, dtype=np.float64)[
                len(sensor.positions) // 2]
            with np.errstate(all="ignore"):
                view(np.array([0.5 * lines]), below[None])
    except Exception:  # noqa: BLE001 - a load ahead only: the first tile loads what failed
        return False
    return True


class KernelsAhead:
    """:func:`load_tile_kernels` of ``sensor`` on a thread of its own, started while the
    calling thread prepares a run (the map grid, the DEM under the footprint, the
    checks), so the tiles find their kernels loaded (loaded at the first tiles instead,
    each tile thread links some of them while the others wait for numba's compiler
    lock: ~0.1-0.2 CPU s of every tile thread's first tile).  :meth:`wait` before the
    tiles start."""

    def __init__(self, sensor: Any = None) -> None:
        self.sensor = sensor
        self.loaded: bool | None = None
        from demtool.tiling.side_threads import start_side_thread

        # joined by wait(), or when the command ends (a refused input raises before it)
        self._thread = start_side_thread(self._run, "demtool-kernels-ahead")

    def _run(self) -> None:
        self.loaded = load_tile_kernels(self.sensor)

    def wait(self) -> bool | None:
        """Wait for the loading to end; whether it loaded every kernel."""
        self._thread.join()
        return self.loaded


__all__ = ["MIN_BATCH", "KernelsAhead", "available_threads", "batched",
           "ground_to_image_threaded", "load_tile_kernels", "ordered_map", "phase",
           "warm"]
