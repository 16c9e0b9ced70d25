"""Logging to stderr and terminal-only progress reporting."""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")

LOGGER_NAME = "demtool"


def configure_logging(verbosity: int) -> None:
    """Set the stderr log level: 0 → INFO, 1 → DEBUG, -1 → WARNING, -2 → ERROR."""
    level = {1: logging.DEBUG, 0: logging.INFO, -1: logging.WARNING}.get(
        max(-2, min(1, verbosity)), logging.ERROR)
    logger = logging.getLogger(LOGGER_NAME)
    logger.setLevel(level)
    if not any(getattr(h, "_demtool", False) for h in logger.handlers):
        handler = logging.StreamHandler()
        handler._demtool = True  # type: ignore[attr-defined]
        handler.setFormatter(logging.Formatter("%(name)s: %(message)s"))
        logger.addHandler(handler)
    for handler in logger.handlers:
        if getattr(handler, "_demtool", False):
            handler.setStream(sys.stderr)
    logger.propagate = False


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
