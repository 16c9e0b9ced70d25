"""The windowed ``compare`` (DEMs larger than memory): the exact streaming statistics, and
a windowed run equal to the in-memory one on a DEM that fits, reading only windows."""

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from demtool.compare.params import CompareParams
from demtool.compare.run import run_compare
from demtool.compare.stats import difference_statistics
from demtool.compare.streaming import Moments, OrderStatistic, StreamStatistics
from tests.helpers.compare import fourier_shift, fractal

SPACING = 2.0
STAT_KEYS = ("mean", "median", "std", "rmse", "nmad", "le90", "min", "max")


def stream(values, pieces=7, **options):
    """StreamStatistics of ``values`` fed in ``pieces`` until done; (result, passes)."""
    stats = StreamStatistics(**options)
    parts = np.array_split(np.asarray(values, dtype=np.float64), pieces)
    while not stats.done:
        for part in parts:
            stats.add(part)
        stats.end_pass()
    return stats.result(), stats.passes


@pytest.mark.parametrize("case", ["heavy tails", "duplicates", "rounded", "two", "one"])
def test_stream_statistics_equal_the_in_memory_ones(case):
    rng = np.random.default_rng(3)
    values = {"heavy tails": rng.standard_t(2, 20001) * 3 + 500.0,
              "duplicates": np.where(rng.random(12000) < 0.4, 7.25, rng.normal(size=12000)),
              "rounded": np.round(rng.normal(scale=4, size=30000), 1),
              "two": np.array([3.0, -1.0]), "one": np.array([2.5])}[case]
    # tiny histograms and buffers: many narrowing passes before the values are gathered
    got, passes = stream(values, bins=16, gather_limit=64)
    want = difference_statistics(values)
    assert got["count"] == want["count"]
    for key in ("median", "nmad", "le90", "min", "max"):  # the same order statistics
        assert got[key] == pytest.approx(want[key], rel=1e-12, abs=1e-12), key
    for key in ("mean", "std", "rmse"):
        assert got[key] == pytest.approx(want[key], rel=1e-12, abs=1e-12), key
    assert passes >= (3 if values.size > 64 else 1)


def test_stream_statistics_of_nothing_are_nan():
    got, passes = stream(np.empty(0), pieces=3)
    assert got["count"] == 0 and np.isnan(got["rmse"]) and np.isnan(got["nmad"])
    assert passes == 1


def test_moments_are_stable_far_from_zero():
    """Chan's update: a 1e9 m offset does not eat the 1 mm spread (sum of squares would)."""
    rng = np.random.default_rng(4)
    values = 1e9 + rng.normal(scale=1e-3, size=10000)
    moments = Moments()
    for part in np.array_split(values, 10):
        moments.add(part)
    assert moments.summary()["std"] == pytest.approx(values.std(), rel=1e-6)


def test_order_statistic_refuses_a_rank_outside_the_count():
    with pytest.raises(ValueError, match="rank 5 outside 0..4"):
        OrderStatistic(5, 5, 0.0, 1.0)


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """A reference, a DEM shifted by (1.3, −0.7) px and +2 m with a hole, a mask, and the
    same DEM on a grid offset by a third of a cell (resampled onto the reference's)."""
    folder = tmp_path_factory.mktemp("windowed_pair")
    truth = fractal(96, relief=25.0, seed=11)
    dem = fourier_shift(truth, 1.3, -0.7) + 2.0
    dem += np.random.default_rng(12).normal(scale=0.02, size=dem.shape)
    dem[40:50, 30:50] = np.nan
    transform = dio.image_frame_transform(SPACING)
    tags = {"frame": "image:view_00"}
    dio.write_raster(folder / "reference.tif", truth, transform=transform, tags=tags)
    dio.write_raster(folder / "dem.tif", dem, transform=transform, tags=tags)
    from affine import Affine

    offset = transform @ Affine.translation(1 / 3, -1 / 3)
    dio.write_raster(folder / "dem_offset.tif", dem[:90, 3:], transform=offset, tags=tags)
    mask = np.ones(truth.shape, dtype=np.float32)
    mask[:, :20] = 0.0
    dio.write_raster(folder / "mask.tif", mask, transform=transform, tags=tags)
    return folder


def compare(pair, out, dem="dem.tif", mask=None, **options):
    return run_compare(pair / dem, pair / "reference.tif", out, CompareParams(**options),
                       mask_path=None if mask is None else pair / mask)


def assert_same_report(got, want):
    assert got["count"] == want["count"]
    for key in ("mean", "rmse", "std"):
        assert got[key] == pytest.approx(want[key], rel=1e-9), key
    for key in ("median", "nmad", "le90", "min", "max"):  # exact, not binned
        assert got[key] == pytest.approx(want[key], rel=1e-12), key
    assert got["completeness"] == pytest.approx(want["completeness"], rel=1e-12)
    for key in ("dx_px", "dy_px", "dz"):
        assert got["shift"][key] == pytest.approx(want["shift"][key], rel=1e-12, abs=1e-12)
    for key in ("count", *STAT_KEYS):
        assert got["before_alignment"][key] == pytest.approx(want["before_alignment"][key],
                                                             rel=1e-9, nan_ok=True), key
    assert len(got["slope_classes"]) == len(want["slope_classes"])
    for a, b in zip(got["slope_classes"], want["slope_classes"], strict=True):
        assert a["count"] == b["count"]
        for key in STAT_KEYS:
            assert a[key] == pytest.approx(b[key], rel=1e-9, nan_ok=True), key


@pytest.mark.parametrize("dem, align, mask", [("dem.tif", "nuth-kaab", None),
                                              ("dem.tif", "offset", "mask.tif"),
                                              ("dem_offset.tif", "none", None)])
