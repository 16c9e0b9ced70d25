"""Running COLMAP inside demtool: signal handlers, log files, interruptible calls.

Three things COLMAP (through pycolmap) does to a host process, and what demtool does
about them (issue 16, class 6):

* **Signal handlers.**  Importing pycolmap installs glog's failure signal handler
  (``google::InstallFailureSignalHandler``) for SIGTERM among others: a SIGTERM then
  prints a C stack dump and kills the process with status 143, skipping demtool's
  handler (which turns SIGTERM into an interrupt, exit 130, no output).
  :func:`load_pycolmap` re-installs Python's own handlers after the import.
* **Log files.**  glog writes ``*.log.INFO.*`` files into ``/tmp`` unless it logs
  to stderr; :func:`load_pycolmap` always sets ``logtostderr`` (no files) and keeps
  the level at FATAL unless :func:`set_colmap_verbosity` asks for COLMAP's log.
* **Long C++ calls.**  Python runs signal handlers only between bytecodes, so an
  interrupt would wait for a mapping to finish.  The file-based steps (feature
  extraction, matching, incremental mapping: their results are in COLMAP's database
  and model folders) run in a child process (:func:`run_in_child`) that is killed on
  an interrupt; cancelling them in-process through COLMAP's ``CancellationToken``
  leaves matcher threads that abort the interpreter at exit with a C stack dump.
  In-memory bundle adjustments run in a worker thread (:func:`call_interruptibly`)
  so the interrupt is raised as soon as the adjustment returns.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from typing import Any

_HANDLED_SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGINT")
                         if hasattr(signal, name))
_verbose = False


def _restore_python_handlers(handlers: dict) -> None:
    """Re-install Python's handlers at the C level (``signal.signal`` calls sigaction)."""
    if threading.current_thread() is not threading.main_thread():
        return
    for signum, handler in handlers.items():
        if handler is not None:
            signal.signal(signum, handler)


def _configure_logging(pycolmap) -> None:
    pycolmap.logging.logtostderr = True  # never write log files (glog's default is /tmp)
    pycolmap.logging.minloglevel = 0 if _verbose else 3
    pycolmap.logging.stderrthreshold = 0 if _verbose else 3


def load_pycolmap():
    """Import pycolmap, keeping Python's SIGTERM/SIGINT handlers and writing no log files.

    Every use of pycolmap in :mod:`demtool.bundle` goes through this function.

    Returns
    -------
    module
        The ``pycolmap`` module.
    """
    handlers = {signum: signal.getsignal(signum) for signum in _HANDLED_SIGNALS}
    import pycolmap

    _restore_python_handlers(handlers)
    _configure_logging(pycolmap)
    return pycolmap


def set_colmap_verbosity(verbose: bool) -> None:
    """Show COLMAP's own (glog) log on stderr only when ``verbose``; never in files."""
    global _verbose
    _verbose = bool(verbose)
    load_pycolmap()


@contextlib.contextmanager
def colmap_output() -> Iterator[None]:
    """Silence what COLMAP's C++ code writes to the stderr file descriptor, unless
    verbose (some of its messages ignore glog's level flags)."""
    if _verbose:
        yield
        return
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "wb") as devnull:
            os.dup2(devnull.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _child(function: Callable[..., Any], args: tuple, kwargs: dict, connection) -> None:
    """Body of :func:`run_in_child`'s process: die quietly on signals, report errors."""
    for signum in _HANDLED_SIGNALS:
        signal.signal(signum, signal.SIG_DFL)
    try:
        function(*args, **kwargs)
    except BaseException as exc:  # reported to the parent as one line
        connection.send(f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")
        connection.close()
        os._exit(1)
    connection.send(None)
    connection.close()
    os._exit(0)


def run_in_child(function: Callable[..., Any], *args: Any, **kwargs: Any) -> None:
    """Run a file-based pycolmap step (results on disk) in a forked child process.

    The parent waits in 0.1 s slices, so SIGINT/SIGTERM reach demtool's handlers; on
    an interrupt the child is killed (SIGKILL: nothing of COLMAP's runs on) and the
    interrupt re-raised.  COLMAP's stderr chatter is silenced unless verbose.

    Raises
    ------
    ProcessingError
        The step failed or the child died (the first line of its error, or the signal).
    """
    import multiprocessing

    from demtool.errors import ProcessingError

    load_pycolmap()
    context = multiprocessing.get_context("fork")
    receiver, sender = context.Pipe(duplex=False)
    with colmap_output():
        process = context.Process(target=_child, args=(function, args, kwargs, sender),
                                  name="demtool-colmap", daemon=True)
        process.start()
        sender.close()
        try:
            while process.is_alive():
                process.join(0.1)
        except BaseException:
            process.kill()
            process.join()
            raise
        finally:
            try:
                message = receiver.recv() if receiver.poll() else None
            except (EOFError, OSError):  # the child died without a word
                message = None
            receiver.close()
    if process.exitcode != 0:
        what = getattr(function, "__name__", "COLMAP step")
        detail = message or (f"killed by signal {-process.exitcode}"
                             if process.exitcode < 0 else f"exit status {process.exitcode}")
        raise ProcessingError(f"COLMAP's {what} failed: {detail}")


def call_interruptibly(function: Callable[..., Any], *args: Any, cancellable: bool = True,
                       **kwargs: Any) -> Any:
    """Call a long pycolmap function so that SIGINT/SIGTERM interrupt it promptly.

    The call runs in a worker thread while the main thread waits in 0.1 s slices, so
    Python's signal handlers run; on an interrupt the COLMAP call is cancelled (its
    ``cancellation_token`` argument, when ``cancellable``), the worker is joined, and
    the interrupt is re-raised.  COLMAP's stderr chatter is silenced unless verbose.

    Returns
    -------
    Whatever ``function`` returns; its exceptions are re-raised in the caller.
    """
    pycolmap = load_pycolmap()
    token = pycolmap.CancellationToken() if cancellable else None
    if token is not None:
        kwargs["cancellation_token"] = token
    with colmap_output():
        if threading.current_thread() is not threading.main_thread():
            return function(*args, **kwargs)
        outcome: dict[str, Any] = {}

        def work() -> None:
            try:
                outcome["value"] = function(*args, **kwargs)
            except BaseException as exc:  # re-raised in the caller's thread
                outcome["error"] = exc

        worker = threading.Thread(target=work, name="demtool-colmap", daemon=True)
        worker.start()
        try:
            while worker.is_alive():
                worker.join(0.1)
        except BaseException:
            if token is not None:
                token.cancel()
            worker.join()
            raise
    if "error" in outcome:
        raise outcome["error"]
    return outcome.get("value")


def bundle_adjustment_options(*, focal_length: bool, principal_point: bool,
                              extra_params: bool, workers: int):
    """pycolmap's ``BundleAdjustmentOptions``, quiet, refining the named intrinsics.

    Parameters
    ----------
    focal_length, principal_point, extra_params : bool
        Which intrinsics of the free cameras the adjustment refines (``extra_params``:
        the distortion terms).
    workers : int
        Ceres threads; 0: all cores (Ceres's -1).
    """
    options = load_pycolmap().BundleAdjustmentOptions()
    options.print_summary = False
    options.refine_focal_length = focal_length
    options.refine_principal_point = principal_point
    options.refine_extra_params = extra_params
    options.ceres.solver_options.num_threads = workers if workers > 0 else -1
    return options
