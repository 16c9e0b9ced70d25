"""One SGM pass over an image: strips, the two sweep threads, and phase timing.

An SGM pass holds one uint16 volume, the aggregated cost S of its strip (the whole
image when it fits ``max_memory_mb``); the down and up sweeps of
:func:`demtool.sgm.aggregate.sweep_rows` run in two threads that meet in the middle.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import numpy as np

from demtool.errors import ParameterError
from demtool.sgm.aggregate import (
    MODE_DISCARD,
    MODE_FINISH,
    MODE_STORE,
    SweepState,
    adapted_p2_table,
    new_sweep_state,
    padded_disparities,
    path_groups,
    sweep_rows,
)
from demtool.sgm.cost import PixelCost
from demtool.sgm.disparity import SUBPIXEL_MODES
from demtool.sgm.volumes import current_pool
from demtool.sizes import release_free_memory

STRIP_OVERLAP = 32  # rows shared by neighbouring strips



class PhaseTimer:
    """Wall-clock seconds per phase, and CPU seconds of the threads that ran it.

    ``seconds[phase]`` is wall time; ``seconds[phase + "_cpu"]`` the CPU time (user +
    system) spent on it, which depends less on other processes' load than wall time:
    for a block timed by :meth:`measure`, the CPU time of the whole process during the
    block (its helper threads included: the census codes and the post-processing run
    in two threads), for the match phase the sum of the sweep threads' own CPU times.
    ``seconds["match_wait"]``: thread-seconds the sweep threads spent waiting for each
    other (the meeting in the middle, the end of a strip), the idle part of the match
    phase that is this process's own (the rest is other processes on the cores).
    """

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self._lock = threading.Lock()

    def add(self, phase: str, seconds: float, cpu_seconds: float | None = None) -> None:
        with self._lock:
            self.seconds[phase] = self.seconds.get(phase, 0.0) + seconds
            if cpu_seconds is not None:
                key = f"{phase}_cpu"
                self.seconds[key] = self.seconds.get(key, 0.0) + cpu_seconds

    def add_cpu(self, phase: str, cpu_seconds: float) -> None:
        with self._lock:
            key = f"{phase}_cpu"
            self.seconds[key] = self.seconds.get(key, 0.0) + cpu_seconds

    @contextmanager
    def measure(self, phase: str) -> Iterator[None]:
        """Time a block (wall, and the CPU of the process: the block's helper threads
        count, so no other work may run in this process meanwhile)."""
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            self.add(phase, time.perf_counter() - wall, time.process_time() - cpu)

    @contextmanager
    def waiting(self, phase: str) -> Iterator[None]:
        """Add the wall time of a block in which a thread waits to ``<phase>_wait``."""
        wall = time.perf_counter()
        try:
            yield
        finally:
            with self._lock:
                key = f"{phase}_wait"
                self.seconds[key] = self.seconds.get(key, 0.0) + time.perf_counter() - wall


def sweep_state_bytes(width: int, num_disparities: int, paths: int, window: int) -> int:
    """Bytes of the buffers of one sweep (:func:`demtool.sgm.aggregate.new_sweep_state`)."""
    n_slots = 3 if paths == 16 else 2
    n_dirs = 4 * path_groups(paths).shape[0]
    path_bytes = (n_slots + 1) * n_dirs * (width + 4) * padded_disparities(num_disparities) * 2
    return path_bytes + (window + 4) * width * num_disparities * 2


def budget_rows(width: int, num_disparities: int, *, workers: int, max_memory_mb: float,
                fixed_bytes: int = 0) -> int:
    """Rows of the aggregated-cost volume S (uint16, W × D × 2 bytes a row) that each of
    ``workers`` concurrent strips may hold beside ``fixed_bytes`` of row buffers."""
    row_bytes = width * num_disparities * 2
    return int((max_memory_mb * 2**20 / workers - fixed_bytes) / row_bytes)


def plan_strips(height: int, width: int, num_disparities: int, *, workers: int,
                max_memory_mb: float, overlap: int = STRIP_OVERLAP, fixed_bytes: int = 0,
                threads: int = 1) -> list[tuple[int, int]]:
    """Split the rows into strips so that ``workers`` concurrent strips fit the budget.

    A strip holds its aggregated-cost volume S (uint16, rows × W × D × 2 bytes) plus
    ``fixed_bytes`` of row buffers.  A single strip (no overlap, exact) is used when
    the image fits, also when it fits only with some rows recomputed by its ``threads``
    sweep threads (:func:`recompute_rows`), unless ``workers`` > 1 strips should run
    at once on a large image.

    Returns
    -------
    list of (start, stop)
        The rows each strip outputs; when there are several, each is computed with
        ``overlap`` extra rows on its inner sides (paths start at a strip's edges).
    """
    rows = budget_rows(width, num_disparities, workers=workers, max_memory_mb=max_memory_mb,
                       fixed_bytes=fixed_bytes)
    if rows < 2 * overlap + 16:
        raise ParameterError(f"--max-memory-mb {max_memory_mb:g} is too small for "
                             f"{width} columns × {num_disparities} disparities × {workers} "
                             f"concurrent strips; raise it or use fewer workers")
    try:
        recompute_rows(height, rows, threads)
        n_strips = 1
    except ParameterError:
        n_strips = math.ceil(height / (rows - 2 * overlap))
    big = height * width * num_disparities > 8_000_000 and height >= 8 * overlap * workers
    if workers > 1 and big:
        n_strips = workers * math.ceil(max(n_strips, workers) / workers)
    bounds = np.linspace(0, height, n_strips + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


def recompute_rows(rows: int, budget_rows: int, threads: int) -> int:
    """Rows q whose sums a sweep recomputes so that the strip's S fits ``budget_rows``.

    The stored volume S has ``rows − 2q`` rows with two sweep threads (q at each end),
    ``rows − q`` with one (q at the top); 0 when S fits.  Recomputing costs q rows of one
    sweep per end (exact: a sweep restarted at the strip's edge repeats its values).

    Raises
    ------
    ParameterError
        When even the most recomputation (q = rows/4 with two threads, rows/2 with
        one) leaves S over the budget.
    """
    if rows <= budget_rows:
        return 0
    most = most_recomputed(rows, threads)
    q = -(-(rows - budget_rows) // 2) if threads >= 2 else rows - budget_rows
    if q > most:
        raise ParameterError(f"the aggregated cost of {rows} rows does not fit --max-memory-mb "
                             f"({budget_rows} rows); raise it")
    return q


def most_recomputed(rows: int, threads: int) -> int:
    """The most end rows q a sweep may recompute (:func:`recompute_rows`): a quarter of
    the strip with two sweep threads (S keeps rows − 2q), half with one (rows − q)."""
    return (rows // 2) // 2 if threads >= 2 else rows // 2


def stored_rows_of_pass(height: int, width: int, num_disparities: int, *, workers: int,
                        max_memory_mb: float, fixed_bytes: int, threads: int, single: bool,
                        held_bytes: int = 0) -> int:
    """Rows of S each strip of a pass may store (:func:`budget_rows`).

    ``held_bytes`` that the caller holds during the pass count against the budget only
    where the plan is a ``single`` strip, and only down to the fewest rows that strip can
    store (:func:`most_recomputed`): recomputing more end rows gives exactly the same
    disparity, cutting the image into (other) strips would not.
    """
    rows = budget_rows(width, num_disparities, workers=workers, max_memory_mb=max_memory_mb,
                       fixed_bytes=fixed_bytes)
    if not (held_bytes and single):
        return rows
    fewest = height - (2 if threads >= 2 and height >= 2 else 1) * most_recomputed(height,
                                                                                    threads)
    held = budget_rows(width, num_disparities, workers=workers,
                       max_memory_mb=max_memory_mb - held_bytes / 2**20,
                       fixed_bytes=fixed_bytes)
    return max(min(held, rows), fewest)


def match_strip(source: tuple, radius: int, guide: np.ndarray, *, n_disp: int, paths: int,
                p1: int, p2: int, p2_kappa: int, rows: tuple[int, int],
                out_rows: tuple[int, int], subpixel: str, lr_threshold: float | None,
                threads: int, timer: PhaseTimer, recompute: int = 0,
                total: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """SGM of the strip ``rows`` (lo, hi); disparity and confidence of ``out_rows``.

    The down and up sweeps run in two threads when ``threads`` > 1: each stores its
    partial sums for its own half of the rows, then (after a barrier) finishes the
    other half (see :func:`demtool.sgm.aggregate.sweep_rows`).

    With ``recompute`` = q > 0 (see :func:`recompute_rows`) the volume S holds fewer
    rows, and the result is the same: the sweeps carry their paths through the q rows
    at the strip's ends where they start without storing sums there; once the other
    sweep has reached those rows (and stored its sums in rows of S already finished),
    the sweep is restarted at the edge and finishes them.  Two threads: S holds
    rows − 2q rows, each sweep recomputes q rows; one thread: rows − q and q rows of the
    down sweep.

    ``total``: a uint16 array of at least the stored rows × W × D to hold S (its contents
    are overwritten: every row is stored before it is read), or None to map a new one.
    """
    lo, hi = rows
    start, stop = out_rows
    width = guide.shape[1]
    groups = path_groups(paths)
    two = threads >= 2 and hi - lo >= 2
    q = int(recompute)
    n_stored = (hi - lo) - (2 * q if two else q)
    if total is None:
        release_free_memory()  # S is mapped fresh: the earlier steps' freed blocks go first
        total = np.empty((n_stored, width, n_disp), dtype=np.uint16)
    else:
        total = total[:n_stored]
    disparity = np.empty((stop - start, width), dtype=np.float32)
    confidence = np.empty((stop - start, width), dtype=np.float32)
    mode = SUBPIXEL_MODES[subpixel]
    threshold = -1 if lr_threshold is None else int(np.floor(lr_threshold))
    p2_table = adapted_p2_table(p1, p2, p2_kappa)

    def sweep(state: SweepState, sign: int, first: int, last: int, sweep_mode: int,
              base: int) -> None:
        """Rows first .. last (exclusive, step ``sign``); S row of image row y: y − base."""
        if first == last:
            return
        cpu = time.thread_time()
        sweep_rows(source, radius, guide, groups, p1, p2_table, sign, first, last, lo, hi,
                   state.buf, state.mins, state.ring, state.running, state.pixel,
                   state.window_state, sweep_mode, total, base, state.scratch, mode,
                   threshold, start, disparity, confidence, state.right_best, state.right_key)
        timer.add_cpu("match", time.thread_time() - cpu)

    def fresh() -> SweepState:
        return new_sweep_state(width, n_disp, paths, radius)

    if not two:
        # S rows: lo + q .. hi; the up sweep then stores the top q rows in the rows of S
        # it finished first (hi − q .. hi), and a restarted down sweep finishes them
        down, up = fresh(), fresh()
        sweep(down, 1, lo, lo + q, MODE_DISCARD, 0)
        sweep(down, 1, lo + q, hi, MODE_STORE, lo + q)
        sweep(up, -1, hi - 1, lo + q - 1, MODE_FINISH, lo + q)
        top = 2 * lo + 2 * q - hi
        sweep(up, -1, lo + q - 1, lo - 1, MODE_STORE, top)
        if q:
            sweep(fresh(), 1, lo, lo + q, MODE_FINISH, top)
        return disparity, confidence
    middle = (lo + hi) // 2
    # S rows: the middle rows lo + q .. hi − q; the end rows' sums go to rows of S their
    # sweep finished first: the bottom q rows (down) to middle .. middle + q, the top q
    # rows (up) to middle − q .. middle
    inner = lo + q
    bottom = hi - middle + lo
    top = 2 * lo + 2 * q - middle
    barrier = threading.Barrier(2)

    def meet() -> None:
        with timer.waiting("match"):
            barrier.wait()

    def in_halves(sign: int) -> None:
        state = fresh()
        try:
            if sign > 0:
                sweep(state, 1, lo, lo + q, MODE_DISCARD, 0)
                sweep(state, 1, lo + q, middle, MODE_STORE, inner)
                meet()
                sweep(state, 1, middle, hi - q, MODE_FINISH, inner)
                sweep(state, 1, hi - q, hi, MODE_STORE, bottom)
                meet()
                if q:
                    sweep(fresh(), 1, lo, lo + q, MODE_FINISH, top)
            else:
                sweep(state, -1, hi - 1, hi - q - 1, MODE_DISCARD, 0)
                sweep(state, -1, hi - q - 1, middle - 1, MODE_STORE, inner)
                meet()
                sweep(state, -1, middle - 1, lo + q - 1, MODE_FINISH, inner)
                sweep(state, -1, lo + q - 1, lo - 1, MODE_STORE, top)
                meet()
                if q:
                    sweep(fresh(), -1, hi - 1, hi - q - 1, MODE_FINISH, bottom)
        except BaseException:
            barrier.abort()
            raise

    with ThreadPoolExecutor(max_workers=1) as pool:
        future = pool.submit(in_halves, -1)
        in_halves(1)
        with timer.waiting("match"):
            future.result()
    return disparity, confidence


def match_pass(pixel_cost: PixelCost, left_valid: np.ndarray, right_valid: np.ndarray,
                guide: np.ndarray, *, min_disparity: int, num_disparities: int, window: int,
                p1: int, p2: int, paths: int, p2_kappa: int, subpixel: str,
                lr_threshold: float | None, workers: int, max_memory_mb: float,
                unmatched_fraction: float, timer: PhaseTimer, held_bytes: int = 0
                ) -> tuple[np.ndarray, np.ndarray]:
    """One SGM pass over the whole image: strips (one when it fits), two sweeps each.

    ``workers`` threads: ``workers // 2`` strips at once, two sweep threads each.
    ``held_bytes``: memory the caller holds during the pass (the results of earlier
    passes of cost "auto"); it counts against ``max_memory_mb`` as far as the image stays
    the same strips — a single strip then recomputes more end rows (the same result,
    :func:`recompute_rows`), several strips are not cut differently (that would change
    the disparity).
    """
    height, width = left_valid.shape
    concurrent = max(1, workers // 2)
    threads = 1 if workers < 2 else 2
    fixed = 2 * sweep_state_bytes(width, num_disparities, paths, window)
    strips = plan_strips(height, width, num_disparities, workers=concurrent,
                         max_memory_mb=max_memory_mb, fixed_bytes=fixed, threads=threads)
    stored_rows = stored_rows_of_pass(height, width, num_disparities, workers=concurrent,
                                      max_memory_mb=max_memory_mb, fixed_bytes=fixed,
                                      threads=threads, single=len(strips) == 1,
                                      held_bytes=held_bytes)
    max_cost = pixel_cost.max_cost * window * window
    if paths * (max_cost + p2) > np.iinfo(np.uint16).max:
        raise ParameterError(
            f"cost window {window}×{window} of {pixel_cost.name} (maximum {max_cost}) + P2 "
            f"{p2} could overflow the 16-bit sums of {paths} paths; lower --p2 or the window")
    source = pixel_cost.kernel_source(left_valid, right_valid, min_disparity,
                                      unmatched_fraction)
    guide = np.ascontiguousarray(guide, dtype=np.uint8)
    overlap = STRIP_OVERLAP if len(strips) > 1 else 0

    def bounds(rows: tuple[int, int]) -> tuple[int, int]:
        return max(0, rows[0] - overlap), min(height, rows[1] + overlap)

    def stored(rows: tuple[int, int]) -> int:
        lo, hi = bounds(rows)
        two = threads >= 2 and hi - lo >= 2
        return (hi - lo) - (2 if two else 1) * recompute_rows(hi - lo, stored_rows, threads)

    # Several strips share their volumes S: one per strip running at once, mapped once
    # for the pass (each strip's S rows are all stored before they are read, so the
    # result is the same); a fresh S per strip paid its page faults again (W × D × 2
    # bytes a row, zeroed by the kernel) in every strip.
    n_slots = 1 if len(strips) == 1 or concurrent == 1 else min(concurrent, len(strips))
    largest = max(stored(rows) for rows in strips)
    reuse = current_pool() if n_slots == 1 else None  # tiles: the thread's last S (exact)
    volumes: queue.SimpleQueue[np.ndarray] = queue.SimpleQueue()
    if reuse is not None:
        volumes.put(reuse.take((largest, width, num_disparities)))
    else:
        release_free_memory()  # S is mapped fresh: the earlier steps' freed blocks go first
        for _ in range(n_slots):
            volumes.put(np.empty((largest, width, num_disparities), dtype=np.uint16))

    def run_strip(rows: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = bounds(rows)
        total = volumes.get()
        try:
            return match_strip(source, window // 2, guide, n_disp=num_disparities,
                               paths=paths, p1=p1, p2=p2, p2_kappa=p2_kappa, rows=(lo, hi),
                               out_rows=rows, subpixel=subpixel, lr_threshold=lr_threshold,
                               threads=threads, timer=timer, total=total,
                               recompute=recompute_rows(hi - lo, stored_rows, threads))
        finally:
            volumes.put(total)

    started = time.perf_counter()
    if n_slots == 1:
        parts = [run_strip(rows) for rows in strips]
    else:
        with ThreadPoolExecutor(max_workers=n_slots) as pool:
            parts = list(pool.map(run_strip, strips))
    while not volumes.empty():  # the volumes go before the results are joined
        volume = volumes.get()
        if reuse is not None:
            reuse.keep(volume)
        volume = None
    timer.add("match", time.perf_counter() - started)  # its CPU time: the sweeps add it
    disparity = np.concatenate([p[0] for p in parts], axis=0)
    confidence = np.concatenate([p[1] for p in parts], axis=0)
    return disparity, confidence
