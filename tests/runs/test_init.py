"""The runner tier: StageRun's file checks, the frame check, and no click below the CLI."""

import ast
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from demtool.errors import InputError, ParameterError
from demtool.runs import StageRun, check_same_frame
from demtool.sgm.params import SgmParams
from demtool.stages import STAGES

PACKAGE = Path(__file__).resolve().parents[2] / "demtool"
CLI_LAYER = {"cli.py", "options.py", "option_types.py", "config.py", "commands"}


def test_stage_run_declares_files_and_builds_provenance(tmp_path):
    (tmp_path / "a.tif").write_bytes(b"a")
    run = StageRun("sgm", SgmParams(), resolved={"cost": "hmi"},
                   inputs={"LEFT": tmp_path / "a.tif", "--rectify": None,
                           "--also": [tmp_path / "b", tmp_path / "c"]},
                   outputs={"--out": tmp_path / "d.tif", "--confidence": None})
    assert run.log.name == "demtool.sgm"
    assert run.input_paths() == [tmp_path / "a.tif", tmp_path / "b", tmp_path / "c"]
    assert run.provenance.stage == "sgm" and run.provenance.params == {"cost": "hmi"}
    assert run.provenance.inputs == run.input_paths()


def test_stage_run_refuses_clashing_or_misplaced_outputs(tmp_path):
    (tmp_path / "x").mkdir()
    with pytest.raises(InputError, match=r"d\.tif: --out and --confidence name the same file"):
        StageRun("sgm", SgmParams(), outputs={"--out": tmp_path / "d.tif",
                                     "--confidence": tmp_path / "x" / ".." / "d.tif"})
    with pytest.raises(InputError, match="--out is a folder, expected a file name"):
        StageRun("sgm", SgmParams(), outputs={"--out": tmp_path})
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="--out is a file, expected a folder"):
        StageRun("sgm", SgmParams(), folders={"--out": tmp_path / "file"})
    with pytest.raises(InputError, match=r"a\.tif: --out would overwrite the input LEFT .*a\.tif"):
        StageRun("sgm", SgmParams(), inputs={"LEFT": tmp_path / "file" / ".." / "a.tif"},
                 outputs={"--out": [tmp_path / "b.tif", tmp_path / "a.tif"]})
    with pytest.raises(InputError,
                       match=r"d\.tif: cannot write the output: .*file is a file, not a folder"):
        StageRun("sgm", SgmParams(), outputs={"--out": tmp_path / "file" / "d.tif"})
    with pytest.raises(ParameterError, match="--median must be odd"):
        StageRun("sgm", SgmParams(median=4))
    with pytest.raises(KeyError):
        StageRun("stereo", SgmParams())


def test_stage_run_transaction_uses_the_declaration(tmp_path, monkeypatch):
    from demtool import io as dio
    from demtool.outputs import CHECK_DECLARED_ENV
    from demtool.runs import sidecar_path

    monkeypatch.setenv(CHECK_DECLARED_ENV, "1")
    (tmp_path / "a.tif").write_bytes(b"a")
    out = tmp_path / "d.tif"
    run = StageRun("sgm", SgmParams(), inputs={"LEFT": tmp_path / "a.tif"},
                   outputs={"--out": out, "sidecar": sidecar_path(out)})
    assert sidecar_path(out) == tmp_path / "d.tif.json"
    assert run.output_paths() == [out, tmp_path / "d.tif.json"]
    with run.transaction():
        dio.write_json(out, {})
        run.provenance.write_sidecar(out, {})
    assert out.exists() and sidecar_path(out).exists()
    with pytest.raises(InputError, match=r"other\.tif: written but not declared"), \
            run.transaction():
        dio.write_json(tmp_path / "other.tif", {})
    with pytest.raises(InputError, match="would overwrite the input LEFT"), run.transaction():
        dio.write_json(tmp_path / "a.tif", {})
    assert (tmp_path / "a.tif").read_bytes() == b"a"


def test_check_same_frame():
    def raster(frame, crs=None):
        return SimpleNamespace(path=f"{frame}.tif", crs=crs, tags={"frame": frame} if frame
                               else {})

    check_same_frame(raster("image:a"), raster("image:a"), "hint")
    check_same_frame(raster(None), raster("image:a"), "hint")
    check_same_frame(raster("image:b", crs="EPSG:4326"), raster("image:a"), "hint")
    with pytest.raises(InputError, match=r"image:b\.tif: is in frame 'image:b' but the DEM "
                                         r"image:a\.tif is in frame 'image:a'; hint"):
        check_same_frame(raster("image:b"), raster("image:a"), "hint", "the DEM")


def _imports_click(path: Path) -> bool:
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Import) and any(a.name.split(".")[0] == "click"
                                                for a in node.names):
            return True
        if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "click":
            return True
    return False


def test_no_module_outside_the_cli_layer_imports_click():
    offenders = [str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("*.py")
                 if p.relative_to(PACKAGE).parts[0] not in CLI_LAYER and _imports_click(p)]
    assert offenders == []


def _runner_module(stage: str) -> str:
    """``demtool.<stage>.run`` in the package-per-stage layout, else ``demtool.runs.<stage>``."""
    if (PACKAGE / stage / "run.py").is_file():
        return f"demtool.{stage}.run"
    return f"demtool.runs.{stage}"


def test_runners_and_parameters_load_without_click():
    modules = [_runner_module(stage) for stage in STAGES] + [
        "demtool.runs.scene", "demtool.stages", "demtool.parameters"]
    code = ("import importlib, sys\n"
            f"for name in {modules!r}:\n"
            "    importlib.import_module(name)\n"
            "import demtool.runs.refine as r\n"
            "from demtool.refine.params import RefineParams\n"
            "RefineParams().check()\n"
            "print('click' in sys.modules)\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            check=True)
    assert result.stdout.strip() == "False"


@pytest.mark.parametrize("stage", list(STAGES))
def test_commands_are_thin(stage):
    lines = (PACKAGE / "commands" / f"{stage}.py").read_text().splitlines()
    assert len(lines) <= 120
