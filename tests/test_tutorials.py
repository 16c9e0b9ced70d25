"""Every command of the tutorials (docs/tutorials/*.md) runs, on synthetic stand-ins.

A tutorial's commands are the fenced ``bash`` blocks that follow the marker
``<!-- tutorial-test -->``; every other fenced block must say ``not run by the tests``
(ISIS, SLURM), so no command escapes the tests.  Each command is run as written through
the command line (in process, with ``CliRunner``, in a fresh folder), after replacing the
tutorial's file names by the stand-ins below: a ``synth --sensor frame`` pair for the
Apollo cubes and LOLA, a ``synth --sensor linescan`` pair for HiRISE/CTX, the small
pinhole scene for NavCam and rover images.  A token is replaced only when it equals a
name of the map (a model's name maps to the ISD after ``--sensor*`` options and in
``camera``, to the image elsewhere); ``*`` patterns are expanded as the shell would.
"""

from __future__ import annotations

import glob
import json
import re
import shlex
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from demtool.cli import cli

ROOT = Path(__file__).resolve().parents[1]
TUTORIALS = ROOT / "docs" / "tutorials"
FENCE = re.compile(r"(?P<marker><!-- tutorial-test -->\s*\n)?^```(?P<lang>\w*)[^\n]*\n"
                   r"(?P<body>.*?)^```\s*$", re.S | re.M)
SENSOR_OPTIONS = {"--sensor", "--sensor-left", "--sensor-right", "--sensors"}
SYNTH_SIZE = ["--size", "192", "--image-size", "192"]


def blocks(path: Path) -> list[tuple[bool, str, str]]:
    """(marked, language, body) of every fenced block of a page."""
    return [(bool(m["marker"]), m["lang"], m["body"]) for m in FENCE.finditer(path.read_text())]


def commands(path: Path) -> list[list[str]]:
    """The commands of the marked blocks, as argument lists (continuations joined)."""
    found = []
    for marked, _, body in blocks(path):
        if marked:
            text = body.replace("\\\n", " ")
            found += [shlex.split(line, comments=True) for line in text.splitlines()]
    return [c for c in found if c]


def substitute(command: list[str], names: dict[str, str | tuple[str, str]]) -> list[str]:
    """The command with the tutorial's names replaced by the stand-ins, globs expanded."""
    stage = next((t for t in command[1:] if not t.startswith("-") and t in _stages()), None)
    out: list[str] = []
    previous = ""
    for token in command[1:]:
        value = names.get(token, token)
        if isinstance(value, tuple):
            value = value[1] if previous in SENSOR_OPTIONS or stage == "camera" else value[0]
        out += sorted(glob.glob(value)) if "*" in value else [value]
        previous = token
    return out


def _stages() -> set[str]:
    from demtool.stages import STAGES

    return set(STAGES)


def run_tutorial(name: str, names: dict, folder: Path, monkeypatch) -> list[list[str]]:
    monkeypatch.chdir(folder)
    ran = []
    for command in commands(TUTORIALS / name):
        assert command[0] == "demtool", f"{name}: not a demtool command: {command}"
        args = substitute(command, names)
        result = CliRunner().invoke(cli, args)
        assert result.exit_code == 0, f"{name}: demtool {' '.join(args)}\n{result.output}"
        ran.append(args)
    return ran


def _synth(out: Path, *args: str) -> Path:
    result = CliRunner().invoke(cli, ["-q", "synth", "--out", str(out), *args])
    assert result.exit_code == 0, result.output
    return out


def _views(scene: Path) -> tuple[str, str]:
    meta = json.loads((scene / "scene.json").read_text())
    return meta["target"], meta["partner"]


def _model(scene: Path, view: str) -> tuple[str, str]:
    return str(scene / f"{view}.tif"), str(scene / f"{view}.json")


def _report(folder: Path) -> dict:
    report = json.loads((folder / "report.json").read_text())
    assert report["count"] > 0 and report["rmse"] == report["rmse"]
    return report


# ----------------------------------------------------------------------------- the pages


def test_every_command_block_is_tested_or_says_it_is_not():
    pages = sorted(TUTORIALS.glob("*.md"))
    assert len(pages) >= 6
    for page in pages:
        for marked, lang, body in blocks(page):
            if not marked:
                assert "not run by the tests" in body, f"{page.name}: untested block:\n{body}"
            else:
                assert lang == "bash", f"{page.name}: marked block in {lang!r}"
        if page.name != "index.md":
            assert commands(page), f"{page.name} has no tested command"


def test_substitution_picks_the_model_after_sensor_options():
    names = {"a.cub": ("a.tif", "a.json")}
    assert substitute(["demtool", "rectify", "a.cub", "--sensor-left", "a.cub"], names) == [
        "rectify", "a.tif", "--sensor-left", "a.json"]
    assert substitute(["demtool", "camera", "a.cub"], names) == ["camera", "a.json"]


