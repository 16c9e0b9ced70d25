"""Options shared by the stages, and the click options of a parameter dataclass.

The CLI layer (with :mod:`demtool.cli` and :mod:`demtool.commands`): the only modules
of demtool that import click.  :func:`parameter_options` turns the fields of a stage's
parameter dataclass (:mod:`demtool.parameters`) into click options, so that every
default, range, choice and help text is written once, in the dataclass.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import click

from demtool.commands import option_types
from demtool.parameters import option_name, value_kind


def out_file(help_text: str = "Output file.") -> click.decorators.FC:
    """``--out PATH`` (required): the stage's main output file.  A folder given here is a
    file problem (exit 1), refused by the runner's ``StageRun`` in one line."""
    return click.option("--out", "out", required=True, type=click.Path(), help=help_text)


def out_dir(help_text: str = "Output folder (created if needed).") -> click.decorators.FC:
    """``--out DIR`` (required): the folder the stage writes into (a file given here is
    refused by the runner's ``StageRun``, exit 1)."""
    return click.option("--out", "out", required=True, type=click.Path(), help=help_text)


def input_file(name: str, **kwargs) -> click.decorators.FC:
    """A positional input file; existence is checked by the runner (one clear message)."""
    return click.argument(name, type=click.Path(dir_okay=False), **kwargs)


def sensor_models() -> click.decorators.FC:
    """``MODEL...``: one or more sensor model files (the block of `camera` and `pairs`)."""
    return click.argument("models", nargs=-1, required=True, type=click.Path(dir_okay=False),
                          metavar="MODEL...")


def json_report_option() -> click.decorators.FC:
    """``--json``: print the JSON report on stdout instead of the table (``as_json``)."""
    return click.option("--json", "as_json", is_flag=True,
                        help="Print the JSON report on stdout instead of the table.")


def path_option(flag: str, help_text: str, **kwargs) -> click.decorators.FC:
    """A file option (``--rectify PATH``), optional unless ``required=True``; the runner
    checks it.  A required one gets no default: click ≥ 8.3 takes an explicit
    ``default=None`` as a value given, and would let a missing option through."""
    if not kwargs.get("required"):
        kwargs.setdefault("default", None)
    return click.option(flag, type=click.Path(dir_okay=False), help=help_text, **kwargs)


def _vector(ctx: click.Context, param: click.Parameter, value: str | None):
    if value is None:
        return None
    try:
        parts = tuple(float(v) for v in value.split(","))
    except ValueError:
        parts = ()
    if len(parts) != 3 or not all(abs(v) < float("inf") for v in parts):
        raise click.BadParameter(f"expected three numbers x,y,z, got {value!r}")
    if not any(parts):
        raise click.BadParameter("the vector has zero length")
    return parts


def vector_option(*declarations: str, help_text: str) -> click.decorators.FC:
    """An optional direction ``X,Y,Z`` (three finite numbers, not all zero)."""
    return click.option(*declarations, callback=_vector, default=None, metavar="X,Y,Z",
                        help=help_text)


def exclusive(given: dict[str, bool], *, exactly_one: bool = False) -> None:
    """BadParameter (exit 2) when more than one of the options in ``given`` is set.

    ``given`` maps an option's flag (``"--points"``) to whether it was set; with
    ``exactly_one``, none set is an error too.
    """
    chosen = [flag for flag, present in given.items() if present]
    if len(chosen) > 1 or (exactly_one and not chosen):
        flags = " or ".join(given)
        raise click.BadParameter(f"give {'exactly one' if exactly_one else 'either'} of "
                                 f"{flags}" + ("" if exactly_one else ", not both"),
                                 param_hint="/".join(given))


