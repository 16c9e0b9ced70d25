"""OpenBLAS's worker threads are told to sleep at once (demtool.blas), before numpy loads."""

from __future__ import annotations

import os
import subprocess
import sys

from demtool import blas


def test_sets_the_shortest_timeout_before_numpy(monkeypatch):
    monkeypatch.delenv(blas.ENV, raising=False)
    monkeypatch.delitem(sys.modules, "numpy", raising=False)
    assert blas.configure() is True
    assert os.environ[blas.ENV] == "4"


def test_a_users_setting_is_kept(monkeypatch):
    monkeypatch.setenv(blas.ENV, "20")
    monkeypatch.delitem(sys.modules, "numpy", raising=False)
    assert blas.configure() is False
    assert os.environ[blas.ENV] == "20"


def test_nothing_is_set_once_numpy_is_loaded(monkeypatch):
    """OpenBLAS read its settings when numpy loaded it: setting the variable now would
    only mislead child processes' readers of the environment."""
    import numpy

    monkeypatch.delenv(blas.ENV, raising=False)
    monkeypatch.setitem(sys.modules, "numpy", numpy)
    assert blas.configure() is False
    assert blas.ENV not in os.environ


def test_import_demtool_sets_it_in_a_fresh_interpreter():
    environ = {k: v for k, v in os.environ.items() if k != blas.ENV}
    code = "import os, demtool, numpy; print(os.environ.get('OPENBLAS_THREAD_TIMEOUT'))"
    result = subprocess.run([sys.executable, "-c", code], env=environ, capture_output=True,
                            text=True, check=True)
    assert result.stdout.strip() == "4"