def test_windowed_compare_equals_the_in_memory_one(pair, tmp_path, dem, align, mask):
    want = compare(pair, tmp_path / "memory", dem, mask, align=align)
    got = compare(pair, tmp_path / "windows", dem, mask, align=align, tile_size=32)
    assert "windowed" not in want
    assert got["windowed"]["windows"] == 9 and got["windowed"]["alignment_decimation"] == 1
    assert_same_report(got, want)
    if align == "nuth-kaab":
        assert got["shift"]["dx_px"] == pytest.approx(-1.3, abs=0.01)
    assert got["effective_resolution"]["wavelength_m"] == pytest.approx(
        want["effective_resolution"]["wavelength_m"], rel=1e-9)
    a = dio.read_raster(tmp_path / "windows" / "difference.tif", what="difference")
    b = dio.read_raster(tmp_path / "memory" / "difference.tif", what="difference")
    np.testing.assert_array_equal(a.data, b.data)
    assert a.tags["frame"] == "image:view_00" and a.transform == b.transform
    assert set(got["figures"]) == set(want["figures"])
    assert (tmp_path / "windows" / "report.json.json").is_file()


def test_only_windows_are_read(pair, tmp_path, monkeypatch):
    """No whole-raster read; the largest read is a window with its margins."""
    def refuse(*args, **kwargs):
        raise AssertionError("a whole raster was read")

    monkeypatch.setattr(dio, "read_raster", refuse)
    report = compare(pair, tmp_path / "out", tile_size=32)
    margin = report["windowed"]["margin_cells"]
    assert margin == 2 + 3 + 2  # |shift| 1.3 px rounded up + Lanczos-3 + 2
    assert report["windowed"]["largest_read_cells"] <= (32 + 2 * margin) ** 2 < 96 * 96
    assert report["windowed"]["passes"] >= 3  # moments, then the order statistics


def test_a_grid_beyond_the_memory_budget_is_compared_in_windows(tmp_path):
    """160² cells × 160 bytes > 3 MiB: windows of √(3 MiB / 160) = 140 cells, the
    alignment on every 2nd cell (3 MiB / 400 bytes = 7864 cells < 160²)."""
    truth = fractal(160, relief=25.0, seed=5)
    dem = fourier_shift(truth, 1.3, -0.7) + 2.0
    transform = dio.image_frame_transform(SPACING)
    dio.write_raster(tmp_path / "reference.tif", truth, transform=transform)
    dio.write_raster(tmp_path / "dem.tif", dem, transform=transform)
    report = compare(tmp_path, tmp_path / "out", max_memory_mb=3.0)
    assert report["windowed"]["tile_size"] == 140
    assert report["windowed"]["alignment_decimation"] == 2
    assert report["shift"]["dx_px"] == pytest.approx(-1.3, abs=0.05)
    assert report["shift"]["dy_px"] == pytest.approx(0.7, abs=0.05)
    assert report["shift"]["dz"] == pytest.approx(-2.0, abs=0.05)
    assert report["rmse"] < 0.15
    assert any("fitted on one cell in 2 x 2" in w for w in report["warnings"])
    memory = compare(tmp_path, tmp_path / "memory")
    assert "windowed" not in memory and memory["count"] == report["count"]
    assert report["rmse"] == pytest.approx(memory["rmse"], abs=0.02)


def _invoke(*args):
    return CliRunner().invoke(cli, ["compare", *map(str, args)])


@pytest.mark.parametrize("args, message", [
    (["--align", "icp", "--tile-size", "32"], "--align icp needs the whole grid in memory"),
    (["--tile-size", "8"], "--tile-size must be 0 (in memory) or >= 16 cells, got 8"),
])
def test_bad_windowed_options_fail_cleanly(pair, tmp_path, args, message):
    out = tmp_path / "out"
    result = _invoke(pair / "dem.tif", pair / "reference.tif", "--out", out, *args)
    assert result.exit_code == 1, result.output
    lines = [ln for ln in result.output.strip().splitlines() if ln.startswith("Error")]
    assert len(lines) == 1 and message in lines[0], result.output
    assert not out.exists() or not any(Path(out).iterdir())


def test_windowed_command_line_with_also(pair, tmp_path):
    out, memory = tmp_path / "out", tmp_path / "memory"
    args = [pair / "dem.tif", pair / "reference.tif", "--also", pair / "dem_offset.tif",
            "--no-plots"]
    result = _invoke(*args, "--out", out, "--tile-size", "48")
    assert result.exit_code == 0, result.output
    assert _invoke(*args, "--out", memory).exit_code == 0
    report, want = dio.read_json(out / "report.json"), dio.read_json(memory / "report.json")
    assert report["windowed"]["windows"] == 4 and report["figures"] == []
    also, also_want = report["also"][0], want["also"][0]
    assert also["label"] == "dem_offset" and also["count"] == also_want["count"]
    for key in ("rmse", "nmad", "median"):
        assert also[key] == pytest.approx(also_want[key], rel=1e-9), key


def test_a_mask_on_another_grid_is_refused_in_windows(pair, tmp_path):
    out = tmp_path / "out"
    result = _invoke(pair / "dem.tif", pair / "reference.tif", "--out", out, "--tile-size",
                     "32", "--mask", pair / "dem_offset.tif")
    assert result.exit_code == 1, result.output
    lines = [ln for ln in result.output.strip().splitlines() if ln.startswith("Error")]
    assert len(lines) == 1 and "dem_offset.tif: mask is" in lines[0], result.output
    assert not out.exists() or not any(Path(out).iterdir())
