"""Dask worker preload: local workers leave Ctrl-C to the demtool process (issue 31).

A terminal's Ctrl-C reaches every process of its group, the ``--workers N`` Dask workers
included; each then printed a KeyboardInterrupt traceback (65 lines for two workers)
before demtool's one line.  Loaded in each local worker (``LocalCluster(preload=...)``),
:func:`dask_setup` makes the worker ignore SIGINT: demtool's own process catches it,
rolls back its outputs, and closing the cluster stops the workers.
"""

from __future__ import annotations

import signal
import threading
from typing import Any


def dask_setup(worker: Any = None) -> None:
    """Ignore SIGINT in this worker process (only the main thread may set handlers)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
