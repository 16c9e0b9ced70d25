"""The click group: help, version, config presets, error reporting."""

from pathlib import Path

import click
import pytest
from click.testing import CliRunner

import demtool
from demtool import __version__
from demtool.cli import STAGES, cli, stage_options
from demtool.commands.config import load_config, to_default_map
from demtool.errors import InputError, ParameterError

CONFIGS = sorted((Path(__file__).parent.parent / "configs").glob("*.toml"))


def test_help_lists_every_stage():
    result = CliRunner().invoke(cli, ["--help"])
    assert result.exit_code == 0
    for stage in ["synth", "select", "bundle", "rectify", "sgm", "match", "dem", "refine",
                  "compare"]:
        assert stage in result.output
    assert list(STAGES)[0] == "synth"


def test_version():
    from importlib.metadata import PackageNotFoundError, version

    try:
        installed = version("demtool")
    except PackageNotFoundError:  # a source tree that is not installed
        installed = "0.1.0"
    assert __version__ == installed
    result = CliRunner().invoke(cli, ["--version"])
    assert result.exit_code == 0 and result.output == f"demtool, version {installed}\n"
    with pytest.raises(AttributeError, match="no attribute 'version'"):
        demtool.version  # noqa: B018


def test_the_version_is_read_only_when_asked():
    import subprocess
    import sys

    code = ("import sys, demtool, demtool.cli\n"
            "before = 'importlib.metadata' in sys.modules\n"
            "print(before, demtool.__version__ == demtool.__dict__['__version__'])\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=120)
    assert out.stdout.split() == ["False", "True"]


@pytest.mark.parametrize("stage", list(STAGES))
def test_each_stage_has_help(stage):
    result = CliRunner().invoke(cli, [stage, "--help"])
    assert result.exit_code == 0
    assert STAGES[stage].split(":")[0] in " ".join(result.output.split())


def test_unknown_stage_is_a_usage_error():
    result = CliRunner().invoke(cli, ["stereo"])
    assert result.exit_code == 2


@pytest.mark.parametrize("preset", CONFIGS, ids=[p.name for p in CONFIGS])
def test_every_preset_names_real_options(preset):
    content = load_config(preset)
    default_map = to_default_map(content, preset, stage_options)
    assert set(default_map) <= set(STAGES)


def test_config_unknown_key_and_section_are_errors(tmp_path):
    def params(stage):
        return ["p1", "num_disparities"] if stage == "sgm" else None

    good = to_default_map({"sgm": {"p1": 8, "num-disparities": 64}}, "x.toml", params)
    assert good == {"sgm": {"p1": 8, "num_disparities": 64}}
    with pytest.raises(ParameterError, match=r"x\.toml: unknown key 'p3' in \[sgm\]; "
                                             r"valid keys: num-disparities, p1"):
        to_default_map({"sgm": {"p3": 1}}, "x.toml", params)
    with pytest.raises(ParameterError, match=r"unknown section \[stereo\]"):
        to_default_map({"stereo": {"p1": 1}}, "x.toml", params)


def test_config_errors_through_the_cli(tmp_path):
    runner = CliRunner()
    missing = runner.invoke(cli, ["--config", str(tmp_path / "none.toml"), "compare", "a.tif",
                                  "b.tif", "--out", str(tmp_path / "r")])
    assert missing.exit_code == 1
    assert "none.toml: config file not found" in missing.output
    bad = tmp_path / "bad.toml"
    bad.write_text("[sgm\n")
    result = runner.invoke(cli, ["--config", str(bad), "compare", "a.tif", "b.tif",
                                 "--out", str(tmp_path / "r")])
    assert result.exit_code == 1
    assert "bad.toml: config file is not valid TOML" in result.output
    unknown = tmp_path / "unknown.toml"
    unknown.write_text("[nosuchstage]\nx = 1\n")
    result = runner.invoke(cli, ["--config", str(unknown), "compare", "a.tif", "b.tif",
                                 "--out", str(tmp_path / "r")])
    assert result.exit_code == 1
    assert "unknown section [nosuchstage]" in result.output
    assert not (tmp_path / "r").exists()


def test_load_config_missing_file(tmp_path):
    with pytest.raises(InputError, match="config file not found"):
        load_config(tmp_path / "absent.toml")


@pytest.mark.parametrize("wrapper", [
    SystemError("returned a result with an exception set"),  # numba's dispatcher
    RuntimeError("cannot release un-acquired lock"),  # Ctrl-C in threading's Condition.wait
    None,  # the interrupt itself
])
def test_interrupt_inside_a_stage_is_reported_and_rolled_back(tmp_path, monkeypatch, wrapper):
    import numpy as np

    from demtool import io as dio

    @click.command(name="synth")
    def interrupted():
        with dio.output_transaction():
            dio.write_raster(tmp_path / "half.tif", np.zeros((4, 4)))
            try:
                raise KeyboardInterrupt("terminated by signal 15")
            except KeyboardInterrupt:
                if wrapper is None:
                    raise
                raise wrapper  # noqa: B904 - raised while handling it, as the libraries do

    monkeypatch.setattr("demtool.cli.load_command", lambda name: interrupted)
    result = CliRunner().invoke(cli, ["synth"])
    assert result.exit_code == 130
    assert "demtool synth: interrupted; no output written" in result.output
    assert list(tmp_path.iterdir()) == []


def test_an_error_that_is_no_interrupt_still_surfaces(monkeypatch):
    @click.command(name="synth")
    def failing():
        raise RuntimeError("a bug")

    monkeypatch.setattr("demtool.cli.load_command", lambda name: failing)
    result = CliRunner().invoke(cli, ["synth"])
    assert result.exit_code == 1 and isinstance(result.exception, RuntimeError)


def test_main_pauses_the_cycle_collector_only_for_the_imports(monkeypatch):
    """main() turns Python's gc off for the imports; the group callback freezes what they
    made and turns it back on, and it is on again however the command ends, with what is
    alive then frozen (the interpreter's shutdown collections skip it)."""
    import gc
    import signal
    import warnings

    from demtool.cli import main

    monkeypatch.setattr(warnings, "showwarning", warnings.showwarning)  # main reroutes it
    previous = signal.getsignal(signal.SIGTERM)
    seen = []
    original_freeze = gc.freeze

    def freeze():  # record whether it ran with gc on (after the group callback's)
        seen[-1].append(gc.isenabled())
        original_freeze()

    monkeypatch.setattr(gc, "freeze", freeze)
    try:
        for argv in (["--version"], ["--no-such-option"], ["sgm", "--no-such-option"],
                     ["warm", "--help"]):
            seen.append([])
            with pytest.raises(SystemExit):
                main(argv)
            seen[-1].append((gc.isenabled(), gc.get_freeze_count() > 0))
            gc.unfreeze()
    finally:
        gc.unfreeze()
        signal.signal(signal.SIGTERM, previous)
    # --version and the group's usage errors end before its callback: frozen only at the
    # end; a stage's command (its usage error here) also froze the imports, with gc off
    assert seen == [[True, (True, True)], [True, (True, True)],
                    [False, True, (True, True)], [False, True, (True, True)]]
