"""The images of a block: selection.json, list files, paths; and their bad inputs."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from click.testing import CliRunner

from demtool import bundle as core
from demtool.cli import cli
from demtool.errors import InputError


def make_images(folder: Path, names: list[str]) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in names:
        path = folder / f"{name}.tif"
        path.write_bytes(b"not read here")
        paths.append(path)
    return paths


def test_list_file_paths_are_relative_to_it(tmp_path):
    make_images(tmp_path / "data" / "img", ["a", "b"])
    listing = tmp_path / "data" / "list.txt"
    absolute = make_images(tmp_path / "elsewhere", ["c"])[0]
    listing.write_text(f"# a comment\nimg/a.tif\n\n  img/b.tif  \n{absolute}\n")
    block = core.read_image_list(listing)
    assert block.names == ("a", "b", "c") and block.target is None
    assert block.paths == (tmp_path / "data" / "img" / "a.tif",
                           tmp_path / "data" / "img" / "b.tif", absolute)


def test_list_file_naming_a_missing_image(tmp_path):
    make_images(tmp_path, ["a"])
    listing = tmp_path / "list.txt"
    listing.write_text("a.tif\ngone.tif\n")
    with pytest.raises(InputError, match=r"list.txt: line 2: image gone.tif not found"):
        core.read_image_list(listing)
    out = tmp_path / "bundle.npz"
    result = CliRunner().invoke(cli, ["bundle", "--images", str(listing), "--out", str(out)])
    assert result.exit_code == 1 and result.output.count("\n") == 1
    assert "line 2: image gone.tif not found" in result.output
    assert not out.exists() and not (tmp_path / "bundle.npz.json").exists()


def test_block_checks(tmp_path):
    a, b = make_images(tmp_path, ["a", "b"])
    other = make_images(tmp_path / "x", ["a"])[0]
    with pytest.raises(InputError, match="share the view name 'a'"):
        core.block_from_paths([a, other])
    with pytest.raises(InputError, match="at least 2 images"):
        core.block_from_paths([a])
    with pytest.raises(InputError, match="gone.tif: image named in the command line not found"):
        core.block_from_paths([a, tmp_path / "gone.tif"])
    assert core.block_from_paths([a, b]).names == ("a", "b")


def test_command_line_input_errors(tmp_path):
    a, b = make_images(tmp_path, ["a", "b"])
    out = tmp_path / "bundle.npz"
    runner = CliRunner()
    result = runner.invoke(cli, ["bundle", "--out", str(out)])
    assert result.exit_code == 2 and "INPUTS" in result.output
    listing = tmp_path / "l.txt"
    listing.write_text("a.tif\nb.tif\n")
    result = runner.invoke(cli, ["bundle", str(a), "--images", str(listing), "--out", str(out)])
    assert result.exit_code == 2
    result = runner.invoke(cli, ["bundle", str(a), str(tmp_path / "s.json"), "--out", str(out)])
    assert result.exit_code == 2 and "alone" in result.output
    result = runner.invoke(cli, ["bundle", str(tmp_path / "nope.json"), "--out", str(out)])
    assert result.exit_code == 1 and "nope.json: selection file not found" in result.output
    assert not out.exists()


def test_selection_paths_resolve_against_the_selection_file(tmp_path, monkeypatch):
    """Issue 16 class 6: a selection written by `select` works from another folder."""
    from demtool.select.core import path_relative_to

    images = make_images(tmp_path / "project" / "images", ["t", "u"])
    selection = tmp_path / "project" / "work" / "selection.json"
    selection.parent.mkdir()
    monkeypatch.chdir(tmp_path / "project")
    relative = [path_relative_to(os.path.relpath(p), selection.parent) for p in images]
    assert relative == ["../images/t.tif", "../images/u.tif"]
    selection.write_text(json.dumps({
        "target": {"name": "t", "path": relative[0]}, "roi": None,
        "selected": [{"name": "t", "path": relative[0]}, {"name": "u", "path": relative[1]}],
        "rejected": [], "parameters": {}}))
    monkeypatch.chdir(tmp_path)  # somewhere else
    block = core.read_selection(selection)
    assert block.target == "t" and block.names == ("t", "u")
    assert all(p.is_file() for p in block.paths)
    assert [p.resolve() for p in block.paths] == [p.resolve() for p in images]
