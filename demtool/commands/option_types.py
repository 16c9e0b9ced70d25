"""Click parameter types for numbers: finite unless an option says otherwise, ranges checked.

click's ``float`` and ``FloatRange`` accept ``nan`` and ``inf`` (``nan`` even passes
any range, since every comparison with it is false), and its ``int`` turns a preset's
``true`` into 1 and ``3.7`` into 3.  These types refuse all of that with a message in
click's words (exit status 2)::

    Error: Invalid value for '--gsd': inf is not a finite number.
    Error: Invalid value for '--outlier-threshold': -1.0 is not in the range x>=0.

When the value came from a ``--config`` preset, the message names the preset file,
its section and key, so the user knows which line to fix::

    Error: Invalid value for '--median': preset p.toml, [dem] median: [1, 2] is not a
    valid integer.

They subclass click's range types, so ``--help`` shows the ranges as usual.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import click
from click.core import ParameterSource


def _preset_prefix(value: Any, param: click.Parameter | None, ctx: click.Context | None) -> str:
    """``"preset FILE, [section] key: "`` when the value came from the preset."""
    if ctx is None or param is None or param.name is None:
        return ""
    try:
        source = ctx.get_parameter_source(param.name)
    except (AttributeError, KeyError):  # pragma: no cover - defensive
        return ""
    if source is not ParameterSource.DEFAULT_MAP:
        return ""
    root = ctx.find_root()
    config = getattr(root.obj, "config_path", None) or "the --config preset"
    key = param.name.replace("_", "-")
    return f"preset {config}, [{ctx.info_name}] {key}: "


class _Checks:
    """Shared conversion: reject what is not a number, NaN and ±inf, then the range."""

    kind = "valid number"

    def _number(self, value: Any, param, ctx, cast):
        if isinstance(value, bool) or not isinstance(value, (str, numbers.Real)):
            self._fail(value, f"{value!r} is not a {self.kind}.", param, ctx)
        if isinstance(value, str):
            value = value.strip()
        try:
            return cast(value)
        except (TypeError, ValueError, OverflowError):
            self._fail(value, f"{value!r} is not a {self.kind}.", param, ctx)

    def _in_range(self, base, number, value: Any, param, ctx):
        """``base.convert`` (click's range check) of ``number``; a refusal of a preset value
        names the preset and its section (see :func:`_preset_prefix`)."""
        try:
            return base.convert(self, number, param, ctx)
        except click.BadParameter as exc:
            prefix = _preset_prefix(value, param, ctx)
            if not prefix:
                raise
            self.fail(prefix + exc.message, param, ctx)

    def _fail(self, value: Any, message: str, param, ctx):
        self.fail(_preset_prefix(value, param, ctx) + message, param, ctx)

    def _describe_range(self) -> str:
        """The range for ``--help``; empty when unbounded (click would print ``x<=None``)."""
        if self.min is None and self.max is None:
            return ""
        return super()._describe_range()


class FloatRange(_Checks, click.FloatRange):
    """A float in an optional range; NaN and ±inf are refused unless allowed.

    Parameters
    ----------
    min, max : float, optional
        Bounds (None = unbounded).
    min_open, max_open : bool
        Exclude the bound itself (``x>0`` rather than ``x>=0``).
    allow_nan, allow_inf : bool
        Accept ``nan`` (e.g. "not set") or ``±inf`` (e.g. "no limit").
    """

    name = "float"
    kind = "valid float"

    def __init__(self, min: float | None = None, max: float | None = None,
                 min_open: bool = False, max_open: bool = False, clamp: bool = False, *,
                 allow_nan: bool = False, allow_inf: bool = False) -> None:
        super().__init__(min=min, max=max, min_open=min_open, max_open=max_open, clamp=clamp)
        self.allow_nan = allow_nan
        self.allow_inf = allow_inf

    def convert(self, value: Any, param: click.Parameter | None,
                ctx: click.Context | None) -> float:
        if isinstance(value, float) and math.isfinite(value) and not self._has_range():
            return value
        number = self._number(value, param, ctx, float)
        if math.isnan(number) and not self.allow_nan:
            self._fail(value, f"{value!r} is not a finite number.", param, ctx)
        if math.isinf(number) and not self.allow_inf:
            self._fail(value, f"{value!r} is not a finite number.", param, ctx)
        if math.isnan(number):
            return number
        return self._in_range(click.FloatRange, number, value, param, ctx)

    def _has_range(self) -> bool:
        return self.min is not None or self.max is not None


class IntRange(_Checks, click.IntRange):
    """An integer in an optional range; refuses booleans and non-integral numbers.

    ``"3"``, ``3`` and (from a preset) ``3.0`` are 3; ``3.5``, ``"3.0"``, ``true``,
    ``nan`` and ``inf`` are refused (click's ``int`` would truncate or crash).
    """

    name = "integer"
    kind = "valid integer"

    def convert(self, value: Any, param: click.Parameter | None,
                ctx: click.Context | None) -> int:
        if isinstance(value, float):
            if not math.isfinite(value) or value != int(value):
                self._fail(value, f"{value!r} is not a valid integer.", param, ctx)
            value = int(value)
        number = self._number(value, param, ctx, int)
        return self._in_range(click.IntRange, number, value, param, ctx)


#: Any finite float.
FLOAT = FloatRange()
#: Any integer.
INT = IntRange()
#: A finite float > 0.
POSITIVE = FloatRange(min=0.0, min_open=True)
#: A finite float ≥ 0.
NON_NEGATIVE = FloatRange(min=0.0)
#: A fraction in [0, 1].
FRACTION = FloatRange(min=0.0, max=1.0)
