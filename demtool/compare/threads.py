"""A second thread for one comparison, within the caller's share of the cores.

``compare`` runs the parts of a comparison that do not wait for each other (the
statistics before the alignment while it is fitted, the reference's spectrum while the
DEM's is computed, half the rows of the Nuth & Kääb sums…) on two threads when the grid
is large enough (:data:`THREADED_CELLS`) and the caller may use two
(:func:`demtool.tiling.tasks.usable_threads`: the cores, or a ``threads_limited``
block's limit).  The side thread runs each function as if on the calling thread
(:func:`demtool.tiling.tasks.carried`): in a copy of its context (so a
``threads_limited`` limit holds there too) and with its numba thread count (numba keeps
the count per thread: a new thread would get every core).  numpy, the FFT, LAPACK and
demtool's ``nogil`` kernels release the GIL; the same functions on the same arrays give
the same numbers on one thread or two.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, TypeVar

__all__ = ["THREADED_CELLS", "Side", "both", "threaded"]

T = TypeVar("T")
U = TypeVar("U")

#: Grids of fewer cells are compared on one thread (the demo's 512² and smaller): below
#: this a second thread saves less than it costs.
THREADED_CELLS = 1 << 20


def threaded(cells: int) -> bool:
    """Whether a comparison of ``cells`` cells runs its independent parts on two threads."""
    from demtool.tiling.tasks import usable_threads

    return cells >= THREADED_CELLS and usable_threads() >= 2


class Side:
    """A side thread (``on``) or none: :meth:`later` runs a function there, or at once
    here.  Use as a context manager; leaving it waits for what was started."""

    def __init__(self, on: bool) -> None:
        self._pool = ThreadPoolExecutor(max_workers=1) if on else None

    def __enter__(self) -> Side:
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)

    def later(self, function: Callable[[], T]) -> Future[T]:
        """``function()`` on the side thread (:func:`demtool.tiling.tasks.carried`), or
        now on this one."""
        if self._pool is not None:
            from demtool.tiling.tasks import carried

            return self._pool.submit(carried(function))
        done: Future[T] = Future()
        done.set_result(function())
        return done


def both(first: Callable[[], T], second: Callable[[], U], *, on: bool) -> tuple[T, U]:
    """``(first(), second())``, the second on a side thread when ``on`` (an exception
    of ``first`` is raised before one of ``second``, as in turn)."""
    if not on:
        return first(), second()
    with Side(True) as side:
        later = side.later(second)
        try:
            value = first()
        except BaseException:
            later.exception()  # wait for it, then raise the first's
            raise
        return value, later.result()

