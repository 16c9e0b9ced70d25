"""TOML presets (``configs/*.toml``): one section per stage, keys are option names.

A preset becomes click's ``default_map``, so an option given on the command line
always overrides the preset.  Unknown sections and keys are errors that list the
valid ones.  Values are checked against the option's own click type (the same
types the command line uses, :mod:`demtool.commands.option_types` for numbers) when the
stages' parameters are given, so ``median = [1, 2]`` or ``gsd = inf`` is a usage
error naming the file, the section and the key, not a ``TypeError`` later.
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import click

from demtool.errors import InputError, ParameterError


def load_config(path: str | os.PathLike) -> dict[str, dict[str, Any]]:
    """Read a TOML preset; InputError naming the file if it is missing or malformed."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: config file not found")
    try:
        with open(p, "rb") as handle:
            content = tomllib.load(handle)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: config file is not valid TOML ({exc})") from None
    return content


def check_preset_value(path: str | os.PathLike, section: str, key: str, value: Any,
                       param: click.Parameter) -> Any:
    """Convert a preset value with the option's click type; a usage error if it does not fit.

    Parameters
    ----------
    path : path-like
        The preset file, for the message.
    section, key : str
        Where the value is in the file (``[dem]``, ``median``).
    value : any
        The TOML value.
    param : click.Parameter
        The stage's option of that name.

    Returns
    -------
    The converted value (what the command would receive).

    Raises
    ------
    click.UsageError
        ``"preset PATH, [section] key = value: problem"`` (exit status 2).
    """
    def refuse(problem: str) -> click.UsageError:
        return click.UsageError(f"preset {path}, [{section}] {key} = {value!r}: {problem}")

    is_flag = isinstance(param, click.Option) and param.is_flag
    if is_flag and not isinstance(value, bool):
        raise refuse("expected true or false")
    several = param.multiple or param.nargs != 1
    if not several and isinstance(value, (list, tuple, Mapping)):
        raise refuse(f"expected one {param.type.name}, got a "
                     f"{'table' if isinstance(value, Mapping) else 'list'}")
    if several and isinstance(value, (str, Mapping)) or (
            several and not isinstance(value, Sequence)):
        raise refuse(f"expected a list of {param.type.name} values")
    if isinstance(value, Mapping) or (several and any(isinstance(v, (list, Mapping))
                                                      for v in value)):
        raise refuse(f"expected {param.type.name} values, not tables or nested lists")
    ctx = click.Context(click.Command(section), info_name=section)
    try:
        return param.type_cast_value(ctx, value)
    except click.BadParameter as exc:
        raise refuse(exc.message) from None
    except (TypeError, ValueError) as exc:
        raise refuse(f"not a valid {param.type.name} ({exc})") from None


def to_default_map(content: Mapping[str, Any], path: str | os.PathLike,
                   stage_params: Callable[[str], Sequence[str | click.Parameter] | None]
                   ) -> dict[str, dict[str, Any]]:
    """Check a preset against the stages' options and convert it to click's default_map.

    Parameters
    ----------
    content : mapping
        The parsed TOML (top-level table ``[study]`` with metadata is allowed).
    path : path-like
        The file, for messages.
    stage_params : callable
        Returns the options of a stage — their click Parameters (then every value is
        checked with :func:`check_preset_value`) or just their underscored names — or
        None for an unknown stage.

    Raises
    ------
    ParameterError
        An unknown section or key, or a section that is not a table.
    click.UsageError
        A value of the wrong type or out of range (exit status 2).
    """
    default_map: dict[str, dict[str, Any]] = {}
    for section, values in content.items():
        if section == "study":  # free-form description of the preset's origin
            continue
        params = stage_params(section)
        if params is None:
            raise ParameterError(f"{path}: unknown section [{section}]; sections are stage names")
        if not isinstance(values, Mapping):
            raise ParameterError(f"{path}: [{section}] must be a table of option = value")
        by_name: dict[str, click.Parameter | None] = {
            (p.name if isinstance(p, click.Parameter) else p): (
                p if isinstance(p, click.Parameter) else None) for p in params}
        section_map: dict[str, Any] = {}
        for key, value in values.items():
            name = key.replace("-", "_")
            if name not in by_name:
                raise ParameterError(
                    f"{path}: unknown key '{key}' in [{section}]; valid keys: "
                    + ", ".join(sorted(n.replace("_", "-") for n in by_name if n)))
            param = by_name[name]
            if param is not None:
                check_preset_value(path, section, key, value, param)
            section_map[name] = value
        default_map[section] = section_map
    return default_map
