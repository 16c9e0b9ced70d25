"""Stage parameters: frozen dataclasses whose fields carry their option, range and help.

Every stage has one frozen parameter dataclass (``demtool.<core>.params``) built from
:func:`parameter` fields.  The field's metadata is the one source of the parameter's
default, admissible range, choices and help text:

* :meth:`Parameters.check` validates every field against it and raises
  :class:`~demtool.errors.ParameterError` naming the option (``--size``);
* :func:`demtool.commands.options.parameter_options` turns the fields into click options (the
  CLI layer; this module never imports click).

A field's option is ``--<field name>`` with dashes, unless ``option=`` gives another
(e.g. ``SceneParams.dem_size`` is ``--size``): the mapping is explicit, never guessed.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import types
import typing
from collections.abc import Sequence
from typing import Any

from demtool.errors import ParameterError


def parameter(default: Any, help: str, *, option: str | None = None,  # noqa: A002
              minimum: float | None = None, maximum: float | None = None,
              min_open: bool = False, max_open: bool = False,
              choices: Sequence[str] | None = None, odd: bool = False,
              what: str = "value", flag: str | None = None, metavar: str | None = None,
              cli: bool = True, check: Any = None) -> Any:
    """A dataclass field describing one stage parameter.

    Parameters
    ----------
    default
        The default value (the one place it is written).
    help : str
        One-line help text of the option (units included).
    option : str, optional
        Option name without dashes when it differs from the field name (``"size"``).
    minimum, maximum : float, optional
        Admissible range; ``min_open``/``max_open`` exclude the bound itself.
    choices : sequence of str, optional
        Admissible values (taken from the core, e.g. ``ALIGN_METHODS``).
    what : str
        What a choice is, for the message of a value outside ``choices``
        (``"reflectance model"``).
    odd : bool
        The value must be odd when it is above 1 (window sizes; 0 and 1 mean "off").
    flag : str, optional
        For booleans: click's declaration when it is not ``--x/--no-x`` (``"--rank"``
        for an on-only flag, ``"--shared-camera/--per-image-camera"``).
    metavar : str, optional
        Metavariable shown in ``--help``.
    cli : bool
        False for parameters that are not command-line options.
    check : callable, optional
        ``check(value) -> str | None``: the problem with a value that has no range or
        choices to say it (a scheduler address), or None; the option refuses it (exit 2)
        and :meth:`Parameters.check` too.
    """
    metadata = {"help": help, "option": option, "minimum": minimum, "maximum": maximum,
                "min_open": min_open, "max_open": max_open, "what": what, "odd": odd,
                "choices": tuple(choices) if choices is not None else None,
                "flag": flag, "metavar": metavar, "cli": cli, "check": check}
    return dataclasses.field(default=default, metadata=metadata)


def core_default(function: Any, name: str) -> Any:
    """The default of keyword ``name`` of a core function (so it is written only there)."""
    return core_defaults(function)[name]


def core_defaults(function: Any) -> dict[str, Any]:
    """The defaults of a core function's (or dataclass's) keywords, by name.

    Raises
    ------
    TypeError
        Asked for through :func:`core_default`, a keyword without a default.
    """
    import inspect

    class Defaults(dict):
        def __missing__(self, name: str) -> Any:
            raise TypeError(f"{function.__name__}() has no default for {name!r}")

    return Defaults({name: p.default for name, p in inspect.signature(function).parameters
                     .items() if p.default is not inspect.Parameter.empty})


def seed_field() -> Any:
    """The ``seed`` field every stage with random choices has (RANSAC, noise)."""
    return parameter(0, "Random seed, for reproducible runs.")


def workers_field() -> Any:
    """The ``workers`` field of the stages that run in parallel (0 = all cores)."""
    return parameter(0, "Parallel workers (0 = all cores).", minimum=0)


# The tiled stages' fields (demtool.tiling runs the tiles; docs/stages/scale.md).  They live
# here, not in demtool.tiling, so that a parameter module stays light: every command run
# with --config imports the parameters of each stage its preset names.
TILE_FIELDS = ("tile_size", "tile_overlap", "scheduler", "dry_run")


def tile_size_field() -> Any:
    """``--tile-size``: side of the tile cores (0 = untiled)."""
    return parameter(0, "Side of the square tile cores, px (0 = untiled, unless --scheduler "
                     "or --dry-run is given: then 1024).  Tiled, --workers N computes N tiles "
                     "at a time on this machine.", minimum=0)


def tile_overlap_field(default_text: str) -> Any:
    """``--tile-overlap``: margin around each core; ``default_text`` says the stage's default."""
    return parameter(None, f"Margin computed around each tile core and cropped, px "
                     f"[default: {default_text}].", minimum=0)


