"""Area-based dense matching (``demtool match``): the HiRISE Dense Matcher scheme.

Seeds (SIFT, Förstner corners, prior matches) → Delaunay initial disparity and
per-pixel search bounds → pyramid NCC → least-squares matching (Grün 1985) with an
acceptance threshold on the correlation coefficient.  The entry point is
:func:`match`; the steps are usable on their own.

Names are imported lazily (PEP 562), so ``demtool match --help`` and the
parameter module ``demtool.match.params`` do not pull in numba, OpenCV or pycolmap.
"""

from demtool.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "dense": ("MatchResult", "check_parameters", "match"),
    "lsm": ("LSMResult", "lsm_match"),
    "ncc": ("NCCResult", "build_pyramid", "ncc_search"),
    "seeds": ("Seeds", "check_seed_points", "find_seeds"),
    "triangles": ("SeedTriangulation", "TriangleBounds"),
})
