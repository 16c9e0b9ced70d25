"""Run a computation once on one row part and once split into several, for the tests that
pin a kernel driven by :func:`demtool.tiling.rows.on_row_parts` to the one-thread result."""

from __future__ import annotations

from collections.abc import Callable

from demtool.tiling import rows
from demtool.tiling.tasks import threads_limited


def whole_and_split(monkeypatch, compute: Callable[[], object], parts: int = 3):
    """``compute()`` on the calling thread alone, then with its row kernels split into up
    to ``parts`` parts on helper threads; returns both results and the part lists the
    split run used (each kernel call's ``(start, stop)`` parts)."""
    with threads_limited(1):
        whole = compute()
    monkeypatch.setattr(rows, "usable_threads", lambda: parts)
    monkeypatch.setattr(rows, "_numba_threads", lambda: parts)
    seen = []
    plain = rows.row_parts

    def spy(count, **options):
        found = plain(count, **options)
        seen.append(found)
        return found

    monkeypatch.setattr(rows, "row_parts", spy)
    return whole, compute(), seen
