"""The documentation: it builds with no warning, and its generated pages are up to date.

- ``mkdocs build --strict`` (warnings, broken links and broken anchors fail);
- ``docs/reference/`` and the reference block of ``mkdocs.yml`` equal what
  ``python docs/gen_reference.py`` writes from the command line now;
- ``docs/validation.md`` equals what ``python bench/validation_page.py`` writes from
  ``bench/results/*.json``, and every table there says when, where and how;
- the README stays short and its links into the docs lead to pages that exist.
"""

from __future__ import annotations

import importlib.util
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _load(path: Path):
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_mkdocs_builds_in_strict_mode(tmp_path):
    if importlib.util.find_spec("mkdocs") is None or importlib.util.find_spec(
            "material") is None:
        pytest.skip("mkdocs and mkdocs-material are not installed (pip install -e '.[docs]')")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file",
         str(ROOT / "mkdocs.yml"), "--site-dir", str(tmp_path / "site")],
        capture_output=True, text=True, env=env, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "WARNING" not in result.stderr, result.stderr
    for page in ["index.html", "tutorials/lunar-frame/index.html", "reference/dem/index.html",
                 "validation/index.html", "concepts/index.html"]:
        assert (tmp_path / "site" / page).exists(), page


def test_reference_pages_regenerate_with_no_diff(capsys):
    generator = _load(ROOT / "docs" / "gen_reference.py")
    status = generator.main(["--check"])
    assert status == 0, capsys.readouterr().out


def test_reference_page_lists_every_option_default_and_range():
    generator = _load(ROOT / "docs" / "gen_reference.py")
    page = generator.stage_page("sgm")
    assert "| `--num-disparities` |" in page and "| `--cost` | choice |" in page
    assert "`hmi`" in page and "None" not in page
    assert "## Error messages" in page


def test_validation_page_is_up_to_date_and_every_table_is_dated():
    builder = _load(ROOT / "bench" / "validation_page.py")
    results = sorted((ROOT / "bench" / "results").glob("*.json"))
    assert results
    for path in results:
        result = builder.load(path)
        assert re.fullmatch(r"\d{4}-\d{2}-\d{2}", result["date"]), path
        assert result["machine"] and result["command"], path
    assert builder.main(["--check"]) == 0


def test_readme_is_short_and_its_doc_links_exist():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 250
    links = re.findall(r"\]\((docs/[^)#]+)", text)
    assert links
    for link in links:
        assert (ROOT / link).exists(), link


def test_tutorial_route_for_two_cubes_is_at_most_six_commands():
    """From the README alone: two cubes with SPICE → DEM on the map → comparison."""
    text = (ROOT / "README.md").read_text()
    block = text.split("<!-- readme-example -->", 1)[1].split("```", 2)[1]
    commands = [shlex.split(line, comments=True) for line in
                block.replace("\\\n", " ").splitlines() if line.startswith("demtool ")]
    stages = [c[1] for c in commands]
    assert stages[-1] == "compare" and "dem" in stages and len(commands) <= 6
    # The same commands run in the lunar tutorial, which tests/test_tutorials.py executes.
    tutorial = _load(ROOT / "tests" / "test_tutorials.py")
    tested = [" ".join(c) for c in tutorial.commands(ROOT / "docs" / "tutorials" /
                                                     "lunar-frame.md")]
    for command in commands:
        assert " ".join(command) in tested, command
