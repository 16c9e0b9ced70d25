"""The window a refine tile is solved on: its outer window grown to a fast DCT length.

Shape from shading costs O(N log N) per iteration in its DCTs (the height step, the
Gaussian low-passes of Edepth and of the albedo), and pocketfft's speed per pixel depends
on the lengths' prime factors: a tile's core plus its margins easily has a prime side
(2048 + 113 = 2161), which runs Bluestein's algorithm at 5× the time per pixel of 2160
(measured, scipy 1.17).  Egrad's block low-pass needs a side divisible by 4 for its 4 × 4
blocks (:class:`demtool.refine.filters.BlockGaussianLowpass`), else it falls back to the
full-resolution DCT, 16× the samples.  So each tile is refined on a window a few pixels
larger than its outer window whose sides are fast, and keeps its core as before.
"""

from __future__ import annotations

#: Prime factors of the transform lengths pocketfft (scipy.fft) has radix passes for; a
#: length with another factor p runs a generic O(p) pass (a prime length: Bluestein's
#: algorithm), 3-5× slower per pixel (a 2161² DCT 5× a 2160²'s, measured).
FAST_FACTORS = (2, 3, 5, 7, 11)
#: Solve windows are multiples of this, so Egrad's block low-pass runs on 4 × 4 blocks as
#: an untiled 2ⁿ grid does (:class:`demtool.refine.filters.BlockGaussianLowpass`: a side
#: with no divisor ≤ σ_f / 5 falls back to full-resolution DCTs, 16× the samples).
WINDOW_MULTIPLE = 4


def fast_length(n: int) -> int:
    """The smallest length ≥ ``n`` that is a multiple of :data:`WINDOW_MULTIPLE` and has
    no prime factor outside :data:`FAST_FACTORS`."""
    m = -(-max(int(n), 1) // WINDOW_MULTIPLE) * WINDOW_MULTIPLE
    while True:
        rest = m
        for factor in FAST_FACTORS:
            while rest % factor == 0:
                rest //= factor
        if rest == 1:
            return m
        m += WINDOW_MULTIPLE


def solve_window(outer: tuple[int, int, int, int], grid: tuple[int, int]
                 ) -> tuple[int, int, int, int]:
    """The window a tile is refined on: its outer window grown to :func:`fast_length` on
    each axis (evenly on both sides, shifted inward at the grid's edges), or the grid's
    whole axis where that is shorter (then as the untiled run along it).

    Shape from shading costs O(N log N) per iteration in its DCTs, whose speed depends on
    the lengths' prime factors; a margin's few extra pixels make every tile's length
    fast (a 2048-px core with 113-px margins: 2161 px, a prime, → 2200).
    """
    bounds = []
    for start, stop, size in ((outer[0], outer[1], grid[0]), (outer[2], outer[3], grid[1])):
        length = fast_length(stop - start)
        if length >= size:
            bounds += [0, size]
            continue
        start = min(max(0, start - (length - (stop - start)) // 2), size - length)
        bounds += [start, start + length]
    return tuple(bounds)
