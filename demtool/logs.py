"""Logging to stderr and terminal-only progress reporting."""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")

LOGGER_NAME = "demtool"


class _HeldWarnings(logging.Handler):
    """At ``-q``: warnings held while the stage runs, then written when it succeeds and
    dropped when it fails, so a failing run says one line (its ``Error:``) on stderr, as
    ``-q`` promises (issue 46); ``-v`` and the default level show them as they come."""

    def __init__(self, target: logging.Handler) -> None:
        super().__init__()
        self.target = target
        self.held: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.held.append(record)

    def end(self, show: bool) -> None:
        held, self.held = self.held, []
        if show:
            for record in held:
                self.target.handle(record)


def configure_logging(verbosity: int) -> None:
    """Set the stderr log level: 0 → INFO, 1 → DEBUG, -1 → WARNING, -2 → ERROR.

    At -1 (``-q``) the warnings wait for the stage's end (:func:`release_warnings`)."""
    level = {1: logging.DEBUG, 0: logging.INFO, -1: logging.WARNING}.get(
        max(-2, min(1, verbosity)), logging.ERROR)
    logger = logging.getLogger(LOGGER_NAME)
    logger.setLevel(level)
    for old in [h for h in logger.handlers if getattr(h, "_demtool", False)]:
        logger.removeHandler(old)
    stream = logging.StreamHandler(sys.stderr)
    stream.setFormatter(logging.Formatter("%(name)s: %(message)s"))
    handler: logging.Handler = _HeldWarnings(stream) if level == logging.WARNING else stream
    handler._demtool = True  # type: ignore[attr-defined]
    logger.addHandler(handler)
    logger.propagate = False


def release_warnings(show: bool) -> None:
    """End of a stage at ``-q``: write the held warnings (``show``: it succeeded, or
    failed with a traceback) or drop them (it failed with its one ``Error:`` line)."""
    for handler in logging.getLogger(LOGGER_NAME).handlers:
        if isinstance(handler, _HeldWarnings):
            handler.end(show)


def route_library_warnings() -> None:
    """Send Python warnings (numpy's RuntimeWarnings, rasterio's, …) to the log at DEBUG
    under ``demtool.warnings`` instead of printing them raw on stderr.

    demtool issues no warnings of its own (its reports go through ``logging``); what
    reaches ``warnings`` comes from libraries on edge cases the stages already handle
    (an all-NaN window, an empty slice) and would only hide the real messages.  ``-v``
    shows them.  Called by the console entry point only (:func:`demtool.cli.main`), so
    library callers and the test suite (where warnings fail tests) keep Python's
    handling.
    """
    import warnings

    logger = logging.getLogger(f"{LOGGER_NAME}.warnings")

    def show(message, category, filename, lineno, file=None, line=None):
        logger.debug("%s: %s (%s:%d)", category.__name__, message, filename, lineno)

    warnings.showwarning = show


def get_logger(name: str) -> logging.Logger:
    """Logger for a module, under the ``demtool`` hierarchy."""
    if not name.startswith(LOGGER_NAME):
        name = f"{LOGGER_NAME}.{name}"
    return logging.getLogger(name)


def _show_progress() -> bool:
    logger = logging.getLogger(LOGGER_NAME)
    return sys.stderr.isatty() and logger.isEnabledFor(logging.INFO)


def progress(items: Iterable[T], description: str, total: int | None = None) -> Iterator[T]:
    """Yield ``items``, drawing a progress line on a terminal; silent in batch jobs."""
    if not _show_progress():
        yield from items
        return
    if total is None:
        try:
            total = len(items)  # type: ignore[arg-type]
        except TypeError:
            total = None
    start = time.perf_counter()
    count = 0
    for item in items:
        yield item
        count += 1
        elapsed = time.perf_counter() - start
        fraction = f"{count}/{total}" if total else f"{count}"
        sys.stderr.write(f"\r{description}: {fraction}  {elapsed:6.1f} s")
        sys.stderr.flush()
    sys.stderr.write("\n")