# ----------------------------------------------------------------------------- tutorials


@pytest.fixture(scope="module")
def frame_scene(tmp_path_factory):
    return _synth(tmp_path_factory.mktemp("frame") / "scene", "--sensor", "frame",
                  "--views", "2", *SYNTH_SIZE)


@pytest.fixture(scope="module")
def linescan_scene(tmp_path_factory):
    return _synth(tmp_path_factory.mktemp("linescan") / "scene", "--sensor", "linescan",
                  *SYNTH_SIZE)


@pytest.mark.slow
def test_lunar_frame_tutorial(frame_scene, tmp_path, monkeypatch):
    left, right = _views(frame_scene)
    names = {"AS15-M-0297.cub": _model(frame_scene, left),
             "AS15-M-0298.cub": _model(frame_scene, right),
             "adjusted/AS15-M-0297.json": f"adjusted/{left}.json",
             "adjusted/AS15-M-0298.json": f"adjusted/{right}.json",
             "lola.tif": str(frame_scene / "truth_dem_map.tif")}
    run_tutorial("lunar-frame.md", names, tmp_path, monkeypatch)
    gsd = json.loads((frame_scene / "scene.json").read_text())["gsd_m"]
    assert _report(tmp_path / "report")["rmse"] < 2 * gsd
    assert _report(tmp_path / "report_refined")["rmse"] < 2 * gsd
    assert (tmp_path / "stereo_adjusted" / "rectify.npz").exists()


@pytest.mark.slow
def test_linescan_tutorial(linescan_scene, tmp_path, monkeypatch):
    left, right = _views(linescan_scene)
    names = {"left.cub": _model(linescan_scene, left),
             "right.cub": _model(linescan_scene, right),
             "reference.tif": str(linescan_scene / "truth_dem_map.tif")}
    run_tutorial("linescan.md", names, tmp_path, monkeypatch)
    gsd = json.loads((linescan_scene / "scene.json").read_text())["gsd_m"]
    assert _report(tmp_path / "report")["rmse"] < 2 * gsd
    assert _report(tmp_path / "report_refined")["rmse"] < 2 * gsd


def _pinhole_names(scene: Path) -> dict:
    left, right = _views(scene)
    return {"left.tif": str(scene / f"{left}.tif"), "right.tif": str(scene / f"{right}.tif"),
            "cameras.npz": str(scene / "cameras.npz")}


def _focal_px(scene: Path, view: str) -> float:
    """The synthetic camera's focal length (pixels): the stand-in for NavCam's calibration."""
    from demtool import io as dio
    from demtool.sensors.pinhole import cameras_from_arrays

    return float(cameras_from_arrays(dio.read_npz(scene / "cameras.npz", "cameras"))[view].K[0, 0])


@pytest.mark.slow
def test_comet_tutorial(small_scene_dir, tmp_path, monkeypatch):
    scene = small_scene_dir
    meta = json.loads((scene / "scene.json").read_text())
    left, right = _views(scene)
    names = {"images/*.tif": str(scene / "view_*.tif"),
             "images/target.tif": str(scene / f"{left}.tif"),
             "images/partner.tif": str(scene / f"{right}.tif"),
             "configs/navcam.toml": str(ROOT / "configs" / "navcam.toml"),
             "28000": f"{meta['distance_m']:.3f}", "2.4": f"{meta['gsd_m']:.4f}",
             "11731": f"{_focal_px(scene, left):.4f}"}
    run_tutorial("comet-no-spice.md", names, tmp_path, monkeypatch)
    assert _report(tmp_path / "report")["rmse"] < 4 * meta["gsd_m"]


@pytest.mark.slow
def test_rover_tutorial(small_scene_dir, tmp_path, monkeypatch):
    names = _pinhole_names(small_scene_dir)
    names["scan.tif"] = str(small_scene_dir / "truth_dem_target.tif")
    run_tutorial("rover-pinhole.md", names, tmp_path, monkeypatch)
    gsd = json.loads((small_scene_dir / "scene.json").read_text())["gsd_m"]
    assert _report(tmp_path / "report")["rmse"] < gsd


@pytest.mark.slow
def test_slurm_tutorial(small_scene_dir, tmp_path, monkeypatch):
    scene = small_scene_dir
    left, right = _views(scene)
    rect = tmp_path / "rect"
    result = CliRunner().invoke(cli, ["-q", "rectify", str(scene / f"{left}.tif"),
                                      str(scene / f"{right}.tif"), "--out", str(rect)])
    assert result.exit_code == 0, result.output
    names = {"left_rect.tif": str(rect / "left_rect.tif"),
             "right_rect.tif": str(rect / "right_rect.tif"),
             "rectify.npz": str(rect / "rectify.npz"),
             "cameras.npz": str(scene / "cameras.npz"),
             "reference.tif": str(scene / "truth_dem_target.tif"),
             "2048": "96"}  # tiles of 96 px: 2 × 2 tiles and more on the stand-in
    work = tmp_path / "work"
    work.mkdir()
    run_tutorial("slurm-dask.md", names, work, monkeypatch)
    gsd = json.loads((scene / "scene.json").read_text())["gsd_m"]
    assert _report(work / "report")["rmse"] < gsd
    assert not list(work.glob(".*.tiles"))


