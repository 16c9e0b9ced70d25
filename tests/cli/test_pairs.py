"""`demtool pairs`: a block of frame ISDs on the Moon → the pairs worth matching."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from demtool.cli import cli
from demtool.maps import enu_frame, lonlat_height_to_xyz
from tests.helpers.camera_isd import MOON_RADIUS, frame_isd, look_at_rotation, write_isd


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    """Four frame cameras 100 km above (10°E, 5°N) looking at it, 0, 10, 40 and 200 km
    east of the nadir (B/H to the first 0, 0.1, 0.4, 2)."""
    folder = tmp_path_factory.mktemp("block")
    east, north, up = enu_frame(10.0, 5.0)
    target = lonlat_height_to_xyz(10.0, 5.0, 0.0, radii=MOON_RADIUS)
    sun = target + 1.5e11 * (np.cos(np.radians(40)) * east + np.sin(np.radians(40)) * up)
    paths = []
    for i, offset in enumerate((0.0, 10e3, 40e3, 200e3)):
        position = target + 100e3 * up + offset * east
        isd = frame_isd(position, look_at_rotation(position, target, east), focal_mm=50.0,
                        pitch_mm=0.01, lines=300, samples=300, sun=sun, name=f"v{i}")
        paths.append(write_isd(folder / f"v{i}.json", isd))
    return paths


def invoke(*args):
    return CliRunner().invoke(cli, ["pairs", *map(str, args)])


def test_pairs_list_keeps_the_useful_pairs(block, tmp_path):
    out = tmp_path / "pairs.txt"
    result = invoke(*block, "--out", out)
    assert result.exit_code == 0, result.output
    lines = out.read_text().splitlines()
    # v0/v2 (B/H 0.4) and v1/v2 (0.3) pass; v0/v1 (0.1) too narrow; v3 too far off
    assert sorted(lines) == ["v0 v2", "v1 v2"]
    assert lines[0] == "v0 v2"  # closer to the preferred B/H 0.5
    assert (tmp_path / "pairs.txt.json").is_file()
    table = result.stdout
    assert "kept #1" in table and "B/H 0.10 outside" in table


def test_no_pair_passing_is_an_error_and_writes_nothing(block, tmp_path):
    out = tmp_path / "pairs.txt"
    result = invoke(*block, "--min-bh", "0.95", "--max-bh", "1.0", "--out", out)
    assert result.exit_code == 1
    assert "Error: demtool pairs: no pair of the 4 models passes" in result.output
    assert not out.exists()


def test_one_model_and_inverted_ranges_are_refused(block, tmp_path):
    result = invoke(block[0])
    assert result.exit_code == 1 and "a block needs at least two" in result.output
    result = invoke(*block, "--min-bh", "0.8", "--max-bh", "0.5")
    assert result.exit_code == 1 and "--min-bh must be <= --max-bh 0.5" in result.output


def test_no_pair_passing_is_one_line_at_q_and_the_table_goes_to_the_log(block, tmp_path):
    """Issue 46: the Error is one line (it was the table, 4–9 lines); the table is logged."""
    out = tmp_path / "pairs.txt"
    args = [*map(str, block), "--min-bh", "0.95", "--max-bh", "1.0", "--out", str(out)]
    quiet = CliRunner().invoke(cli, ["-q", "pairs", *args])
    assert quiet.exit_code == 1
    assert quiet.output.strip().splitlines() == [
        line for line in quiet.output.strip().splitlines() if line.startswith("Error:")]
    assert len(quiet.output.strip().splitlines()) == 1 and "B/H" in quiet.output
    logged = CliRunner().invoke(cli, ["pairs", *args])
    assert "verdict" in logged.output and "v0 v1" in logged.output
    assert not out.exists()


def test_pairs_txt_names_the_files_as_given(block, tmp_path):
    """Issue 46: renamed ISDs (their internal image ids v0…v3 unchanged) are listed by
    their file names, so a loop over pairs.txt finds the files."""
    import shutil

    renamed = []
    for i, path in enumerate(block):
        renamed.append(tmp_path / f"M{1000 + i}LE.json")
        shutil.copy(path, renamed[-1])
    out = tmp_path / "pairs.txt"
    result = invoke(*renamed, "--out", out)
    assert result.exit_code == 0, result.output
    for line in out.read_text().splitlines():
        for stem in line.split():
            assert (tmp_path / f"{stem}.json").is_file(), line
