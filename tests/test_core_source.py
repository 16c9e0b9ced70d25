"""Core defaults read from source, lazy packages, and `demtool <stage> --help` without numba."""

import json
import subprocess
import sys

import pytest

from demtool import core_source
from demtool.parameters import core_defaults as imported_defaults
from demtool.stages import STAGES

HEAVY = ("numba", "cv2", "pycolmap")
REFS = ["demtool.sgm.matcher:sgm", "demtool.match.dense:match", "demtool.rectify.core:rectify_pair",
        "demtool.compare.core:compare_dems"]
CONSTANTS = ["demtool.sgm.disparity:SUBPIXEL_MODES", "demtool.sgm.matcher:CENSUS_WINDOWS",
             "demtool.sgm.matcher:COSTS", "demtool.compare.align:ALIGN_METHODS"]


def _run(code: str) -> dict:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=120)
    return json.loads(out.stdout.splitlines()[-1])


@pytest.mark.parametrize("ref", REFS)
def test_static_defaults_equal_the_imported_ones(ref):
    import importlib

    module, name = ref.split(":")
    static = core_source._static_defaults(module, name)  # the source path, whatever is loaded
    real = imported_defaults(getattr(importlib.import_module(module), name))
    assert static == dict(real)
    assert dict(core_source.core_defaults(ref)) == dict(real)


@pytest.mark.parametrize("ref", CONSTANTS)
def test_static_constants_equal_the_imported_ones(ref):
    import importlib

    module, name = ref.split(":")
    constants = core_source._constants(core_source._tree(module))
    assert constants[name] == getattr(importlib.import_module(module), name)


def test_non_literal_defaults_fall_back_to_the_import(tmp_path, monkeypatch):
    (tmp_path / "corefake.py").write_text(
        "import math\nLIMIT = 3\n"
        "def f(a, b=LIMIT, *, c=(1, 'x'), d=None):\n    pass\n"
        "def g(a, b=math.pi):\n    pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "corefake", raising=False)
    found = core_source.core_defaults("corefake:f")
    assert dict(found) == {"b": 3, "c": (1, "x"), "d": None} and "corefake" not in sys.modules
    with pytest.raises(TypeError, match="f\\(\\) has no default for 'a'"):
        found["a"]
    assert dict(core_source.core_defaults("corefake:g")) == {"b": pytest.approx(3.141592653)}
    assert "corefake" in sys.modules  # math.pi needed the import
    assert core_source.core_constant("corefake:LIMIT") == 3
    with pytest.raises(ValueError, match="module:name"):
        core_source.core_defaults("corefake")


def test_help_of_every_stage_loads_no_numba_opencv_or_pycolmap():
    stages = sorted(STAGES)
    found = _run(
        "import json, sys\n"
        "from click.testing import CliRunner\n"
        "from demtool.cli import cli\n"
        f"heavy = {HEAVY!r}\n"
        "first = {}\n"
        f"for stage in {stages!r}:\n"
        "    result = CliRunner().invoke(cli, [stage, '--help'])\n"
        "    assert result.exit_code == 0, (stage, result.output)\n"
        "    for name in heavy:\n"
        "        if name in sys.modules and name not in first:\n"
        "            first[name] = stage\n"
        "print(json.dumps(first))\n")
    assert found == {}, f"loaded by --help of: {found}"


LAZY = [("sgm", "sgm"), ("match", "match"), ("compare", "compare_dems"),
        ("dem", "dem_from_points"), ("bundle", "adjust_block"), ("refine", "refine_heights")]


@pytest.mark.parametrize("package, name", LAZY)
def test_core_packages_are_lazy(package, name):
    found = _run(
        "import json, sys\n"
        f"import demtool.{package} as pkg\n"
        f"before = [m for m in {HEAVY!r} if m in sys.modules]\n"
        f"value = getattr(pkg, {name!r})\n"
        f"print(json.dumps([before, callable(value), {name!r} in dir(pkg), "
        f"{name!r} in pkg.__all__]))\n")
    assert found == [[], True, True, True]
