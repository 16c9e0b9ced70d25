"""Issue 44: the same inputs give the same ``bundle.npz`` bit for bit by default, and
a view that cannot register is reported with the reason."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli


def _arrays(path) -> dict[str, np.ndarray]:
    """Every array of an NPZ file, the file closed (an open one warns when collected)."""
    with np.load(path, allow_pickle=False) as npz:
        return {key: npz[key] for key in npz.files}


@pytest.mark.slow
def test_bundle_twice_gives_identical_files(strip_dir, tmp_path):
    """Two runs with two threads (extraction and matching in parallel, mapping on one)
    write identical bundle.npz files; an image of noise among the strip's frames is
    left out with the reason: no verified matches with the registered views."""
    noise = tmp_path / "noise.tif"
    dio.write_raster(noise, np.random.default_rng(0).uniform(0, 255, (256, 256))
                     .astype(np.float32))
    images = [*sorted(str(p) for p in strip_dir.glob("view_*.tif")), str(noise)]
    outputs = []
    for run in ("first", "second"):
        out = tmp_path / f"{run}.npz"
        result = CliRunner().invoke(cli, ["-q", "bundle", *images, "--out", str(out),
                                          "--workers", "2", "--features", "standard"])
        assert result.exit_code == 0, result.output
        outputs.append(out)
    first, second = (_arrays(p) for p in outputs)
    assert sorted(first) == sorted(second)
    for key in first:
        np.testing.assert_array_equal(first[key], second[key], err_msg=key)
    assert outputs[0].read_bytes() == outputs[1].read_bytes()
    sidecar = json.loads((tmp_path / "first.npz.json").read_text())
    assert sidecar["parameters"]["reproducible"] is True
    summary = sidecar["summary"]
    assert summary["registered_count"] == 6 and summary["not_registered"] == ["noise"]
    reason = summary["unregistered_reasons"]["noise"]
    assert reason["features"] > 100 and reason["verified_matches"] < 15
    assert reason["reason"].startswith("too few verified matches")
    assert summary["mapping"]["feature_passes"] == ["standard"]


def test_unknown_features_are_refused(tmp_path):
    from demtool.bundle.colmap import SfmOptions, run_sfm
    from demtool.errors import ParameterError

    with pytest.raises(ParameterError, match="unknown features 'dense'; should be one of "
                       "auto, standard, rich"):
        run_sfm(tmp_path, {"a.png": "a"}, tmp_path, SfmOptions(features="dense"))
    result = CliRunner().invoke(cli, ["bundle", "a.tif", "b.tif", "--out",
                                      str(tmp_path / "b.npz"), "--features", "dense"])
    assert result.exit_code == 2 and "dense" in result.output
