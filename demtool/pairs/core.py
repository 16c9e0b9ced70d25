"""Which pairs of a block to match: overlap, convergence and B/H within a range, sun.

Every pair of images on one surface is measured by :func:`demtool.camera.info.camera_info`
(footprint overlap, convergence angle and base-to-height ratio at the overlap's centre,
each image's sun azimuth and elevation).  A pair is kept when

* each footprint is covered by the other by at least ``min_overlap`` (a fraction);
* its convergence angle lies in ``[min_convergence, max_convergence]`` degrees and its
  B/H in ``[min_bh, max_bh]`` (too narrow: height noise grows as 1/(B/H); too wide: the
  views differ too much to match — the usual rule of thumb of 10–60° convergence,
  B/H 0.2–1, as in ASP's guidance on choosing stereo pairs and the LRO NAC studies);
* the angle between the two sun directions (from azimuth and elevation at each image's
  centre) is at most ``max_sun_difference`` degrees (different shading defeats
  intensity matching; SfS-grade stereo wants similar illumination).

Kept pairs are ranked by the smaller overlap fraction times how close the B/H is to
``best_bh`` (``min(b, best)/max(b, best)``), and ``max_pairs`` (0 = all) keeps the best.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

__all__ = ["pair_verdicts", "select_pairs", "sun_difference_deg"]


def sun_difference_deg(first: Mapping[str, Any], second: Mapping[str, Any]) -> float | None:
    """Angle between two images' sun directions, degrees (None: a sun is unknown).

    Parameters
    ----------
    first, second : mapping
        Camera entries of :func:`demtool.camera.info.camera_info` (``sun_azimuth_deg``,
        ``sun_elevation_deg``: local east-north-up at each image's centre).
    """
    try:
        a1, e1 = math.radians(first["sun_azimuth_deg"]), math.radians(first["sun_elevation_deg"])
        a2, e2 = (math.radians(second["sun_azimuth_deg"]),
                  math.radians(second["sun_elevation_deg"]))
    except (KeyError, TypeError):
        return None
    cosine = (math.cos(e1) * math.cos(e2) * math.cos(a1 - a2) + math.sin(e1) * math.sin(e2))
    return math.degrees(math.acos(max(-1.0, min(1.0, cosine))))


def pair_verdicts(cameras: Sequence[Mapping[str, Any]], pairs: Sequence[Mapping[str, Any]], *,
                  min_overlap: float = 0.5, min_convergence: float = 10.0,
                  max_convergence: float = 60.0, min_bh: float = 0.2, max_bh: float = 1.0,
                  max_sun_difference: float = 20.0, best_bh: float = 0.5
                  ) -> list[dict[str, Any]]:
    """Each pair's figures, whether it passes, why not, and its score.

    Parameters
    ----------
    cameras, pairs : sequences of mapping
        ``camera_info(...)["cameras"]`` and ``["pairs"]``.
    min_overlap : float
        Smallest fraction of each footprint the other covers.
    min_convergence, max_convergence : float
        Convergence angle range, degrees.
    min_bh, max_bh : float
        Base-to-height ratio range.
    max_sun_difference : float
        Largest angle between the sun directions, degrees.
    best_bh : float
        The B/H the ranking prefers.

    Returns
    -------
    list of dict
        One per pair, in input order: ``first``, ``second``, ``overlap`` (the smaller
        fraction), ``convergence_deg``, ``base_to_height``, ``sun_difference_deg``,
        ``reasons`` (empty: kept), ``score``.
    """
    by_name = {c["name"]: c for c in cameras}
    out = []
    for pair in pairs:
        fractions = [pair.get("overlap_fraction_first"), pair.get("overlap_fraction_second")]
        overlap = None if None in fractions else min(fractions)
        convergence = pair.get("convergence_deg")
        bh = pair.get("base_to_height")
        sun = sun_difference_deg(by_name[pair["first"]], by_name[pair["second"]])
        reasons = []
        if overlap is None or overlap < min_overlap:
            reasons.append(f"overlap {0 if overlap is None else overlap:.0%} < "
                           f"{min_overlap:.0%}")
        if convergence is None or not min_convergence <= convergence <= max_convergence:
            reasons.append("convergence " + ("unknown" if convergence is None else
                                             f"{convergence:.1f}°") +
                           f" outside {min_convergence:g}–{max_convergence:g}°")
        if bh is None or not min_bh <= bh <= max_bh:
            reasons.append("B/H " + ("unknown" if bh is None else f"{bh:.2f}") +
                           f" outside {min_bh:g}–{max_bh:g}")
        if sun is not None and sun > max_sun_difference:
            reasons.append(f"sun directions {sun:.1f}° apart > {max_sun_difference:g}°")
        score = 0.0
        if overlap is not None and bh:
            score = overlap * min(bh, best_bh) / max(bh, best_bh)
        out.append({"first": pair["first"], "second": pair["second"], "overlap": overlap,
                    "convergence_deg": convergence, "base_to_height": bh,
                    "sun_difference_deg": sun, "reasons": reasons, "score": score})
    return out


def select_pairs(verdicts: Sequence[Mapping[str, Any]], max_pairs: int = 0
                 ) -> list[Mapping[str, Any]]:
    """The kept pairs, best score first (``max_pairs`` > 0: at most that many)."""
    kept = sorted((v for v in verdicts if not v["reasons"]), key=lambda v: -v["score"])
    return kept[:max_pairs] if max_pairs > 0 else kept
