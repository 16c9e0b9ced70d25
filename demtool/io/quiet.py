"""Warning filters that concurrent threads can hold at once.

``warnings.catch_warnings`` saves the process's one filter list on entry and puts it back
on exit (Python ≤ 3.13; 3.14's context-aware warnings only under a flag).  Two threads
inside it at once put back each other's lists: the first to leave drops the filters the
second set and still holds (a warning it meant to hide shows), the last to leave restores
a list holding the first one's filter for good.  Tiles run on threads
(:mod:`demtool.tiling.local_threads`), and each of them reads its windows, so the readers'
"ignore GDAL's not-georeferenced warning" could not be a ``catch_warnings`` block.

:func:`ignoring` instead adds one filter to the list in place, shared by every thread
that holds it (counted under a lock), and removes that entry (the very tuple, by
identity) when the last holder leaves: no list is swapped, so the filters other threads
set meanwhile stay as they are.  A holder that finds the entry gone (the list was swapped
by a ``catch_warnings`` that ended while another holder was inside, e.g. a test's own
filters put back while a tile thread still wrote) puts it back in the list in force.
"""

from __future__ import annotations

import threading
import warnings
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["ignoring"]

_LOCK = threading.Lock()
_HELD: dict[type[Warning], list] = {}  # category -> [holders, the filter entry]


def _filters_changed() -> None:
    """Tell the warnings machinery its filters changed (so each module's registry of
    warnings already shown is re-checked; CPython's own ``filterwarnings`` does this)."""
    changed = getattr(warnings, "_filters_mutated", None)
    if changed is not None:
        changed()


@contextmanager
def ignoring(category: type[Warning]) -> Iterator[None]:
    """Ignore warnings of ``category`` (and its subclasses) while inside, in every thread.

    Safe for threads entering and leaving in any order (see the module docstring); the
    filter is in place from the first holder's entry to the last holder's exit.  A filter
    list swapped meanwhile by someone else's ``catch_warnings`` may keep the entry
    (this category stays ignored): it never drops other filters.  Each entry checks that
    the filter is in the list in force (not only that it is held), so one swapped list
    cannot leave a later holder unprotected.

    Parameters
    ----------
    category : Warning subclass
        E.g. rasterio's ``NotGeoreferencedWarning`` (GDAL's note on every image-frame
        raster, which demtool writes on purpose).
    """
    with _LOCK:
        held = _HELD.get(category)
        if held is None:
            entry = ("ignore", None, category, None, 0)
            warnings.filters.insert(0, entry)
            _filters_changed()
            held = _HELD[category] = [0, entry]
        elif not any(item is held[1] for item in warnings.filters):
            warnings.filters.insert(0, held[1])
            _filters_changed()
        held[0] += 1
    try:
        yield
    finally:
        with _LOCK:
            held[0] -= 1
            if held[0] == 0:
                del _HELD[category]
                for index, item in enumerate(warnings.filters):
                    if item is held[1]:
                        del warnings.filters[index]
                        break
                _filters_changed()
