"""The click options generated from parameter dataclasses (demtool.commands.options)."""

import dataclasses

import click
import pytest
from click.testing import CliRunner

from demtool.cli import load_command
from demtool.commands import option_types, options
from demtool.parameters import Parameters, option_name, parameter
from demtool.stages import STAGES
from tests.test_parameters import stage_class


@dataclasses.dataclass(frozen=True)
class Toy(Parameters):
    size: int = parameter(8, "Size in px.", option="width", minimum=1)
    fraction: float = parameter(0.5, "Fraction.", minimum=0.0, maximum=1.0, max_open=True)
    window: int = parameter(3, "Window.", minimum=0, odd=True)
    mode: str = parameter("a", "Mode.", choices=("a", "b"))
    paths: int = parameter(8, "Paths.", choices=(8, 16))
    limit: float | None = parameter(None, "Optional limit.")
    fast: bool = parameter(True, "Go fast.")
    rank: bool = parameter(False, "Rank.", flag="--rank")
    hidden: float = parameter(1.0, "Not an option.", cli=False)


@click.command()
@options.parameter_options(Toy)
def toy_command(**values):
    click.echo(repr(Toy.from_options(values)))


def run(*args):
    return CliRunner().invoke(toy_command, list(args))


def test_defaults_and_values_reach_the_dataclass():
    assert run().output.strip() == repr(Toy())
    result = run("--width", "3", "--fraction", "0.25", "--mode", "b", "--paths", "16",
                 "--limit", "2.5", "--no-fast", "--rank")
    assert result.output.strip() == repr(Toy(size=3, fraction=0.25, mode="b", paths=16,
                                             limit=2.5, fast=False, rank=True))


@pytest.mark.parametrize("args, message", [
    (["--width", "0"], "--width"), (["--fraction", "1"], "--fraction"),
    (["--window", "4"], "must be odd"), (["--mode", "c"], "'c' is not one of"),
    (["--paths", "10"], "--paths"), (["--hidden", "2"], "No such option"),
])
def test_bad_values_are_usage_errors(args, message):
    result = run(*args)
    assert result.exit_code == 2 and message in result.output


def test_option_type_for_ranges_and_choices():
    fields = {f.name: f for f in dataclasses.fields(Toy)}
    width = options.option_type_for(fields["size"], int)
    assert isinstance(width, click.IntRange) and width.min == 1
    fraction = options.option_type_for(fields["fraction"], float)
    assert isinstance(fraction, click.FloatRange) and fraction.max_open
    assert isinstance(options.option_type_for(fields["mode"], str), click.Choice)
    limit = options.option_type_for(fields["limit"], float)
    assert limit is option_types.FLOAT
    with pytest.raises(click.BadParameter, match="not a finite number"):
        limit.convert("nan", None, None)


def test_help_shows_defaults_and_help_text():
    result = run("--help")
    assert "Size in px." in result.output and "[default: 8" in result.output
    assert "--hidden" not in result.output and "--fast / --no-fast" in result.output


@pytest.mark.parametrize("stage", list(STAGES))
def test_every_parameter_field_is_an_option_of_its_command(stage):
    cls = stage_class(stage)
    command = load_command(stage)
    by_name = {p.name: p for p in command.params}
    for field in dataclasses.fields(cls):
        if not field.metadata["cli"]:
            continue
        param = by_name[option_name(field)]
        assert param.default == field.default, (stage, field.name)
        assert (param.help or "").startswith(field.metadata["help"][:20])
