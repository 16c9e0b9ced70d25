"""``match --workers N`` bounds numba's threads for its own run only."""

from __future__ import annotations

import numpy as np
import pytest

from demtool import io as dio
from tests.helpers.match import textured_pair


def test_match_workers_leave_the_callers_numba_threads_as_they_were(tmp_path):
    """An in-process caller (a CliRunner, a notebook, a chain of stages) keeps its numba
    thread count after ``match --workers 1``."""
    import numba
    from click.testing import CliRunner

    from demtool.cli import cli

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("one numba thread: nothing to restore")
    left, right, _ = textured_pair(64, 80, seed=1)
    dio.write_raster(tmp_path / "l.tif", left.astype(np.float32))
    dio.write_raster(tmp_path / "r.tif", right.astype(np.float32))
    before = numba.get_num_threads()
    result = CliRunner().invoke(cli, ["match", str(tmp_path / "l.tif"), str(tmp_path / "r.tif"),
                                      "--out", str(tmp_path / "d.tif"), "--template", "13",
                                      "--workers", "1"])
    assert result.exit_code == 0, result.output
    assert numba.get_num_threads() == before
