"""A figure drawn in a forked child (demtool.compare.figure_process): the child's bytes
and CPU, the same exception when it fails, and no child left behind."""

import os
import time

import numpy as np
import pytest

from demtool.compare import threads
from demtool.compare.figure_process import Apart, forking

pytestmark = pytest.mark.skipif(not forking(), reason="figures are forked on Linux only")


def _busy_bytes() -> bytes:
    """Bytes that only the child's CPU makes (~0.05 CPU s), larger than a pipe's buffer."""
    end = time.process_time() + 0.05
    while time.process_time() < end:
        pass
    return os.getpid().to_bytes(8, "little") + bytes(range(256)) * 4096


def test_the_child_draws_and_its_cpu_is_counted():
    with Apart(_busy_bytes) as apart:
        data = apart.result()
    assert int.from_bytes(data[:8], "little") != os.getpid()  # drawn in another process
    assert data[8:] == bytes(range(256)) * 4096  # 1 MiB through the pipe, whole
    assert apart.cpu_s >= 0.04


def test_a_failing_child_raises_the_same_error_here():
    calls = []

    def make() -> bytes:
        calls.append(os.getpid())
        raise ValueError("no figure")

    with Apart(make) as apart, pytest.raises(ValueError, match="no figure"):
        apart.result()
    assert calls == [os.getpid()]  # the child's call is not seen here: this one raised


def test_leaving_early_stops_and_reaps_the_child():
    def slow() -> bytes:
        time.sleep(30)
        return b""

    start = time.perf_counter()
    with pytest.raises(RuntimeError), Apart(slow) as apart:
        pid = apart._pid
        raise RuntimeError("another figure failed")
    assert time.perf_counter() - start < 5
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)  # reaped: no zombie left


@pytest.mark.slow  # six small figures, one of them in a child: ~2 CPU s
def test_the_forked_figures_phase_counts_the_childs_cpu(monkeypatch):
    """(The bytes equal one-at-a-time drawing: tests/compare/test_threads.py, whose grid
    is past the lowered THREADED_CELLS too, so its dems.png is drawn in a child.)"""
    from demtool.compare import compare_dems
    from demtool.compare.plots import default_profiles
    from demtool.compare.report import make_figures

    rng = np.random.default_rng(5)
    reference = rng.normal(size=(24, 30)).cumsum(0).cumsum(1) * 0.1
    dem = reference + rng.normal(scale=0.05, size=reference.shape) - 0.3
    comparison = compare_dems(dem, reference, spacing=2.0)
    monkeypatch.setattr(threads, "THREADED_CELLS", 64)
    timings = {"figures_cpu": 1.0}
    figures = make_figures([("dem", comparison)], reference,
                           default_profiles(reference.shape), (2.0, 2.0), "dem",
                           timings=timings)
    assert figures["dems.png"].startswith(b"\x89PNG") and len(figures) == 6
    assert timings["figures_cpu"] > 1.0  # the child's CPU added to the phase's