def scheduler_address_problem(address: Any) -> str | None:
    """What is wrong with a ``--scheduler`` address (None when it is one).

    An address is ``[protocol://]host:port`` with a port 1 … 65535 (Dask's
    ``parse_address``; ``tcp://`` when no protocol is given).
    """
    import re

    text = str(address).strip()
    match = re.fullmatch(r"(?:(tcp|tls|inproc|ucx|ws|wss)://)?(\[[0-9a-fA-F:]+\]|[^\s/:]+)"
                         r":(\d+)", text)
    if match is None or not 0 < int(match.group(3)) < 65536:
        return (f"{text!r} is not a scheduler address: expected [tcp://]host:port "
                "(e.g. tcp://127.0.0.1:8786)")
    return None


def scheduler_field() -> Any:
    """``--scheduler``: address of a running dask.distributed scheduler."""
    return parameter(None, "Address of a running dask.distributed scheduler "
                     "(tcp://host:8786) to run the tiles on.", metavar="ADDRESS",
                     check=scheduler_address_problem)


def dry_run_field() -> Any:
    """``--dry-run``: plan and calibrate, write nothing."""
    return parameter(False, "Print the tiling, the estimated peak memory per worker and a "
                     "time estimate from one calibration tile; write nothing.",
                     flag="--dry-run")


def option_name(field: dataclasses.Field) -> str:
    """The option of a field, without dashes and with underscores (click's param name)."""
    return (field.metadata.get("option") or field.name).replace("-", "_")


@functools.cache
def _type_hints(cls: type) -> dict[str, Any]:
    """``typing.get_type_hints(cls)``, evaluated once per class (it evaluates every field's
    annotation, and a command asks for each field's: 20 fields cost 400 evaluations)."""
    return typing.get_type_hints(cls)


def value_kind(cls: type, field: dataclasses.Field) -> type:
    """The scalar type of a field (``int``, ``float``, ``bool`` or ``str``), Optional removed."""
    hint = _type_hints(cls)[field.name]
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        hint = next(a for a in typing.get_args(hint) if a is not type(None))
    return hint if hint in (int, float, bool, str) else str


def describe_range(metadata: typing.Mapping[str, Any]) -> str | None:
    """The admissible range of a field as text (``"in (0, 1]"``, ``">= 0"``), or None."""
    low, high = metadata.get("minimum"), metadata.get("maximum")
    if low is not None and high is not None:
        return (f"in {'(' if metadata['min_open'] else '['}{low:g}, {high:g}"
                f"{')' if metadata['max_open'] else ']'}")
    if low is not None:
        return f"{'>' if metadata['min_open'] else '>='} {low:g}"
    if high is not None:
        return f"{'<' if metadata['max_open'] else '<='} {high:g}"
    return None


class Parameters:
    """Base of the stage parameter dataclasses (use with ``@dataclass(frozen=True)``)."""

    @classmethod
    def label(cls, name: str) -> str:
        """How a user sets field ``name``: its option, ``--size``."""
        field = next(f for f in dataclasses.fields(cls) if f.name == name)  # type: ignore[arg-type]
        return "--" + option_name(field).replace("_", "-")

    def as_dict(self) -> dict[str, Any]:
        """All parameters as a plain dict (for JSON, tags and the provenance sidecar)."""
        return dataclasses.asdict(self)  # type: ignore[call-overload]

    def fail(self, name: str, problem: str) -> typing.NoReturn:
        """Raise the ParameterError of field ``name``: ``--size must be ..., got 0``."""
        raise ParameterError(f"{self.label(name)} {problem}")

    def check(self) -> None:
        """Raise ParameterError naming the first field outside its range or choices.

        Stages with constraints between fields extend this (calling it first).
        """
        for field in dataclasses.fields(self):  # type: ignore[arg-type]
            value = getattr(self, field.name)
            meta = field.metadata
            if value is None or isinstance(value, bool):
                continue
            if meta.get("choices") is not None:
                if value not in meta["choices"]:
                    raise ParameterError(f"{self.label(field.name)}: unknown {meta['what']} "
                                         f"{value!r}: should be one of "
                                         + ", ".join(meta["choices"]))
                continue
            if meta.get("check") is not None and (problem := meta["check"](value)):
                self.fail(field.name, problem)
            if not isinstance(value, (int, float)):
                continue
            if not math.isfinite(value):
                self.fail(field.name, f"must be a finite number, got {value}")
            low, high = meta.get("minimum"), meta.get("maximum")
            below = low is not None and (value <= low if meta["min_open"] else value < low)
            above = high is not None and (value >= high if meta["max_open"] else value > high)
            if below or above:
                self.fail(field.name, f"must be {describe_range(meta)}, got {value:g}")
            if meta.get("odd") and value > 1 and value % 2 == 0:
                self.fail(field.name, f"must be odd, got {value}")

    @classmethod
    def from_options(cls, values: typing.Mapping[str, Any]):
        """Build from click's parameter values (keyed by option name); absent keep defaults."""
        chosen = {}
        for field in dataclasses.fields(cls):  # type: ignore[arg-type]
            key = option_name(field)
            if key in values:
                chosen[field.name] = values[key]
        return cls(**chosen)
