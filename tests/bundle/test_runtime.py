"""COLMAP inside demtool: SIGTERM stays demtool's (exit 130, one line, no output, no C
stack dump) and no glog files are written (issue 16, class 6)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest


def test_pycolmap_import_keeps_python_sigterm_handler(tmp_path):
    """In a fresh interpreter: a Python SIGTERM handler survives load_pycolmap()
    (a plain `import pycolmap` replaces it with glog's, which dumps a C stack)."""
    script = (
        "import os, signal, time\n"
        "def handler(signum, frame):\n"
        "    raise KeyboardInterrupt\n"
        "signal.signal(signal.SIGTERM, handler)\n"
        "from demtool.bundle.runtime import load_pycolmap\n"
        "load_pycolmap()\n"
        "try:\n"
        "    os.kill(os.getpid(), signal.SIGTERM)\n"
        "    time.sleep(5)\n"
        "except KeyboardInterrupt:\n"
        "    print('python handler ran')\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "python handler ran"
    assert "stack trace" not in done.stderr and "SIGTERM" not in done.stderr


@pytest.mark.slow
def test_sigterm_during_bundle(ring_dir, tmp_path):
    out = tmp_path / "out" / "bundle.npz"
    glog_dir = tmp_path / "glog"
    glog_dir.mkdir()
    env = {**os.environ, "GLOG_log_dir": str(glog_dir), "GOOGLE_LOG_DIR": str(glog_dir)}
    images = sorted(str(p) for p in Path(ring_dir).glob("view_*.tif"))
    process = subprocess.Popen([sys.executable, "-m", "demtool", "bundle", *images, "--out",
                                str(out)], stderr=subprocess.PIPE, text=True, env=env)
    lines = []
    for line in process.stderr:
        lines.append(line)
        if "matching features" in line:
            time.sleep(0.5)  # inside COLMAP's matching
            process.send_signal(signal.SIGTERM)
            break
    rest = process.stderr.read()
    status = process.wait(timeout=60)
    process.stderr.close()
    assert status == 130, "".join(lines) + rest
    assert rest.count("\n") == 1 and rest.startswith("Error: demtool bundle: interrupted")
    assert "stack trace" not in rest
    assert not out.parent.exists() or not any(out.parent.iterdir())
    assert not any(glog_dir.iterdir())


@pytest.mark.slow
def test_no_glog_files(tmp_path):
    """A bundle run (here one that fails: no overlap) leaves no COLMAP log file."""
    import numpy as np

    from demtool import io as dio

    rng = np.random.default_rng(3)
    paths = []
    for name in ("a", "b"):
        paths.append(str(tmp_path / f"{name}.tif"))
        dio.write_raster(paths[-1], rng.normal(100, 20, (64, 64)))
    glog_dir = tmp_path / "glog"
    glog_dir.mkdir()
    env = {**os.environ, "GLOG_log_dir": str(glog_dir), "GOOGLE_LOG_DIR": str(glog_dir)}
    done = subprocess.run([sys.executable, "-m", "demtool", "-v", "bundle", *paths, "--out",
                           str(tmp_path / "b.npz")], capture_output=True, text=True, env=env,
                          timeout=120)
    assert done.returncode == 1
    assert not any(glog_dir.iterdir())
