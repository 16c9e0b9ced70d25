"""Area-based dense matching (``demtool match``): the HiRISE Dense Matcher scheme.

Seeds (SIFT, Förstner corners, prior matches) → Delaunay initial disparity and
per-pixel search bounds → pyramid NCC → least-squares matching (Grün 1985) with an
acceptance threshold on the correlation coefficient.  The entry point is
:func:`match`; the steps are usable on their own.

Names are imported lazily (PEP 562), so ``demtool match --help`` and the
parameter module ``demtool.match.params`` do not pull in numba, OpenCV or pycolmap.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from demtool.match.dense import (  # noqa: F401
        MatchResult,
        check_parameters,
        match,
    )
    from demtool.match.lsm import (  # noqa: F401
        LSMResult,
        lsm_match,
    )
    from demtool.match.ncc import (  # noqa: F401
        NCCResult,
        build_pyramid,
        ncc_search,
    )
    from demtool.match.seeds import (  # noqa: F401
        Seeds,
        check_seed_points,
        find_seeds,
    )
    from demtool.match.triangles import (  # noqa: F401
        SeedTriangulation,
        TriangleBounds,
    )

_EXPORTS = {
    "MatchResult": "demtool.match.dense",
    "check_parameters": "demtool.match.dense",
    "match": "demtool.match.dense",
    "LSMResult": "demtool.match.lsm",
    "lsm_match": "demtool.match.lsm",
    "NCCResult": "demtool.match.ncc",
    "build_pyramid": "demtool.match.ncc",
    "ncc_search": "demtool.match.ncc",
    "Seeds": "demtool.match.seeds",
    "check_seed_points": "demtool.match.seeds",
    "find_seeds": "demtool.match.seeds",
    "SeedTriangulation": "demtool.match.triangles",
    "TriangleBounds": "demtool.match.triangles",
}

__all__ = [
    "LSMResult",
    "MatchResult",
    "NCCResult",
    "SeedTriangulation",
    "Seeds",
    "TriangleBounds",
    "build_pyramid",
    "check_parameters",
    "check_seed_points",
    "find_seeds",
    "lsm_match",
    "match",
    "ncc_search",
]


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name]), name)
        globals()[name] = value  # later look-ups skip this function
        return value
    raise AttributeError(f"module 'demtool.match' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
