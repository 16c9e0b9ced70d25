"""Area-based dense matching (``demtool match``): the HiRISE Dense Matcher scheme.

Seeds (SIFT, Förstner corners, prior matches) → Delaunay initial disparity and
per-pixel search bounds → pyramid NCC → least-squares matching (Grün 1985) with an
acceptance threshold on the correlation coefficient.  The entry point is
:func:`match`; the steps are usable on their own.
"""

from demtool.match.dense import MatchResult, check_parameters, match
from demtool.match.lsm import LSMResult, lsm_match
from demtool.match.ncc import NCCResult, build_pyramid, ncc_search
from demtool.match.seeds import Seeds, check_seed_points, find_seeds
from demtool.match.triangles import SeedTriangulation, TriangleBounds

__all__ = [
    "LSMResult", "MatchResult", "NCCResult", "SeedTriangulation", "Seeds", "TriangleBounds",
    "build_pyramid", "check_parameters", "check_seed_points", "find_seeds", "lsm_match",
    "match", "ncc_search",
]
