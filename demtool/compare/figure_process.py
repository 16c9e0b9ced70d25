"""One figure drawn in a forked process while this process's threads draw the others.

matplotlib draws under Python's global interpreter lock: the artists, the transforms,
contourpy's ``mpl2014`` contour generator and Agg's stroking of paths all hold it
(py-spy ``--gil`` of a 4096² comparison: the DEMs figure holds it for all of its
4 CPU s, its 2 × 20 contour levels of ~0.8 M vertices a panel for half of them).  Two
figure threads therefore take turns rather than share the cores.  A forked child has
its own interpreter lock: the DEMs figure drawn there runs beside the other figures'
threads.

The child is a copy of this process at the fork (no pickling of the grids: their pages
are shared copy-on-write) that calls one function, writes the bytes it returns to a
pipe and leaves with :func:`os._exit` (no ``atexit``, no flushing of this process's
buffers).  It is forked before the figure threads start, so no thread of this process
holds a matplotlib or logging lock at the fork; it runs only numpy and matplotlib, never
numba's thread pool, GDAL or PROJ.  Forking a process that has threads (numba's idle
workers) is what Python 3.12's ``DeprecationWarning`` is about: this one narrow use is
why it is silenced here.  On anything but Linux, or when the fork or the child fails,
the function runs in this process instead: the same bytes, or the same exception.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable

__all__ = ["Apart", "forking"]


def forking() -> bool:
    """Whether figures may be drawn in a forked child (Linux: ``fork`` is cheap and safe
    for a child that only runs numpy and matplotlib; macOS' system libraries are not
    fork-safe and Windows has no fork)."""
    return sys.platform.startswith("linux") and hasattr(os, "fork")


class Apart:
    """``make()`` (returning bytes) started in a forked child; :meth:`result` waits for
    it.  ``cpu_s``: the child's CPU seconds (user + system, from ``wait4``) once
    collected, which the caller adds to its phase's CPU (``time.process_time`` counts
    this process only).  Use as a context manager so an early exit reaps the child."""

    def __init__(self, make: Callable[[], bytes]) -> None:
        self._make = make
        self.cpu_s = 0.0
        self._pid: int | None = None
        self._pipe: int | None = None
        if not forking():
            return
        from demtool.io.quiet import ignoring

        read, write = os.pipe()
        try:
            with ignoring(DeprecationWarning):  # Python ≥ 3.12: fork with threads
                pid = os.fork()
        except OSError:
            os.close(read)
            os.close(write)
            return
        if pid == 0:  # the child: draw, send, leave (never returns into the caller)
            code = 1
            try:
                os.close(read)
                view = memoryview(make())
                while view:
                    view = view[os.write(write, view):]
                code = 0
            finally:
                os._exit(code)
        os.close(write)
        self._pid, self._pipe = pid, read

    def __enter__(self) -> Apart:
        return self

    def __exit__(self, kind: type[BaseException] | None, *exc: object) -> None:
        if kind is not None and self._pid is not None:  # left early: stop the drawing
            import signal

            os.kill(self._pid, signal.SIGKILL)
        self._reap()

    def _reap(self) -> bool:
        """Close the pipe and wait for the child; True when it exited cleanly."""
        if self._pid is None:
            return False
        if self._pipe is not None:
            os.close(self._pipe)  # a child still writing gets EPIPE and leaves
            self._pipe = None
        _, status, usage = os.wait4(self._pid, 0)
        self._pid = None
        self.cpu_s = usage.ru_utime + usage.ru_stime
        return os.waitstatus_to_exitcode(status) == 0

    def result(self) -> bytes:
        """The child's bytes, or ``make()`` here when there is no child or it failed
        (the same bytes, or the same exception raised in this process)."""
        if self._pid is None or self._pipe is None:
            return self._make()
        chunks = []
        while chunk := os.read(self._pipe, 1 << 20):
            chunks.append(chunk)
        return b"".join(chunks) if self._reap() else self._make()
