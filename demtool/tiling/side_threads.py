"""Threads a stage starts beside its own work (kernels loaded ahead, imports ahead, input
hashes), joined before the command ends, however it ends.

A stage starts such a thread early, before its checks, so its work overlaps the
preparation.  When a check then refuses the input, the stage raises at once; the
thread would go on (numba compiling a kernel into the cache, scipy importing) after the
command's ``Error:`` line, in the process of whoever called the command.  In a test
suite or a notebook that process runs the next command meanwhile, and the thread's
library calls change process-wide state under it: numba formats a typing message in a
``colorama`` init/deinit pair that puts back the ``sys.stderr`` it saw (the next
command's error went to the previous one's stream), and ``warnings.catch_warnings``
puts back the filter list it saw (CI, issue 47).  :func:`join_side_threads`, called by
the command group (:class:`demtool.cli.DemtoolGroup`) when a command ends, waits for
them; a stage called as a library joins its own.
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable
from typing import Any

_STARTED: weakref.WeakSet[threading.Thread] = weakref.WeakSet()
_LOCK = threading.Lock()


def start_side_thread(target: Callable[..., Any], name: str,
                      args: tuple = ()) -> threading.Thread:
    """Start ``target(*args)`` on a daemon thread named ``name``, registered for
    :func:`join_side_threads`; returns the (started) thread."""
    thread = threading.Thread(target=target, args=args, name=name, daemon=True)
    with _LOCK:
        _STARTED.add(thread)
    thread.start()
    return thread


def join_side_threads() -> int:
    """Wait for every side thread still running; returns how many were waited for.

    Not after an interrupt (Ctrl-C, SIGTERM): the process ends, and the threads are
    daemons.
    """
    with _LOCK:
        running = [thread for thread in _STARTED if thread.is_alive()]
    for thread in running:
        thread.join()
    return len(running)


__all__ = ["join_side_threads", "start_side_thread"]
