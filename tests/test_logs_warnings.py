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
