"""Every stage end to end on the small synthetic scene, checked against its truth.

This is `make demo` in miniature, run through the command line with the NavCam preset:
BAM (select → bundle → dem), SIAM (rectify → sgm → dem, calibrated and projective),
area-based matching (match → dem), shape from shading (refine), and compare of each
product with the truth.
"""

import json
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from demtool.compare.summary import format_table, summary_rows

NAVCAM = str(Path(__file__).parents[2] / "configs" / "navcam.toml")

pytestmark = pytest.mark.slow


def _run(*args: str) -> None:
    result = CliRunner().invoke(cli, ["-q", "--config", NAVCAM, *args])
    assert result.exit_code == 0, f"demtool {' '.join(args)} failed:\n{result.output}"


@pytest.fixture(scope="module")
def chain(small_scene_dir, tmp_path_factory):
    work = tmp_path_factory.mktemp("chain")
    scene = work / "scene"
    shutil.copytree(small_scene_dir, scene)
    meta = json.loads((scene / "scene.json").read_text())
    target = scene / f"{meta['target']}.tif"
    partner = scene / f"{meta['partner']}.tif"
    stereo = work / "stereo"
    views = sorted(str(p) for p in scene.glob("view_*.tif"))

    _run("select", *views, "--target", str(target), "--cameras", str(scene / "cameras.npz"),
         "--scene", str(scene / "scene.json"), "--out", str(work / "selection.json"))
    _run("bundle", str(work / "selection.json"), "--cameras", str(scene / "cameras.npz"),
         "--align-cameras", str(scene / "cameras.npz"), "--out", str(work / "bundle.npz"))
    _run("dem", "--points", str(work / "bundle.npz"), "--scene", str(scene / "scene.json"),
         "--out", str(work / "dem_bam.tif"))
    _run("rectify", str(target), str(partner), "--out", str(stereo))
    _run("sgm", str(stereo / "left_rect.tif"), str(stereo / "right_rect.tif"),
         "--rectify", str(stereo / "rectify.npz"), "--out", str(stereo / "disparity_sgm.tif"))
    _run("dem", "--disparity", str(stereo / "disparity_sgm.tif"),
         "--rectify", str(stereo / "rectify.npz"), "--cameras", str(scene / "cameras.npz"),
         "--scene", str(scene / "scene.json"), "--out", str(work / "dem_siam.tif"))
    _run("dem", "--disparity", str(stereo / "disparity_sgm.tif"),
         "--rectify", str(stereo / "rectify.npz"), "--reference", str(work / "dem_bam.tif"),
         "--out", str(work / "dem_siam_projective.tif"))
    _run("match", str(stereo / "left_rect.tif"), str(stereo / "right_rect.tif"),
         "--rectify", str(stereo / "rectify.npz"), "--out", str(stereo / "disparity_match.tif"))
    _run("dem", "--disparity", str(stereo / "disparity_match.tif"),
         "--rectify", str(stereo / "rectify.npz"), "--cameras", str(scene / "cameras.npz"),
         "--scene", str(scene / "scene.json"), "--out", str(work / "dem_match.tif"))
    _run("refine", str(target), str(work / "dem_siam.tif"), "--out", str(work / "dem_refined.tif"))
    reports = {}
    for product in ["dem_bam", "dem_siam", "dem_siam_projective", "dem_match", "dem_refined"]:
        _run("compare", str(work / f"{product}.tif"), str(scene / "truth_dem_target.tif"),
             "--out", str(work / "reports" / product), "--label", product, "--no-plots")
        reports[product] = work / "reports" / product / "report.json"
    return {"work": work, "gsd_m": meta["gsd_m"], "reports": reports}


def test_every_product_meets_its_accuracy_against_the_truth(chain):
    gsd = chain["gsd_m"]
    report = {name: json.loads(path.read_text()) for name, path in chain["reports"].items()}
    # Issue targets on the default scene: calibrated SIAM < 1 GSD, BAM < 2 GSD, gaps filled.
    assert report["dem_siam"]["rmse"] < 1.0 * gsd
    assert report["dem_match"]["rmse"] < 1.0 * gsd
    assert report["dem_bam"]["rmse"] < 2.0 * gsd
    assert report["dem_siam_projective"]["rmse"] < 2.0 * gsd
    for name in report:
        assert report[name]["completeness"] == pytest.approx(100.0), name
    # Shape from shading must add detail, not noise, and keep the absolute heights.
    assert report["dem_refined"]["rmse"] < report["dem_siam"]["rmse"]
    assert abs(report["dem_refined"]["shift"]["dz"]) < 0.1 * gsd


def test_every_output_says_how_it_was_made(chain):
    work = chain["work"]
    for name in ["dem_bam", "dem_siam", "dem_match", "dem_refined"]:
        raster = dio.read_raster(work / f"{name}.tif")
        assert raster.tags["demtool_stage"] in {"dem", "refine"}
        assert raster.tags["frame"] == "image:view_00"
        sidecar = json.loads((work / f"{name}.tif.json").read_text())
        assert sidecar["inputs"] and all(item["sha256"] for item in sidecar["inputs"])
        assert sidecar["parameters"]


def test_summary_table_lists_every_product(chain):
    rows = summary_rows(list(chain["reports"].values()))
    assert [row["product"] for row in rows] == list(chain["reports"])
    table = format_table(rows)
    assert "dem_refined" in table and "RMSE" in table
    assert all(row["coherent_wavelength_m"] is not None for row in rows)
