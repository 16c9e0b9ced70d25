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
