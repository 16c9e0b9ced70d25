"""A figure drawn in a forked child (demtool.compare.figure_process): the child's bytes
and CPU, the same exception when it fails, and no child left behind.  (The forked
dems.png equals one-at-a-time drawing to the byte: tests/compare/test_threads.py.)"""

import os
import time

import pytest

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
