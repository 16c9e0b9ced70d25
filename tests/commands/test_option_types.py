"""demtool.commands.option_types: finite numbers, ranges, and messages that name the preset."""

import json
import math

import click
import pytest
from click.testing import CliRunner

from demtool.cli import cli
from demtool.commands import option_types as ot
from demtool.stages import STAGES


class _State:
    config_path = "presets/p.toml"


def _command(default_map=None):
    @click.group()
    @click.pass_context
    def group(ctx):
        ctx.obj = _State()
        ctx.default_map = default_map or {}

    @group.command("dem")
    @click.option("--median", type=ot.IntRange(min=0), default=0)
    @click.option("--gsd", type=ot.POSITIVE, default=1.0)
    @click.option("--azimuth", type=ot.FLOAT, default=0.0)
    @click.option("--fraction", type=ot.FloatRange(0.0, 1.0, max_open=True), default=0.5)
    @click.option("--limit", type=ot.FloatRange(min=0.0, allow_inf=True), default=1.0)
    @click.option("--level", type=ot.FloatRange(allow_nan=True), default=0.0)
    def dem(**values):
        click.echo(json.dumps(values))

    return group


def _run(args, default_map=None):
    result = CliRunner().invoke(_command(default_map), ["dem", *args])
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    return result, errors


@pytest.mark.parametrize("args, message", [
    (["--gsd", "inf"], "Invalid value for '--gsd': 'inf' is not a finite number."),
    (["--gsd", "-inf"], "Invalid value for '--gsd': '-inf' is not a finite number."),
    (["--azimuth", "nan"], "Invalid value for '--azimuth': 'nan' is not a finite number."),
    (["--azimuth", "NaN"], "Invalid value for '--azimuth': 'NaN' is not a finite number."),
    (["--gsd", "0"], "Invalid value for '--gsd': 0.0 is not in the range x>0.0."),
    (["--gsd", "-1"], "Invalid value for '--gsd': -1.0 is not in the range x>0.0."),
    (["--fraction", "1"], "Invalid value for '--fraction': 1.0 is not in the range 0.0<=x<1.0."),
    (["--fraction", "nan"], "Invalid value for '--fraction': 'nan' is not a finite number."),
    (["--gsd", "abc"], "Invalid value for '--gsd': 'abc' is not a valid float."),
    (["--median", "2.5"], "Invalid value for '--median': '2.5' is not a valid integer."),
    (["--median", "-1"], "Invalid value for '--median': -1 is not in the range x>=0."),
    (["--median", "nan"], "Invalid value for '--median': 'nan' is not a valid integer."),
    (["--limit", "nan"], "Invalid value for '--limit': 'nan' is not a finite number."),
    (["--limit", "-inf"], "Invalid value for '--limit': -inf is not in the range x>=0.0."),
])
def test_command_line_values_are_refused_in_clicks_words(args, message):
    result, errors = _run(args)
    assert result.exit_code == 2
    assert errors == [f"Error: {message}"]
    assert "Traceback" not in result.output


def test_good_values_and_the_allowed_non_finite_ones_pass():
    result, _ = _run(["--gsd", "0.25", "--median", "3", "--azimuth", "-30",
                      "--fraction", "0", "--limit", "inf", "--level", "nan"])
    assert result.exit_code == 0, result.output
    values = json.loads(result.output)
    assert values["gsd"] == 0.25 and values["median"] == 3 and values["azimuth"] == -30.0
    assert values["limit"] == math.inf and math.isnan(values["level"])
    assert isinstance(values["median"], int)


@pytest.mark.parametrize("preset, message", [
    ({"median": [1, 2]}, "Invalid value for '--median': preset presets/p.toml, [dem] median: "
                         "[1, 2] is not a valid integer."),
    ({"median": True}, "Invalid value for '--median': preset presets/p.toml, [dem] median: "
                       "True is not a valid integer."),
    ({"median": 3.7}, "Invalid value for '--median': preset presets/p.toml, [dem] median: "
                      "3.7 is not a valid integer."),
    ({"gsd": math.inf}, "Invalid value for '--gsd': preset presets/p.toml, [dem] gsd: "
                        "inf is not a finite number."),
    ({"gsd": "fast"}, "Invalid value for '--gsd': preset presets/p.toml, [dem] gsd: "
                      "'fast' is not a valid float."),
    ({"gsd": -2}, "Invalid value for '--gsd': preset presets/p.toml, [dem] gsd: "
                  "-2.0 is not in the range x>0.0."),
    ({"azimuth": {"a": 1}}, "Invalid value for '--azimuth': preset presets/p.toml, [dem] "
                            "azimuth: {'a': 1} is not a valid float."),
])
def test_preset_values_are_refused_naming_file_section_and_key(preset, message):
    result, errors = _run([], {"dem": preset})
    assert result.exit_code == 2, result.output
    assert errors == [f"Error: {message}"]
    assert "Traceback" not in result.output


def test_preset_values_that_fit_are_converted_and_the_command_line_wins():
    result, _ = _run(["--gsd", "2"], {"dem": {"median": 5.0, "gsd": 1, "azimuth": "12.5"}})
    assert result.exit_code == 0, result.output
    values = json.loads(result.output)
    assert values["median"] == 5 and isinstance(values["median"], int)
    assert values["gsd"] == 2.0 and values["azimuth"] == 12.5


def test_help_still_shows_the_ranges():
    result = CliRunner().invoke(_command(), ["dem", "--help"])
    assert "x>0.0" in result.output and "0.0<=x<1.0" in result.output


def test_types_used_directly_reject_non_numbers():
    with pytest.raises(click.BadParameter, match="is not a valid float"):
        ot.FLOAT.convert(None, None, None)
    with pytest.raises(click.BadParameter, match="is not a finite number"):
        ot.POSITIVE.convert(float("inf"), None, None)
    assert ot.INT.convert("  7 ", None, None) == 7
    assert ot.FRACTION.convert(1, None, None) == 1.0


@pytest.mark.parametrize("stage", list(STAGES))
def test_help_shows_no_range_for_unbounded_numbers(stage):
    """Unbounded numbers (--seed, --min-disparity, --height) show no ``x<=None``."""
    result = CliRunner().invoke(cli, [stage, "--help"], terminal_width=200)
    assert result.exit_code == 0, result.output
    assert "None]" not in result.output and "x<=None" not in result.output
