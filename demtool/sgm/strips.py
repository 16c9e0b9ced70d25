"""One SGM pass over an image: strips, the two sweep threads, and phase timing.

An SGM pass holds one uint16 volume, the aggregated cost S of its strip (the whole
image when it fits ``max_memory_mb``); the down and up sweeps of
:func:`demtool.sgm.aggregate.sweep_rows` run in two threads that meet in the middle.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import numpy as np

from demtool.errors import ParameterError
from demtool.sgm.aggregate import (
    MODE_FINISH,
    MODE_STORE,
    SweepState,
    adapted_p2_table,
    new_sweep_state,
    path_groups,
    sweep_rows,
)
from demtool.sgm.cost import PixelCost
from demtool.sgm.disparity import SUBPIXEL_MODES

STRIP_OVERLAP = 32  # rows shared by neighbouring strips


class PhaseTimer:
    """Wall-clock seconds per phase, and CPU seconds of the threads that ran it.

    ``seconds[phase]`` is wall time; ``seconds[phase + "_cpu"]`` the CPU time (user +
    system) of the threads that worked on it, which depends less on other processes'
    load than wall time.
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
        """Time a block run by the calling thread (wall and this thread's CPU)."""
        wall, cpu = time.perf_counter(), time.thread_time()
        try:
            yield
        finally:
            self.add(phase, time.perf_counter() - wall, time.thread_time() - cpu)


