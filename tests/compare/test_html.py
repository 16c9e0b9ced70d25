"""compare --html: one self-contained report.html, rendered by a real headless Chromium."""

import base64
import re
import shutil
import subprocess

import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from demtool.compare.html import html_report
from tests.helpers.compare import fourier_shift, fractal

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def _browser():
    for name in BROWSERS:
        path = shutil.which(name)
        if path:
            return path
    return None


@pytest.fixture(scope="module")
def report_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("html")
    truth = fractal(96, relief=30.0, seed=5)
    dem = fourier_shift(truth, 0.6, -0.4) + 1.0
    transform = dio.image_frame_transform(2.0)
    dio.write_raster(folder / "ref.tif", truth, transform=transform)
    dio.write_raster(folder / "dem.tif", dem, transform=transform)
    result = CliRunner().invoke(cli, ["-q", "compare", str(folder / "dem.tif"),
                                      str(folder / "ref.tif"), "--out", str(folder / "out"),
                                      "--html"])
    assert result.exit_code == 0, result.output
    return folder / "out"


@pytest.mark.slow
def test_report_html_is_self_contained_with_table_shift_figures_and_provenance(report_folder):
    page = (report_folder / "report.html").read_text(encoding="utf-8")
    report = dio.read_json(report_folder / "report.json")
    assert "report.html" in [str(p).rsplit("/", 1)[-1] for p in report["provenance"]["outputs"]]
    # nothing fetched from anywhere: every src is a data: URI, no script, no link
    sources = re.findall(r'src="([^"]*)"', page)
    assert sources and all(s.startswith("data:image/png;base64,") for s in sources)
    assert "<script" not in page and "<link" not in page and "http" not in page.split(
        "<h2>Provenance</h2>")[0]
    figures = sorted(report["figures"])
    assert len(sources) == len(figures)
    for source, name in zip(sources, [re.search(r'data-name="([^"]+)"', m).group(1)
                                      for m in re.findall(r"<img[^>]*>", page)], strict=True):
        assert base64.b64decode(source.split(",", 1)[1]) == (report_folder / name).read_bytes()
    assert 'id="statistics"' in page and f"{report['rmse']:.3f}" in page
    assert 'id="shift"' in page and f"{report['shift']['dx_px']:.3f}" in page
    assert f"{report['shift_input_px']['dem']['dx_px']:.3f}" in page
    assert report["provenance"]["inputs"][0]["sha256"] in page


def test_html_escapes_what_it_shows():
    page = html_report({"label": "<b>x</b>", "reference": "r&d.tif", "warnings": ["a<b"]}, {})
    assert "<b>x</b>" not in page and "&lt;b&gt;x&lt;/b&gt;" in page
    assert "r&amp;d.tif" in page and "a&lt;b" in page and "No figures" in page


@pytest.mark.slow
@pytest.mark.skipif(_browser() is None,
                    reason="no Chromium/Chrome on PATH (Debian: apt-get install chromium; "
                           ".ci/run installs it): the HTML report is not rendered")
def test_report_html_renders_in_headless_chromium(report_folder, tmp_path):
    browser = _browser()
    url = (report_folder / "report.html").resolve().as_uri()
    common = [browser, "--headless", "--no-sandbox", "--disable-gpu",
              "--disable-background-networking", "--disable-component-update",
              "--disable-sync", "--no-first-run", "--disable-dev-shm-usage",
              f"--user-data-dir={tmp_path / 'profile'}"]
    shot = tmp_path / "report.png"
    # one browser start: the DOM after loading on stdout, the rendered page as a PNG
    dom = subprocess.run([*common, f"--screenshot={shot}", "--window-size=1200,2400",
                          "--hide-scrollbars", "--dump-dom", url], capture_output=True,
                         text=True, timeout=120, check=True).stdout
    # the browser parsed the page: its tables and inline images are in the DOM
    assert '<table id="statistics">' in dom and '<table id="shift">' in dom
    images = re.findall(r'<img [^>]*src="data:image/png;base64,', dom)
    assert len(images) == len(dio.read_json(report_folder / "report.json")["figures"])
    from matplotlib.image import imread

    pixels = imread(shot)[..., :3]
    assert pixels.shape[:2] == (2400, 1200)
    # the page drew something: text (dark pixels) and the figures' colour maps
    # (saturated pixels, which the page's grey text and tables never are)
    saturation = pixels.max(axis=-1) - pixels.min(axis=-1)
    assert (pixels.max(axis=-1) < 0.3).mean() > 0.002
    assert (saturation > 0.3).mean() > 0.01
