"""Parameter dataclasses: ranges, choices and odd windows checked, options named."""

import dataclasses
import importlib

import pytest

from demtool.errors import ParameterError
from demtool.parameters import Parameters, core_default, describe_range, parameter

# every stage's parameter dataclass (module, class)
STAGE_PARAMETERS = {
    "synth": ("demtool.synth.params", "SceneParams"),
    "select": ("demtool.select.params", "SelectParams"),
    "bundle": ("demtool.bundle.params", "BundleParams"),
    "rectify": ("demtool.rectify.params", "RectifyParams"),
    "sgm": ("demtool.sgm.params", "SgmParams"),
    "match": ("demtool.match.params", "MatchParams"),
    "dem": ("demtool.dem.params", "DemParams"),
    "refine": ("demtool.refine.params", "RefineParams"),
    "mapproject": ("demtool.mapproject.params", "MapprojectParams"),
    "compare": ("demtool.compare.params", "CompareParams"),
    "camera": ("demtool.camera.params", "CameraParams"),
    "pairs": ("demtool.pairs.params", "PairsParams"),
    "fuse": ("demtool.fuse.params", "FuseParams"),
}


def stage_class(stage: str) -> type:
    module, name = STAGE_PARAMETERS[stage]
    return getattr(importlib.import_module(module), name)


@dataclasses.dataclass(frozen=True)
class Toy(Parameters):
    size: int = parameter(8, "Size.", option="width", minimum=1)
    fraction: float = parameter(0.5, "Fraction.", minimum=0.0, maximum=1.0, max_open=True)
    window: int = parameter(3, "Window.", minimum=0, odd=True)
    mode: str = parameter("a", "Mode.", choices=("a", "b"), what="mode")
    hidden: float = parameter(1.0, "Not an option.", minimum=0.0, min_open=True, cli=False)


def test_defaults_pass_and_each_bad_field_is_named_by_its_option():
    Toy().check()
    cases = [({"size": 0}, "--width must be >= 1, got 0"),
             ({"fraction": 1.0}, "--fraction must be in [0, 1), got 1"),
             ({"fraction": float("nan")}, "--fraction must be a finite number, got nan"),
             ({"window": 4}, "--window must be odd, got 4"),
             ({"mode": "c"}, "--mode: unknown mode 'c': should be one of a, b"),
             ({"hidden": 0.0}, "--hidden must be > 0, got 0")]
    for change, message in cases:
        with pytest.raises(ParameterError) as info:
            Toy(**change).check()
        assert str(info.value) == message


def test_frozen_as_dict_and_from_options():
    toy = Toy.from_options({"width": 4, "mode": "b", "unrelated": 1})
    assert (toy.size, toy.mode, toy.fraction) == (4, "b", 0.5)
    assert toy.as_dict() == {"size": 4, "fraction": 0.5, "window": 3, "mode": "b",
                             "hidden": 1.0}
    with pytest.raises(dataclasses.FrozenInstanceError):
        toy.size = 3  # type: ignore[misc]
    assert Toy.label("size") == "--width" and Toy.label("fraction") == "--fraction"


def test_describe_range_and_core_default():
    assert describe_range({"minimum": 0, "maximum": 1, "min_open": True,
                           "max_open": False}) == "in (0, 1]"
    assert describe_range({"minimum": None, "maximum": 5, "min_open": False,
                           "max_open": True}) == "< 5"

    def core(x, *, window=7):
        return x

    assert core_default(core, "window") == 7
    with pytest.raises(TypeError, match="no default"):
        core_default(core, "x")


@pytest.mark.parametrize("stage", list(STAGE_PARAMETERS))
def test_every_stage_default_is_valid_and_every_field_documented(stage):
    cls = stage_class(stage)
    cls().check()
    for field in dataclasses.fields(cls):
        assert field.metadata["help"].strip(), f"{cls.__name__}.{field.name} has no help"


def test_core_defaults_are_the_stage_defaults():
    """The stage parameters read their defaults from the core (written once)."""
    from demtool.compare import compare_dems
    from demtool.match import match
    from demtool.rectify.core import rectify_pair
    from demtool.refine.prepare import prepare_dem
    from demtool.sgm import sgm

    assert stage_class("sgm")().cost == core_default(sgm, "cost")
    assert stage_class("sgm")().median == core_default(sgm, "median")
    assert stage_class("match")().template == core_default(match, "template")
    assert stage_class("rectify")().ratio == core_default(rectify_pair, "ratio")
    assert stage_class("compare")().align == core_default(compare_dems, "align")
    assert stage_class("refine")().median == core_default(prepare_dem, "median_size")
