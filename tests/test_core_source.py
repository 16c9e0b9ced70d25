"""Core defaults read from source, lazy packages, and `demtool <stage> --help` without numba."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from demtool import core_source
from demtool.parameters import core_defaults as imported_defaults
from demtool.stages import STAGES

ROOT = Path(__file__).resolve().parents[1]

# libraries a stage loads only to do its work (scipy.sparse alone took 0.16 s of every
# command run with a preset naming [dem], before dem.grid imported its solver lazily)
HEAVY = ("numba", "cv2", "pycolmap", "scipy", "matplotlib")
REFS = ["demtool.sgm.matcher:sgm", "demtool.match.dense:match", "demtool.rectify.core:rectify_pair",
        "demtool.compare.core:compare_dems", "demtool.select.core:compare_with_target",
        "demtool.imaging.features:detect_sift", "demtool.dem.routes:OutlierOptions"]
CONSTANTS = ["demtool.sgm.disparity:SUBPIXEL_MODES", "demtool.sgm.matcher:CENSUS_WINDOWS",
             "demtool.sgm.matcher:COSTS", "demtool.compare.align:ALIGN_METHODS",
             "demtool.maps.projections:PROJECTIONS", "demtool.bundle.colmap:CAMERA_MODELS",
             "demtool.bundle.colmap:MATCHERS", "demtool.bundle.register:FEATURES"]


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


def test_dataclass_defaults_are_read_from_the_source(tmp_path, monkeypatch):
    """A plain dataclass's field defaults are its constructor's; a default_factory field has
    no value to read, and anything the source cannot say falls back to the import."""
    from demtool.bundle.colmap import SfmOptions

    static = core_source._static_defaults("demtool.bundle.colmap", "SfmOptions")
    real = dict(imported_defaults(SfmOptions))
    assert "extra" not in static and real.pop("extra") is not None  # field(default_factory=dict)
    assert static == real
    (tmp_path / "coredc.py").write_text(
        "import dataclasses\nfrom dataclasses import dataclass, field\n"
        "from typing import ClassVar\n"
        "N = 4\n"
        "@dataclass(frozen=True)\nclass A:\n    a: int\n    b: int = N\n"
        "    c: tuple = field(default=(1, 2))\n    d: list = field(default_factory=list)\n"
        "@dataclasses.dataclass(frozen=True)\nclass B(A):\n    e: int = 1\n"
        "@dataclass\nclass C:\n    k: ClassVar[int] = 3\n    f: int = 2\n"
        "@dataclass\nclass D:\n    g: float = float('inf')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "coredc", raising=False)
    assert dict(core_source.core_defaults("coredc:A")) == {"b": 4, "c": (1, 2)}
    assert "coredc" not in sys.modules
    for name in "BCD":  # a base class, a ClassVar, a call: from the import
        with pytest.raises(core_source._NotStatic):
            core_source._static_defaults("coredc", name)
    assert dict(core_source.core_defaults("coredc:C")) == {"f": 2}
    assert dict(core_source.core_defaults("coredc:D")) == {"g": float("inf")}


def test_source_reads_import_no_package():
    """Reading ``demtool.maps.projections`` does not run ``demtool.maps``'s ``__init__``
    (``importlib.util.find_spec`` would import the parent package)."""
    found = _run(
        "import json, sys\n"
        "from demtool.core_source import core_constant\n"
        "value = core_constant('demtool.maps.projections:PROJECTIONS')\n"
        "print(json.dumps([value, sorted(m for m in sys.modules if m.startswith('demtool.'))]))\n")
    assert found[0] == ["auto", "equirectangular", "polar-stereographic"]
    assert not [m for m in found[1] if m.startswith("demtool.maps")]


# what checking a preset may import besides each named stage's command, package and params
PRESET_MODULES = {"demtool.core_source", "demtool.lazy", "demtool.parameters",
                  "demtool.imaging", "demtool.imaging.reflectance"}  # refine's model names


def test_presets_import_only_the_parameter_modules():
    """Every command run with ``--config`` checks the preset's sections against each named
    stage's parameters: those modules read their cores' defaults from source and import no
    core, sensor, map or tiling module (about 0.3 CPU s of every demo step otherwise)."""
    presets = sorted(str(p) for p in (ROOT / "configs").glob("*.toml"))
    found = _run(
        "import json, sys\n"
        "from click.testing import CliRunner\n"
        "from demtool.cli import cli\n"
        "assert CliRunner().invoke(cli, ['pairs', '--help']).exit_code == 0\n"
        "before = set(sys.modules)\n"
        "found = {}\n"
        f"for preset in {presets!r}:\n"
        "    result = CliRunner().invoke(cli, ['--config', preset, 'pairs', '--help'])\n"
        "    assert result.exit_code == 0, (preset, result.output)\n"
        "    found[preset] = sorted(m for m in set(sys.modules) - before\n"
        "                           if m.startswith('demtool.'))\n"
        "print(json.dumps(found))\n")
    allowed = set(PRESET_MODULES)
    for stage in STAGES:
        allowed |= {f"demtool.commands.{stage}", f"demtool.{stage}", f"demtool.{stage}.params"}
    assert {preset: sorted(set(mods) - allowed) for preset, mods in found.items()} == {
        preset: [] for preset in found}
    assert any("demtool.sgm.params" in mods for mods in found.values())


def test_help_of_every_stage_and_every_preset_loads_no_heavy_library():
    """``--help``, and the check of a preset's sections against every stage's options
    (which every command run with ``--config`` makes), load none of :data:`HEAVY`."""
    stages = sorted(STAGES)
    presets = sorted(str(p) for p in (ROOT / "configs").glob("*.toml"))
    assert presets
    found = _run(
        "import json, sys\n"
        "from click.testing import CliRunner\n"
        "from demtool.cli import cli\n"
        f"heavy = {HEAVY!r}\n"
        "first = {}\n"
        f"runs = [[stage, '--help'] for stage in {stages!r}]\n"
        f"runs += [['--config', preset, 'pairs', '--help'] for preset in {presets!r}]\n"
        "for stage in runs:\n"
        "    result = CliRunner().invoke(cli, stage)\n"
        "    assert result.exit_code == 0, (stage, result.output)\n"
        "    for name in heavy:\n"
        "        if name in sys.modules and name not in first:\n"
        "            first[name] = ' '.join(stage)\n"
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