def available_cores() -> int:
    """CPU cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def sweep_state_bytes(width: int, num_disparities: int, paths: int, window: int) -> int:
    """Bytes of the buffers of one sweep (:func:`demtool.sgm.aggregate.new_sweep_state`)."""
    n_slots = 3 if paths == 16 else 2
    n_dirs = 4 * path_groups(paths).shape[0]
    path_bytes = (n_slots + 1) * n_dirs * (width + 4) * (num_disparities + 2) * 2
    return path_bytes + (window + 4) * width * num_disparities * 2


def plan_strips(height: int, width: int, num_disparities: int, *, workers: int,
                max_memory_mb: float, overlap: int = STRIP_OVERLAP, fixed_bytes: int = 0
                ) -> list[tuple[int, int]]:
    """Split the rows into strips so that ``workers`` concurrent strips fit the budget.

    A strip holds its aggregated-cost volume S (uint16, rows × W × D × 2 bytes) plus
    ``fixed_bytes`` of row buffers.  A single strip (no overlap, exact) is used when
    the image fits, unless ``workers`` > 1 strips should run at once on a large image.

    Returns
    -------
    list of (start, stop)
        The rows each strip outputs; when there are several, each is computed with
        ``overlap`` extra rows on its inner sides (paths start at a strip's edges).
    """
    row_bytes = width * num_disparities * 2  # S, uint16
    budget_rows = int((max_memory_mb * 2**20 / workers - fixed_bytes) / row_bytes)
    if budget_rows < 2 * overlap + 16:
        raise ParameterError(f"--max-memory-mb {max_memory_mb:g} is too small for "
                             f"{width} columns × {num_disparities} disparities × {workers} "
                             f"concurrent strips; raise it or use fewer workers")
    n_strips = 1 if height <= budget_rows else math.ceil(height / (budget_rows - 2 * overlap))
    big = height * width * num_disparities > 8_000_000 and height >= 8 * overlap * workers
    if workers > 1 and big:
        n_strips = workers * math.ceil(max(n_strips, workers) / workers)
    bounds = np.linspace(0, height, n_strips + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


def match_strip(source: tuple, radius: int, guide: np.ndarray, *, n_disp: int, paths: int,
                 p1: int, p2: int, p2_kappa: int, rows: tuple[int, int],
                 out_rows: tuple[int, int], subpixel: str, lr_threshold: float | None,
                 threads: int, timer: PhaseTimer) -> tuple[np.ndarray, np.ndarray]:
    """SGM of the strip ``rows`` (lo, hi); disparity and confidence of ``out_rows``.

    The down and up sweeps run in two threads when ``threads`` > 1: each stores its
    partial sums for its own half of the rows, then (after a barrier) finishes the
    other half (see :func:`demtool.sgm.aggregate.sweep_rows`).
    """
    lo, hi = rows
    start, stop = out_rows
    width = guide.shape[1]
    groups = path_groups(paths)
    total = np.empty((hi - lo, width, n_disp), dtype=np.uint16)
    disparity = np.empty((stop - start, width), dtype=np.float32)
    confidence = np.empty((stop - start, width), dtype=np.float32)
    mode = SUBPIXEL_MODES[subpixel]
    threshold = -1 if lr_threshold is None else int(np.floor(lr_threshold))
    down = new_sweep_state(width, n_disp, paths, radius)
    up = new_sweep_state(width, n_disp, paths, radius)
    p2_table = adapted_p2_table(p1, p2, p2_kappa)

    def sweep(state: SweepState, sign: int, first: int, last: int, sweep_mode: int) -> None:
        cpu = time.thread_time()
        sweep_rows(source, radius, guide, groups, p1, p2_table, sign, first, last, lo, hi,
                   state.buf, state.mins, state.ring, state.running, state.pixel,
                   state.window_state, sweep_mode, total, state.scratch, mode, threshold,
                   start, disparity, confidence, state.right_best, state.right_key)
        timer.add_cpu("match", time.thread_time() - cpu)

    if threads < 2 or hi - lo < 2:
        sweep(down, 1, lo, hi, MODE_STORE)
        sweep(up, -1, hi - 1, lo - 1, MODE_FINISH)
        return disparity, confidence
    middle = (lo + hi) // 2
    barrier = threading.Barrier(2)

    def in_halves(state: SweepState, sign: int) -> None:
        try:
            if sign > 0:
                sweep(state, 1, lo, middle, MODE_STORE)
                barrier.wait()
                sweep(state, 1, middle, hi, MODE_FINISH)
            else:
                sweep(state, -1, hi - 1, middle - 1, MODE_STORE)
                barrier.wait()
                sweep(state, -1, middle - 1, lo - 1, MODE_FINISH)
        except BaseException:
            barrier.abort()
            raise

    with ThreadPoolExecutor(max_workers=1) as pool:
        future = pool.submit(in_halves, up, -1)
        in_halves(down, 1)
        future.result()
    return disparity, confidence


def match_pass(pixel_cost: PixelCost, left_valid: np.ndarray, right_valid: np.ndarray,
                guide: np.ndarray, *, min_disparity: int, num_disparities: int, window: int,
                p1: int, p2: int, paths: int, p2_kappa: int, subpixel: str,
                lr_threshold: float | None, workers: int, max_memory_mb: float,
                unmatched_fraction: float, timer: PhaseTimer) -> tuple[np.ndarray, np.ndarray]:
    """One SGM pass over the whole image: strips (one when it fits), two sweeps each.

    ``workers`` threads: ``workers // 2`` strips at once, two sweep threads each.
    """
    height, width = left_valid.shape
    concurrent = max(1, workers // 2)
    threads = 1 if workers < 2 else 2
    fixed = 2 * sweep_state_bytes(width, num_disparities, paths, window)
    strips = plan_strips(height, width, num_disparities, workers=concurrent,
                         max_memory_mb=max_memory_mb, fixed_bytes=fixed)
    max_cost = pixel_cost.max_cost * window * window
    if paths * (max_cost + p2) > np.iinfo(np.uint16).max:
        raise ParameterError(
            f"cost window {window}×{window} of {pixel_cost.name} (maximum {max_cost}) + P2 "
            f"{p2} could overflow the 16-bit sums of {paths} paths; lower --p2 or the window")
    source = pixel_cost.kernel_source(left_valid, right_valid, min_disparity,
                                      unmatched_fraction)
    guide = np.ascontiguousarray(guide, dtype=np.uint8)
    overlap = STRIP_OVERLAP if len(strips) > 1 else 0

    def run_strip(rows: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        start, stop = rows
        lo, hi = max(0, start - overlap), min(height, stop + overlap)
        return match_strip(source, window // 2, guide, n_disp=num_disparities, paths=paths,
                            p1=p1, p2=p2, p2_kappa=p2_kappa, rows=(lo, hi), out_rows=rows,
                            subpixel=subpixel, lr_threshold=lr_threshold, threads=threads,
                            timer=timer)

    started = time.perf_counter()
    if len(strips) == 1 or concurrent == 1:
        parts = [run_strip(rows) for rows in strips]
    else:
        with ThreadPoolExecutor(max_workers=min(concurrent, len(strips))) as pool:
            parts = list(pool.map(run_strip, strips))
    timer.add("match", time.perf_counter() - started)  # its CPU time: the sweeps add it
    disparity = np.concatenate([p[0] for p in parts], axis=0)
    confidence = np.concatenate([p[1] for p in parts], axis=0)
    return disparity, confidence
