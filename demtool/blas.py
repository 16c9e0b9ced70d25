"""OpenBLAS's worker threads, set before numpy is imported.

numpy and scipy each load their own OpenBLAS, and each starts a worker thread per core
that spins for 2^28 cycles (OpenBLAS's ``thread_timeout``, about 0.1 s) before it
sleeps — once when the library loads and again after every threaded BLAS call.  On a
2-core machine that is 0.2 CPU s of every demtool command spent spinning, and a core
taken from demtool's own threads (SGM's two sweeps, numba's parallel loops) after a
BLAS call.  ``OPENBLAS_THREAD_TIMEOUT=4`` (OpenBLAS's smallest, 2^4 cycles) puts the
workers to sleep at once; BLAS stays multi-threaded, only waking its workers costs a
few microseconds more per call.
"""

from __future__ import annotations

import os
import sys

ENV = "OPENBLAS_THREAD_TIMEOUT"
SHORTEST = "4"  # OpenBLAS clamps the exponent to 4 … 30 cycles (2^n)


def configure() -> bool:
    """Set ``OPENBLAS_THREAD_TIMEOUT`` to its shortest unless the user set it.

    Called on ``import demtool`` (before numpy).  OpenBLAS reads the variable when it
    loads, so it has no effect where numpy was imported first (a user's own script).

    Returns
    -------
    bool
        True when the setting will take effect: numpy not imported yet and the
        variable not set by the user.
    """
    if ENV in os.environ or "numpy" in sys.modules:
        return False
    os.environ[ENV] = SHORTEST
    return True
