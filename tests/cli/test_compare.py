"""Tests of `demtool compare` through the command line (CliRunner)."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from tests.helpers.compare import fourier_shift, fractal, wavy

SPACING = 2.0
FIGURES = {"difference.png", "dems.png", "profiles.png", "histogram.png", "completeness.png",
           "coherence.png"}


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """A reference and a DEM displaced by (1.3, -0.7) px and +2 m with a hole, on disk."""
    folder = tmp_path_factory.mktemp("compare_pair")
    truth = fractal(96, relief=25.0, seed=11)
    dem = fourier_shift(truth, 1.3, -0.7) + 2.0
    dem += np.random.default_rng(12).normal(scale=0.02, size=dem.shape)
    dem[40:50, 30:50] = np.nan
    transform = dio.image_frame_transform(SPACING)
    tags = {"frame": "image:view_00"}
    dio.write_raster(folder / "reference.tif", truth, transform=transform, tags=tags)
    dio.write_raster(folder / "dem.tif", dem, transform=transform, tags=tags)
    dio.write_raster(folder / "other.tif", truth + 0.5, transform=transform, tags=tags)
    return folder


def _invoke(*args):
    return CliRunner().invoke(cli, ["compare", *map(str, args)])


def _assert_png(path):
    import matplotlib.pyplot as plt

    assert path.stat().st_size > 5_000
    image = plt.imread(path)
    assert image.shape[0] > 200 and image.shape[1] > 200
    assert np.ptp(image[..., :3]) > 0.3  # not a uniform picture


def test_compare_writes_the_report_folder(pair, tmp_path):
    out = tmp_path / "report"
    result = _invoke(pair / "dem.tif", pair / "reference.tif", "--out", out, "--label", "bam",
                     "--also", pair / "other.tif", "--profile", "0,10,95,80", "--profile",
                     "5,5,5,90", "--json")
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    on_disk = dio.read_json(out / "report.json")
    assert on_disk["rmse"] == pytest.approx(report["rmse"])
    for key in ("rmse", "nmad", "mean", "median", "std", "le90", "completeness", "count"):
        assert isinstance(report[key], (int, float))
    assert report["label"] == "bam"
    assert report["shift"]["dx_px"] == pytest.approx(-1.3, abs=0.01)
    assert report["shift"]["dy_px"] == pytest.approx(0.7, abs=0.01)
    assert report["shift"]["dz"] == pytest.approx(-2.0, abs=0.01)
    assert report["completeness"] == pytest.approx(100 * (1 - 200 / 96**2))
    assert report["rmse"] < 0.1  # noise 0.02 m + cubic interpolation of a rough surface
    assert report["before_alignment"]["rmse"] > 1.0
    assert [c["slope_min_deg"] for c in report["slope_classes"]] == [0, 5, 10, 20, 30]
    assert report["effective_resolution"]["wavelength_m"] >= 2 * SPACING
    assert report["also"][0]["label"] == "other"
    assert report["also"][0]["shift"]["dz"] == pytest.approx(-0.5, abs=1e-3)
    assert report["provenance"]["stage"] == "compare"
    assert report["profiles_px"] == [[0, 10, 95, 80], [5, 5, 5, 90]]
    assert set(report["figures"]) == FIGURES
    for name in FIGURES:
        _assert_png(out / name)
    difference = dio.read_raster(out / "difference.tif", what="difference")
    assert difference.tags["demtool_stage"] == "compare"
    assert difference.tags["frame"] == "image:view_00"
    assert difference.spacing == (SPACING, SPACING)
    assert np.nanstd(difference.data) == pytest.approx(report["std"], rel=1e-3)
    sidecar = dio.read_json(out / "report.json.json")
    assert sidecar["summary"]["rmse"] == pytest.approx(report["rmse"])
    timings = sidecar["summary"]["timings_s"]  # wall and CPU seconds per phase
    assert {"read", "compare", "coarse", "figures", "write_difference"} <= set(timings)
    assert all(timings[f"{phase}_cpu"] >= 0 for phase in ("read", "compare", "figures"))
    assert "count" in result.stderr or "RMSE" in result.stderr  # the console table


def test_no_plots_and_grid_dem(pair, tmp_path):
    from affine import Affine

    coarse = tmp_path / "coarse_reference.tif"
    truth = dio.read_raster(pair / "reference.tif").data
    # pixel centres of the coarse grid coincide with the even pixels' centres shifted
    # by half a fine pixel: a resampling on the DEM's grid is needed
    dio.write_raster(coarse, truth[::2, ::2],
                     transform=dio.image_frame_transform(2 * SPACING) @ Affine.translation(
                         0.25, -0.25))
    out = tmp_path / "report"
    result = _invoke(pair / "other.tif", coarse, "--out", out, "--grid", "dem", "--align",
                     "offset", "--no-plots")
    assert result.exit_code == 0, result.output
    report = dio.read_json(out / "report.json")
    assert report["grid"]["on"] == "dem" and report["grid"]["shape"] == [96, 96]
    assert report["shift"]["dz"] == pytest.approx(-0.5, abs=0.05)
    assert not list(out.glob("*.png"))


def test_mismatched_crs_is_reprojected(tmp_path):
    from affine import Affine

    east, north = 400_000.0, 5_000_000.0
    rows, cols = np.indices((64, 64), dtype=float)
    reference = wavy(east + 2.0 * (cols + 0.5), north - 2.0 * (rows + 0.5))
    dio.write_raster(tmp_path / "ref.tif", reference, crs="EPSG:32633",
                     transform=Affine(2.0, 0, east, 0, -2.0, north))
    rows, cols = np.indices((80, 80), dtype=float)
    dem = wavy(east - 20 + 2.0 * (cols + 0.5), north + 20 - 2.0 * (rows + 0.5))
    shifted = ("+proj=tmerc +lat_0=0 +lon_0=15 +k=0.9996 +x_0=501000 +y_0=0 +datum=WGS84 "
               "+units=m +no_defs")
    dio.write_raster(tmp_path / "dem.tif", dem, crs=shifted,
                     transform=Affine(2.0, 0, east + 1000 - 20, 0, -2.0, north + 20))
    out = tmp_path / "report"
    result = _invoke(tmp_path / "dem.tif", tmp_path / "ref.tif", "--out", out, "--align",
                     "none", "--no-plots")
    assert result.exit_code == 0, result.output
    report = dio.read_json(out / "report.json")
    assert report["completeness"] == 100.0
    assert report["rmse"] < 0.01
    assert "32633" in report["grid"]["crs"]


def test_mask_restricts_the_statistics(pair, tmp_path):
    mask = np.zeros((96, 96), np.float32)
    mask[:, :48] = 1
    dio.write_raster(tmp_path / "mask.tif", mask, transform=dio.image_frame_transform(SPACING))
    out = tmp_path / "report"
    result = _invoke(pair / "other.tif", pair / "reference.tif", "--out", out, "--mask",
                     tmp_path / "mask.tif", "--align", "none", "--no-plots")
    assert result.exit_code == 0, result.output
    report = dio.read_json(out / "report.json")
    assert report["count"] == 96 * 48
    assert report["mean"] == pytest.approx(0.5, abs=1e-5)


@pytest.mark.parametrize("case", ["missing", "corrupt", "all_nan", "no_overlap", "empty_mask",
                                  "other_frame"])
def test_bad_inputs_fail_cleanly_without_output(pair, tmp_path, case):
    dem = tmp_path / "dem.tif"
    extra = []
    if case == "empty_mask":
        dio.write_raster(dem, np.zeros((96, 96)), transform=dio.image_frame_transform(SPACING))
        extra = ["--mask", dem]  # all zeros: selects nothing
        dem = pair / "dem.tif"
        expected = "mask selects no pixel"
    elif case == "missing":
        expected = "not found"
    elif case == "other_frame":
        dio.write_raster(dem, np.zeros((96, 96)), transform=dio.image_frame_transform(SPACING),
                         tags={"frame": "map:local"})
        expected = "is in frame 'map:local' but the reference"
    elif case == "corrupt":
        dem.write_bytes(b"this is not a GeoTIFF" * 20)
        expected = "cannot read DEM"
    elif case == "all_nan":
        dio.write_raster(dem, np.full((20, 20), np.nan), transform=dio.image_frame_transform(2))
        expected = "no valid"
    else:
        from affine import Affine

        dio.write_raster(dem, np.zeros((20, 20)), transform=Affine(2, 0, 5000, 0, -2, 0))
        expected = "do not overlap"
    out = tmp_path / "report"
    result = _invoke(dem, pair / "reference.tif", "--out", out, *extra)
    assert result.exit_code == 1
    assert expected in result.output
    assert str(extra[1] if extra else dem) in result.output
    assert len(result.output.strip().splitlines()) == 1
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize("args, message", [
    (["--profile", "1,2,3"], "needs 4 numbers"),
    (["--profile", "a,b,c,d"], "comma-separated numbers"),
    (["--slope-bins", "10,5"], "increasing"),
    (["--align", "icpp"], "icpp"),
])
def test_bad_options_are_usage_errors(pair, tmp_path, args, message):
    result = _invoke(pair / "dem.tif", pair / "reference.tif", "--out", tmp_path / "r", *args)
    assert result.exit_code == 2
    assert message in result.output
    assert not (tmp_path / "r").exists()


def test_profile_outside_the_grid_is_a_parameter_error(pair, tmp_path):
    result = _invoke(pair / "dem.tif", pair / "reference.tif", "--out", tmp_path / "r",
                     "--profile", "0,0,500,10", "--no-plots")
    assert result.exit_code == 1
    assert "leaves the comparison grid" in result.output
    assert not (tmp_path / "r").exists()


def test_difference_written_beside_the_figures_is_the_same_and_all_or_nothing(
        pair, tmp_path, monkeypatch):
    """On a grid large enough for two threads the difference raster is written on a side
    thread while the figures are drawn: the same raster and figures as one after the
    other; a figure that fails leaves no output folder, the raster written beside it
    included."""
    import demtool.compare.threads as compare_threads

    single = tmp_path / "single"
    monkeypatch.setattr(compare_threads, "THREADED_CELLS", 10**9)
    assert _invoke(pair / "dem.tif", pair / "reference.tif", "--out", single).exit_code == 0
    monkeypatch.setattr(compare_threads, "THREADED_CELLS", 1)
    monkeypatch.setattr("demtool.tiling.tasks.usable_threads", lambda: 2)
    written = []
    original = dio.write_raster

    def recording(path, *args, **kwargs):
        import threading

        written.append(threading.current_thread().name)
        return original(path, *args, **kwargs)

    monkeypatch.setattr(dio, "write_raster", recording)
    beside = tmp_path / "beside"
    assert _invoke(pair / "dem.tif", pair / "reference.tif", "--out", beside).exit_code == 0
    assert written and written[0] != "MainThread"  # the side thread wrote it
    first = dio.read_raster(single / "difference.tif")
    second = dio.read_raster(beside / "difference.tif")
    assert np.array_equal(first.data, second.data, equal_nan=True)
    for name in FIGURES:
        assert (single / name).read_bytes() == (beside / name).read_bytes(), name

    def failing(*args, **kwargs):
        raise RuntimeError("a figure failed")

    monkeypatch.setattr("demtool.compare.plots.histogram_figure", failing)
    failed = tmp_path / "failed"
    result = _invoke(pair / "dem.tif", pair / "reference.tif", "--out", failed)
    assert result.exit_code != 0
    assert len(written) >= 2  # the raster was written beside the failing figures
    assert not failed.exists()


def test_matplotlib_imported_ahead_leaves_the_warning_filters_as_they_were(pair, tmp_path):
    """compare imports matplotlib's figure and canvas on a side thread while it reads;
    the package (whose import sets and puts back warning filters) on this one first: the
    process's warning filters after the command are those before it, and the thread is
    joined when the command ends."""
    import threading
    import warnings

    before = list(warnings.filters)
    result = _invoke(pair / "dem.tif", pair / "reference.tif", "--out", tmp_path / "r")
    assert result.exit_code == 0, result.output
    assert list(warnings.filters) == before
    assert not any(t.name == "demtool-matplotlib-ahead" for t in threading.enumerate())
    assert {p.name for p in (tmp_path / "r").iterdir()} >= FIGURES