@pytest.mark.slow
def test_control_altimetry_tutorial(tmp_path, monkeypatch):
    """The CTX network stand-in: three synthetic line scanners with a known pointing error
    and their network (tests/bundle/network_block.py); the LOLA stand-in: a DEM moved by a
    known shift and shots along two tracks."""
    from demtool import io as dio
    from demtool.io.controlnet import write_control_network
    from demtool.maps import body_by_name, grid_from_lonlat, grid_lonlat, lonlat_to_map
    from tests.bundle import network_block as nb

    models = nb.true_models()
    theta = nb.bias()
    data = tmp_path / "data"
    data.mkdir()
    isds = []
    for k, isd in enumerate(nb.prior_isds(models, theta)):
        isds.append(data / f"img{k}.json")
        isds[-1].write_text(json.dumps(isd))
    network, _ = nb.network(models, count=20, noise_px=0.1)
    net = write_control_network(data / "net.net", network)
    moon = body_by_name("Moon")
    grid = grid_from_lonlat(moon, np.array([29.95, 30.05, 30.05, 29.95]),
                            np.array([-10.05, -10.05, -9.95, -9.95]), 20.0)
    gx, gy = lonlat_to_map(grid.crs, *grid_lonlat(grid))
    dem = 40 * np.sin((gx - 30.0) / 300.0) * np.cos(gy / 400.0) + 3.0
    dio.write_raster(data / "dem.tif", dem.astype(np.float32), transform=grid.transform,
                     crs=grid.crs, tags=moon.tags())
    lon = np.concatenate([np.full(200, 30.0), np.full(200, 30.02)])
    lat = np.concatenate([np.linspace(-10.04, -9.96, 200)] * 2)
    x, y = lonlat_to_map(grid.crs, lon, lat)
    radius = moon.radius + 40 * np.sin(x / 300.0) * np.cos(y / 400.0)
    (data / "shots.csv").write_text("longitude,latitude,radius_m,orbit\n" + "\n".join(
        f"{a:.8f},{b:.8f},{r:.3f},{int(a > 30.01)}" for a, b, r in zip(lon, lat, radius,
                                                                          strict=True)))
    names = {"G21_026491_2001_XN_20N286W.lev1.json": str(isds[0]),
             "P15_006844_2009_XN_20N286W.lev1.json": str(isds[1]),
             "P17_007846_2007_XN_20N286W.lev1.json": str(isds[2]),
             "controlnet.net": str(net), "dem.tif": str(data / "dem.tif"),
             "lidarPoints.csv": str(data / "shots.csv")}
    run_tutorial("control-altimetry.md", names, tmp_path, monkeypatch)
    summary = json.loads((tmp_path / "ctx" / "bundle.npz.json").read_text())["summary"]
    assert summary["sigma0"] < summary["initial_sigma0"]
    report_text = (tmp_path / "ctx" / "bundle.bundleout.txt").read_text()
    assert f"Sigma0: {summary['sigma0']:.6f}" in report_text
    assert len((tmp_path / "ctx" / "bundle.points.csv").read_text().splitlines()) == 21
    # the report's residuals are those of the written models and network, read back
    from demtool.io.controlnet import read_control_network
    from demtool.sensors import read_sensor

    adjusted = read_control_network(tmp_path / "ctx" / "adjusted.net")
    written = [read_sensor(tmp_path / "ctx" / "adjusted" / f"img{k}.json") for k in range(3)]
    xyz = np.array([p.adjusted_xyz for p in adjusted.points])
    recomputed = []
    for k, model in enumerate(written):
        line, sample = model.ground_to_image(xyz)
        measured = [p.measures[k] for p in adjusted.points]
        assert np.allclose(line - [m.line for m in measured],
                           [m.line_residual for m in measured], atol=1e-4)
        assert np.allclose(sample - [m.sample for m in measured],
                           [m.sample_residual for m in measured], atol=1e-4)
        recomputed += list(line - [m.line for m in measured])
    assert np.sqrt(np.mean(np.square(recomputed))) == pytest.approx(summary["rms_line_px"],
                                                                    rel=1e-3)
    report = json.loads((tmp_path / "lola" / "report.json").read_text())
    assert abs(report["alignment"]["shift_m"]["east"] + 30.0) < 2.0  # undoes its 30 m
    assert abs(report["alignment"]["shift_m"]["up"] + 3.0) < 0.1
    assert len(list((tmp_path / "lola").glob("profile_track_*.png"))) == 2
