"""Side threads (demtool.tiling.side_threads) end before the command does, however it ends: a
thread left running changes process-wide state under the caller's next command."""

from __future__ import annotations

import sys
import threading

import click
from click.testing import CliRunner

from demtool.cli import cli
from demtool.errors import InputError
from demtool.tiling.side_threads import join_side_threads, start_side_thread


def _command(body):
    @click.command(name="synth")
    def command():
        body()

    return command


def _stream_keeper(started: threading.Event, release: threading.Event):
    """What numba's message markup does through colorama: save ``sys.stderr``, later put
    it back."""
    def keep() -> None:
        saved = sys.stderr
        started.set()
        assert release.wait(10)
        sys.stderr = saved

    return keep


def test_a_refusing_command_waits_for_its_side_thread(monkeypatch):
    started, release, threads = threading.Event(), threading.Event(), []

    def refuse():
        threads.append(start_side_thread(_stream_keeper(started, release), "test-side"))
        assert started.wait(10)
        threading.Timer(0.2, release.set).start()  # ends after the refusal is raised
        raise InputError("x.tif: refused")

    monkeypatch.setattr("demtool.cli.load_command", lambda name: _command(refuse))
    result = CliRunner().invoke(cli, ["-q", "synth"])
    assert result.exit_code == 1
    assert [line for line in result.output.splitlines() if line.startswith("Error:")] == \
        ["Error: demtool synth: x.tif: refused"]
    assert not threads[0].is_alive()
    # the next command's error reaches its own stream
    monkeypatch.setattr("demtool.cli.load_command",
                        lambda name: _command(lambda: (_ for _ in ()).throw(
                            InputError("y.tif: refused"))))
    second = CliRunner().invoke(cli, ["-q", "synth"])
    assert "Error: demtool synth: y.tif: refused" in second.output


def test_a_succeeding_command_waits_too(monkeypatch):
    done = []

    def work():
        threading.Event().wait(0.1)
        done.append(True)

    monkeypatch.setattr("demtool.cli.load_command",
                        lambda name: _command(lambda: start_side_thread(work, "test-side")))
    result = CliRunner().invoke(cli, ["synth"])
    assert result.exit_code == 0, result.output
    assert done == [True]


def test_join_counts_only_running_threads():
    thread = start_side_thread(lambda: None, "test-side")
    thread.join()
    assert join_side_threads() == 0
    gate = threading.Event()
    start_side_thread(gate.wait, "test-side", args=(10,))
    threading.Timer(0.05, gate.set).start()
    assert join_side_threads() == 1
