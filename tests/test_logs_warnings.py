"""Library warnings reach the log (at DEBUG), not the user's terminal raw (issue 25)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = """
import numpy as np
from demtool.logs import configure_logging, route_library_warnings
route_library_warnings()
configure_logging({verbosity})
np.mean(np.array([]))  # RuntimeWarning: Mean of empty slice
"""


def _stderr(verbosity: int) -> str:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONWARNINGS": "default"}
    done = subprocess.run([sys.executable, "-c", SCRIPT.format(verbosity=verbosity)],
                          capture_output=True, text=True, env=env, check=True, timeout=60)
    return done.stderr


def test_runtime_warnings_are_logged_not_printed():
    assert "RuntimeWarning" not in _stderr(0)
    verbose = _stderr(1)
    assert "demtool.warnings: RuntimeWarning: Mean of empty slice" in verbose
    assert len([line for line in verbose.splitlines() if "Mean of empty" in line]) == 1


def test_quiet_failing_run_says_one_line_and_a_succeeding_one_keeps_its_warnings(
        monkeypatch):
    """Issue 46: at -q a run that fails prints its Error line alone (the warnings logged
    before it are dropped); one that succeeds prints its warnings at the end."""
    import click
    from click.testing import CliRunner

    from demtool.cli import cli
    from demtool.errors import InputError
    from demtool.logs import get_logger

    @click.command("_warn_then")
    @click.argument("fail", type=bool)
    def warn_then(fail: bool) -> None:
        get_logger("demtool.test").warning("a warning")
        if fail:
            raise InputError("x.tif: bad")

    monkeypatch.setattr(type(cli), "get_command", lambda self, ctx, name: warn_then)
    failed = CliRunner().invoke(cli, ["-q", "_warn_then", "true"])
    assert failed.exit_code == 1
    assert failed.output.strip().splitlines() == ["Error: demtool _warn_then: x.tif: bad"]
    passed = CliRunner().invoke(cli, ["-q", "_warn_then", "false"])
    assert passed.exit_code == 0 and "a warning" in passed.output
    shown = CliRunner().invoke(cli, ["_warn_then", "true"])  # default level: as they come
    assert shown.output.strip().splitlines()[0] == "demtool.test: a warning"
