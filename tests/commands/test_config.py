"""demtool.commands.config: preset values checked against the options' own click types."""

import math
from pathlib import Path

import click
import pytest

from demtool.cli import load_command
from demtool.commands import option_types as ot
from demtool.commands.config import check_preset_value, load_config, to_default_map
from demtool.errors import ParameterError

CONFIGS = sorted((Path(__file__).parents[2] / "configs").glob("*.toml"))

PARAMS = {
    "dem": [
        click.Option(["--median"], type=ot.IntRange(min=0), default=0),
        click.Option(["--gsd"], type=ot.POSITIVE),
        click.Option(["--mask-band"], is_flag=True),
        click.Option(["--align"], type=click.Choice(["none", "icp"])),
        click.Option(["--roi"], nargs=4, type=ot.FLOAT),
        click.Option(["--also"], multiple=True, type=click.Path()),
    ],
}


def _params(stage):
    return PARAMS.get(stage)


@pytest.mark.parametrize("key, value, problem", [
    ("median", [1, 2], "expected one integer, got a list"),
    ("median", {"a": 1}, "expected one integer, got a table"),
    ("median", True, "True is not a valid integer."),
    ("median", 2.5, "2.5 is not a valid integer."),
    ("median", -1, "-1 is not in the range x>=0."),
    ("gsd", math.inf, "inf is not a finite number."),
    ("gsd", math.nan, "nan is not a finite number."),
    ("gsd", "wide", "'wide' is not a valid float."),
    ("mask-band", 1, "expected true or false"),
    ("align", "fast", "'fast' is not one of 'none', 'icp'."),
    ("align", ["icp"], "expected one choice, got a list"),
    ("roi", [0, 0, 10], "Takes 4 values but 3 were given."),
    ("roi", [0, 0, 10, math.inf], "inf is not a finite number."),
    ("roi", "0 0 10 10", "expected a list of float values"),
    ("also", [["a"]], "expected path values, not tables or nested lists"),
])
def test_wrong_values_are_usage_errors_naming_file_section_and_key(key, value, problem):
    with pytest.raises(click.UsageError) as caught:
        to_default_map({"dem": {key: value}}, "presets/p.toml", _params)
    assert caught.value.message == f"preset presets/p.toml, [dem] {key} = {value!r}: {problem}"
    assert caught.value.exit_code == 2


def test_values_that_fit_pass_unchanged_into_the_default_map():
    preset = {"dem": {"median": 3, "gsd": 0.5, "mask-band": True, "align": "icp",
                      "roi": [0, 0, 10, 10], "also": ["a.tif", "b.tif"]}}
    default_map = to_default_map(preset, "p.toml", _params)
    assert default_map == {"dem": {"median": 3, "gsd": 0.5, "mask_band": True, "align": "icp",
                                   "roi": [0, 0, 10, 10], "also": ["a.tif", "b.tif"]}}
    param = PARAMS["dem"][4]
    assert check_preset_value("p.toml", "dem", "roi", [0, 0, 10, 10], param) == (0, 0, 10, 10)


def test_names_only_still_check_keys_and_sections():
    names = ["median", "gsd"]
    assert to_default_map({"dem": {"median": [1, 2]}}, "p.toml",
                          lambda s: names if s == "dem" else None) == {"dem": {"median": [1, 2]}}
    with pytest.raises(ParameterError, match=r"unknown key 'p3' in \[dem\]; valid keys: gsd, "
                                             r"median"):
        to_default_map({"dem": {"p3": 1}}, "p.toml", lambda s: names if s == "dem" else None)


@pytest.mark.parametrize("preset", CONFIGS, ids=[p.name for p in CONFIGS])
def test_every_shipped_preset_passes_the_type_check(preset):
    def stage_params(stage):
        return [p for p in load_command(stage).params if isinstance(p, click.Option)]

    content = load_config(preset)
    default_map = to_default_map(content, preset, stage_params)
    assert default_map  # every shipped preset sets something
