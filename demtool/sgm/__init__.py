"""Semi-global matching (Hirschmüller 2008) of a rectified stereo pair.

``sgm(left, right, *, min_disparity, num_disparities, ...)`` returns the left image's
disparity (``x_right = x_left − d``, float32 pixels, NaN = invalid) and a confidence
map.  Modules: :mod:`~demtool.sgm.cost` (census, absolute difference and table costs;
window-summed cost rows), :mod:`~demtool.sgm.mutual_information` (the MI cost table),
:mod:`~demtool.sgm.aggregate` (8/16-path aggregation sweeps, numba),
:mod:`~demtool.sgm.disparity` (WTA, sub-pixel, left–right check, speckles, median),
:mod:`~demtool.sgm.strips` (one pass: strips, sweep threads, timing),
:mod:`~demtool.sgm.matcher` (MI iterations, the HMI pyramid, the public :func:`sgm`).

Names are imported lazily (PEP 562), so ``demtool sgm --help`` and the
parameter module ``demtool.sgm.params`` do not pull in numba, OpenCV or pycolmap.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from demtool.sgm.matcher import (  # noqa: F401
        COST_DEFAULTS,
        COSTS,
        SGMResult,
        sgm,
    )
    from demtool.sgm.strips import (  # noqa: F401
        plan_strips,
    )

_EXPORTS = {
    "COST_DEFAULTS": "demtool.sgm.matcher",
    "COSTS": "demtool.sgm.matcher",
    "SGMResult": "demtool.sgm.matcher",
    "sgm": "demtool.sgm.matcher",
    "plan_strips": "demtool.sgm.strips",
}

__all__ = [
    "COSTS",
    "COST_DEFAULTS",
    "SGMResult",
    "plan_strips",
    "sgm",
]


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name]), name)
        globals()[name] = value  # later look-ups skip this function
        return value
    raise AttributeError(f"module 'demtool.sgm' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
