"""numpy work of the shape-from-shading solver on row parts, in cache-sized blocks.

Between its compiled row kernels (:mod:`demtool.refine.kernels`) the solver does
element-wise numpy work: I/ρ, heights to pixel units and back, the lit weights, the
dark and attached shadows, its set-up.  numpy releases the GIL inside its loops, so
that work runs on every core when the rows are cut into parts, one per thread
(:func:`demtool.tiling.rows.on_row_parts`).  Each part then goes through its rows in
blocks of about :data:`BLOCK_ELEMENTS` pixels, so that the temporaries of an expression
stay in the core's cache instead of streaming whole-grid arrays through memory, which
two cores share.  Element-wise arithmetic gives the same bits whatever the cut.
"""

from __future__ import annotations

from collections.abc import Callable

#: Pixels per block: 64 Ki, 256 KiB of float32 or 512 KiB of float64 per temporary.
BLOCK_ELEMENTS = 1 << 16


def on_row_blocks(work: Callable[[int, int], object], count: int, width: int) -> None:
    """Run ``work(start, stop)`` over rows ``0 … count`` of a grid ``width`` pixels wide:
    the rows in parts on every core (:func:`~demtool.tiling.rows.on_row_parts`), each
    part in blocks of about :data:`BLOCK_ELEMENTS` pixels, in order.  ``work`` must
    write only rows ``start … stop − 1`` of its outputs."""
    from demtool.tiling.rows import on_row_parts

    step = max(1, BLOCK_ELEMENTS // max(1, int(width)))

    def part(start: int, stop: int) -> None:
        for first in range(start, stop, step):
            work(first, min(first + step, stop))

    on_row_parts(part, count)