def parse_numbers(text: str, count: int | None, what: str) -> tuple[float, ...]:
    """Comma-separated finite numbers (``count`` of them when given), else BadParameter."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise click.BadParameter(f"{text!r}: {what} must be comma-separated numbers") from None
    if count is not None and len(values) != count:
        raise click.BadParameter(f"{text!r}: {what} needs {count} numbers, got {len(values)}")
    if not all(v == v and abs(v) != float("inf") for v in values):
        raise click.BadParameter(f"{text!r}: {what} must be finite numbers")
    return values


def resolved_params(ctx: click.Context) -> dict:
    """The command's parameters after config preset and command line (for provenance)."""
    return dict(ctx.params)


def given_on_command_line(ctx: click.Context, name: str) -> bool:
    """True when option ``name`` was set on the command line (or its environment variable)."""
    from click.core import ParameterSource

    return ctx.get_parameter_source(name) in (ParameterSource.COMMANDLINE,
                                              ParameterSource.ENVIRONMENT)


# --------------------------------------------------------------------------------------
# Parameter dataclass -> click options
# --------------------------------------------------------------------------------------


def option_type_for(field: dataclasses.Field, kind: type) -> Any:
    """The click type of a parameter field: its choices, or its numeric range.

    Every numeric option built from a parameter dataclass gets its type here (one place
    to switch them to stricter types, e.g. ones that reject NaN and ±inf).
    """
    meta = field.metadata
    if meta.get("choices") is not None:
        return click.Choice(meta["choices"])
    if kind not in (int, float):
        return kind
    bounds = {"min": meta.get("minimum"), "max": meta.get("maximum"),
              "min_open": meta.get("min_open", False), "max_open": meta.get("max_open", False)}
    if bounds["min"] is None and bounds["max"] is None:
        return option_types.INT if kind is int else option_types.FLOAT
    if kind is int:
        # open bounds are supported too; keep integral bounds integral
        bounds["min"] = None if bounds["min"] is None else int(bounds["min"])
        bounds["max"] = None if bounds["max"] is None else int(bounds["max"])
        return option_types.IntRange(**bounds)
    return option_types.FloatRange(**bounds)


def _odd_callback(ctx: click.Context, param: click.Parameter, value: Any) -> Any:
    if value is not None and value > 1 and value % 2 == 0:
        raise click.BadParameter(f"must be odd, got {value}")
    return value


def _check_callback(check: Callable[[Any], str | None]) -> Callable:
    """A click callback refusing a value a field's ``check`` finds a problem with."""
    def callback(ctx: click.Context, param: click.Parameter, value: Any) -> Any:
        if value is not None and (problem := check(value)):
            raise click.BadParameter(problem)
        return value

    return callback


def field_option(cls: type, field: dataclasses.Field) -> Callable:
    """The click option of one parameter field (default, range, choices and help from it)."""
    meta = field.metadata
    kind = value_kind(cls, field)
    name = option_name(field)
    flag = "--" + name.replace("_", "-")
    kwargs: dict[str, Any] = {"default": field.default, "help": meta["help"],
                              "show_default": field.default is not None}
    if kind is bool:
        declaration = meta.get("flag") or f"{flag}/--no-{flag[2:]}"
        if "/" not in declaration:
            kwargs.update(is_flag=True, show_default=False)
        return click.option(declaration, name, **kwargs)
    if meta.get("metavar"):
        kwargs["metavar"] = meta["metavar"]
    if meta.get("odd"):
        kwargs["callback"] = _odd_callback
    if meta.get("check") is not None:
        kwargs["callback"] = _check_callback(meta["check"])
    return click.option(flag, name, type=option_type_for(field, kind), **kwargs)


def parameter_options(cls: type, *, exclude: tuple[str, ...] = ()) -> Callable:
    """Decorator adding the options of every field of ``cls`` (in field order)."""
    chosen = [f for f in dataclasses.fields(cls)
              if f.metadata.get("cli", True) and "help" in f.metadata and f.name not in exclude]

    def decorate(function: Callable) -> Callable:
        for field in reversed(chosen):
            function = field_option(cls, field)(function)
        return function

    return decorate

