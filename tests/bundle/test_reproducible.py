"""Issue 44: the same inputs give the same ``bundle.npz`` bit for bit by default."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from demtool.cli import cli


@pytest.mark.slow
def test_bundle_twice_gives_identical_files(strip_dir, tmp_path):
    """Two runs with two threads (extraction and matching in parallel, mapping on one)
    write identical bundle.npz files; the sidecar records the choice."""
    images = sorted(str(p) for p in strip_dir.glob("view_*.tif"))
    outputs = []
    for run in ("first", "second"):
        out = tmp_path / f"{run}.npz"
        result = CliRunner().invoke(cli, ["-q", "bundle", *images, "--out", str(out),
                                          "--workers", "2"])
        assert result.exit_code == 0, result.output
        outputs.append(out)
    first, second = (np.load(p, allow_pickle=False) for p in outputs)
    assert sorted(first.files) == sorted(second.files)
    for key in first.files:
        np.testing.assert_array_equal(first[key], second[key], err_msg=key)
    assert outputs[0].read_bytes() == outputs[1].read_bytes()
    sidecar = json.loads((tmp_path / "first.npz.json").read_text())
    assert sidecar["parameters"]["reproducible"] is True
