"""TOML presets (``configs/*.toml``): one section per stage, keys are option names.

A preset becomes click's ``default_map``, so an option given on the command line
always overrides the preset.  Unknown sections and keys are errors that list the
valid ones.
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

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


def to_default_map(content: Mapping[str, Any], path: str | os.PathLike,
                   stage_params: Callable[[str], list[str] | None]) -> dict[str, dict[str, Any]]:
    """Check a preset against the stages' options and convert it to click's default_map.

    Parameters
    ----------
    content : mapping
        The parsed TOML (top-level table ``[study]`` with metadata is allowed).
    path : path-like
        The file, for messages.
    stage_params : callable
        Returns the option names of a stage (underscored), or None for an unknown stage.
    """
    default_map: dict[str, dict[str, Any]] = {}
    for section, values in content.items():
        if section == "study":  # free-form description of the preset's origin
            continue
        names = stage_params(section)
        if names is None:
            raise ParameterError(f"{path}: unknown section [{section}]; sections are stage names")
        if not isinstance(values, Mapping):
            raise ParameterError(f"{path}: [{section}] must be a table of option = value")
        section_map: dict[str, Any] = {}
        for key, value in values.items():
            name = key.replace("-", "_")
            if name not in names:
                raise ParameterError(
                    f"{path}: unknown key '{key}' in [{section}]; valid keys: "
                    + ", ".join(sorted(n.replace("_", "-") for n in names)))
            section_map[name] = value
        default_map[section] = section_map
    return default_map
