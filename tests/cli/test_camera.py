"""`demtool camera`: table and JSON on stdout, --out report, every bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from demtool.maps import enu_frame, lonlat_height_to_xyz
from demtool.sensors.pinhole import cameras_to_arrays, look_at
from tests.helpers.camera_isd import MOON_RADIUS, frame_isd, look_at_rotation, write_isd
from tests.helpers.tsai import NULL_LENS as TSAI


@pytest.fixture(scope="module")
def pair_files(tmp_path_factory):
    """Two frame ISDs 30 km apart, 100 km above (10°E, 5°N), both looking at that point,
    the sun 40° high in the east (B/H = 0.3, convergence 2·atan(0.15))."""
    folder = tmp_path_factory.mktemp("isd")
    east, north, up = enu_frame(10.0, 5.0)
    target = lonlat_height_to_xyz(10.0, 5.0, 0.0, radii=MOON_RADIUS)
    sun = target + 1.5e11 * (np.cos(np.radians(40)) * east + np.sin(np.radians(40)) * up)
    paths = []
    for name, side in (("left", -15e3), ("right", 15e3)):
        position = target + 100e3 * up + side * east
        isd = frame_isd(position, look_at_rotation(position, target, east), focal_mm=50.0,
                        pitch_mm=0.01, lines=400, samples=500, sun=sun, name=name)
        paths.append(write_isd(folder / f"{name}.json", isd))
    return paths


def invoke(*args):
    return CliRunner().invoke(cli, ["camera", *map(str, args)])


def test_table_on_stdout(pair_files):
    result = invoke(*pair_files)
    assert result.exit_code == 0, result.output
    out = result.stdout
    assert "left" in out and "right" in out and "Moon" in out
    rows = {line.split("  ")[0].strip(): line.split() for line in out.splitlines() if line}
    assert rows["incidence °"][-2:] == ["50.000", "50.000"]  # the sun 40° high
    # across: pitch · slant / f = 0.01 mm · 101.1 km / 50 mm = 20.22 m; along: / cos 8.53°
    assert [float(v) for v in rows["GSD m/px"][-2:]] == [pytest.approx(20.34, abs=0.02)] * 2
    pair = next(line for line in out.splitlines() if line.startswith("left / right"))
    assert "0.3000" in pair  # B/H
    assert f"{2 * np.degrees(np.arctan(0.15)):.3f}" in pair
    assert "Error" not in result.stderr


def test_json_on_stdout_and_out_report(pair_files, tmp_path):
    report_path = tmp_path / "camera.json"
    result = invoke(*pair_files, "--json", "--out", report_path, "--points-per-edge", "8")
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    left, right = report["cameras"]
    assert (left["name"], right["name"]) == ("left", "right")
    assert left["file"].endswith("left.json") and left["body"] == "Moon"
    assert left["center_lon_deg"] == pytest.approx(10.0, abs=1e-6)
    assert left["center_lat_deg"] == pytest.approx(5.0, abs=1e-6)
    assert left["sun_azimuth_deg"] == pytest.approx(90.0, abs=0.5)
    assert len(left["footprint"]["lon_deg"]) == 32
    (pair,) = report["pairs"]
    assert pair["base_to_height"] == pytest.approx(0.3, rel=1e-6)
    assert pair["convergence_deg"] == pytest.approx(2 * np.degrees(np.arctan(0.15)), abs=1e-4)
    written = json.loads(report_path.read_text())
    assert written["pairs"][0]["base_to_height"] == pytest.approx(0.3, rel=1e-6)
    assert written["provenance"]["stage"] == "camera"
    sidecar = json.loads((tmp_path / "camera.json.json").read_text())
    assert sidecar["stage"] == "camera" and sidecar["summary"] == {"cameras": 2, "pairs": 1}


def test_pinhole_file_without_sun_and_tsai_with_body(tmp_path):
    cams = [look_at((0.0, 0.0, 500.0), (0.0, 0.0, 0.0), (0, 1, 0), focal_px=1000.0,
                    width=200, height=100),
            look_at((100.0, 0.0, 500.0), (100.0, 0.0, 0.0), (0, 1, 0), focal_px=1000.0,
                    width=200, height=100)]
    npz = tmp_path / "cameras.npz"
    dio.write_npz(npz, "cameras", cameras_to_arrays(["a", "b"], cams))
    result = invoke(npz, "--json")
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    a = report["cameras"][0]
    assert a["frame"] == "local" and a["gsd_m"] == pytest.approx(0.5)
    assert "incidence_deg" not in a and any("no sun" in n for n in a["notes"])
    # 100 x 50 m footprints 100 m apart: they touch along an edge, no overlap
    assert report["pairs"][0]["overlap_area_km2"] == pytest.approx(0.0, abs=1e-12)
    tsai = tmp_path / "cam.tsai"
    tsai.write_text(TSAI)
    result = invoke(tsai, "--body", "Moon")
    assert result.exit_code == 0, result.output
    assert "no sun" in result.stdout and "Moon" in result.stdout
    rows = {line.split("  ")[0].strip(): line.split() for line in result.stdout.splitlines()
            if line}
    assert float(rows["GSD m/px"][-1]) == pytest.approx(100e3 / 2000, rel=1e-4)


def one_error_line(result, *needles):
    assert result.exit_code == 1, result.output
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("Error: demtool camera:"), result.stderr
    for needle in needles:
        assert needle in lines[0]
    return lines[0]


def test_bad_inputs(pair_files, tmp_path):
    out = tmp_path / "report.json"
    missing = tmp_path / "missing.json"
    one_error_line(invoke(pair_files[0], missing, "--out", out), str(missing))
    junk = tmp_path / "junk.txt"
    junk.write_text("hello\n")
    one_error_line(invoke(junk, "--out", out), str(junk), "not a sensor model")
    isd = json.loads(pair_files[0].read_text())
    del isd["focal_length_model"]
    broken = write_isd(tmp_path / "broken.json", isd)
    one_error_line(invoke(pair_files[0], broken, "--out", out), str(broken),
                   "focal_length_model")
    tsai = tmp_path / "cam.tsai"
    tsai.write_text(TSAI)
    one_error_line(invoke(tsai, "--out", out), str(tsai), "--body")
    one_error_line(invoke(pair_files[0], "--body", "Vulcan", "--out", out), "--body",
                   "Vulcan")
    assert not out.exists() and not (tmp_path / "report.json.json").exists()
    before = pair_files[1].read_bytes()
    one_error_line(invoke(*pair_files, "--out", pair_files[1]), str(pair_files[1]),
                   "overwrite")
    assert pair_files[1].read_bytes() == before
    usage = invoke(pair_files[0], "--points-per-edge", "1")
    assert usage.exit_code == 2 and "--points-per-edge" in usage.output
    assert invoke().exit_code == 2


def test_a_local_frame_tsai_is_not_put_inside_a_body(tmp_path):
    """A rover's .tsai (centre 1.2 m from its frame's origin) given --body Earth would be a
    camera inside the planet: one line saying so, exit 1, nothing on stdout."""
    tsai = tmp_path / "rover.tsai"
    tsai.write_text(TSAI.replace("C = 1837400 0 0", "C = 0.3 0 -1.2"))
    result = invoke(tsai, "--body", "Earth")
    assert result.exit_code == 1, result.output
    assert "inside the body" in result.output and "local-frame" in result.output
    assert "Traceback" not in result.output
    assert invoke(tmp_path / "rover.tsai", "--body", "Moon").exit_code == 1


def test_a_camera_seeing_no_surface_is_reported_not_refused(tmp_path):
    """A camera looking past the Moon loads in ``camera`` (which says so) though the
    stages that need ground refuse it (issue 41)."""
    position = np.array([3e7, 0.0, 0.0])
    rotation = look_at_rotation(position, position + np.array([0.0, 1e6, 0.0]),
                                np.array([0.0, 0.0, 1.0]))
    path = write_isd(tmp_path / "away.json", frame_isd(position, rotation, focal_mm=20.0,
                                                       pitch_mm=0.01, lines=64, samples=64))
    result = invoke(path, "--json")
    assert result.exit_code == 0, result.output
    assert "sees no surface" in result.stdout
