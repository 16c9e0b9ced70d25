"""Accuracy of `demtool sgm` against OpenCV StereoSGBM (MODE_HH) on pairs with truth.

Scored the way a DEM user meets the result (issue 13): every pixel with truth counts,
and an invalid (NaN) pixel counts as bad.  Per pair and method: bad-1 and bad-2 over
all pixels with truth (``all``) and over the non-occlusion mask (``nonocc``), the
invalid fraction and the MAE of the valid pixels (both over ``all``).  The left
``ndisp`` columns are excluded from every mask (their matches may fall outside the
right image).  Methods: demtool's default ``sgm``, ``--cost census``, and OpenCV's
StereoSGBM MODE_HH (block 5, P1 8·25, P2 32·25, disp12MaxDiff 1, uniqueness 10,
speckle 100/2, same disparity range; 8-bit images, float ones stretched by
``demtool.imaging.features.to_uint8``), all in the same run.

Targets (issue 13), on the five Middlebury pairs and every weak-texture pair: the
default's bad-2 (``all``, invalid = bad) at or below OpenCV's on each pair and on
average at most 0.8 × OpenCV's; its invalid fraction at most 1.5 × OpenCV's on each.

Pairs
-----
synthetic
    The synthetic scene's target/partner pair (``demtool.synth``), rectified by
    ``demtool.rectify.core``; truth from ``demtool.synth.truth.truth_disparity`` (visible
    pixels).  Needs no outside data; printed, not part of the targets.
weak1 … weak6
    Generated planetary-like pairs (``_stereo_pairs.WEAK_TEXTURE_PAIRS``): fractal
    albedo of σ 3–8 DN, noise σ 1–4 DN, gain 0.8–1.25 with an offset, float32 or 8-bit,
    smooth or stepped disparity fields with true occlusions.  Need no outside data.
tsukuba, venus, cones, teddy, cloth3
    From ``../shared/data/middlebury`` when that folder exists (skipped otherwise).
    © Middlebury College; Scharstein & Szeliski (2002), IJCV 47, 7–42; (2003) CVPR;
    Hirschmüller & Scharstein (2007), CVPR (cloth3).  ``nonocc``: cones and teddy use
    ``derived/nonocc_lrcheck.png``, cloth3 the same left–right check of its two
    truths made here; tsukuba and venus have no right truth, so ``nonocc`` = ``all``.

Usage: ``.venv/bin/python bench/stereo_accuracy.py [--quick] [--pairs weak1,cones,...]``
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from _stereo_pairs import (
    MIDDLEBURY,
    MIDDLEBURY_PAIRS,
    WEAK_TEXTURE_PAIRS,
    StereoPair,
    middlebury_pair,
    opencv_sgbm,
    score,
    scored_masks,
    synthetic_pair,
    weak_texture_pair,
)

TARGET_PAIRS = (*MIDDLEBURY_PAIRS, *WEAK_TEXTURE_PAIRS)
DEFAULT_PAIRS = ("synthetic", *TARGET_PAIRS)
OPENCV = "OpenCV HH bs=5"


def load_pair(name: str, quick: bool) -> StereoPair | None:
    """The named pair, or None (with a note) when its data are absent."""
    if name == "synthetic":
        return synthetic_pair(quick)
    if name in WEAK_TEXTURE_PAIRS:
        return weak_texture_pair(WEAK_TEXTURE_PAIRS[name], quick)
    if name in MIDDLEBURY_PAIRS:
        if not (MIDDLEBURY / name).is_dir():
            print(f"\n{name}: skipped ({MIDDLEBURY / name} not found)")
            return None
        return middlebury_pair(name)
    raise KeyError(name)


def run_methods(pair: StereoPair, methods: dict[str, dict]) -> dict[str, tuple[dict, float]]:
    """Run each demtool option set and OpenCV HH on a pair; scores per mask and seconds."""
    from demtool.sgm import sgm

    masks = scored_masks(pair)
    results = {}
    for label, options in methods.items():
        start = time.perf_counter()
        disparity = sgm(pair.left, pair.right, min_disparity=pair.min_disparity,
                        num_disparities=pair.num_disparities, **options).disparity
        results[label] = ({k: score(disparity, pair.truth, m) for k, m in masks.items()},
                          time.perf_counter() - start)
    disparity, seconds = opencv_sgbm(pair.left, pair.right, pair.min_disparity,
                                     pair.num_disparities, 5)
    results[OPENCV] = ({k: score(disparity, pair.truth, m) for k, m in masks.items()},
                       seconds)
    return results


def print_pair(name: str, pair: StereoPair, results: dict) -> None:
    masks = scored_masks(pair)
    print(f"\n{name}: {pair.left.shape[1]}×{pair.left.shape[0]} px, disparities "
          f"{pair.min_disparity} … {pair.min_disparity + pair.num_disparities - 1}; scored "
          f"pixels all {int(masks['all'].sum())}, nonocc {int(masks['nonocc'].sum())}",
          flush=True)
    print(f"  {'method':<16} {'bad1 all':>9} {'bad2 all':>9} {'bad1 noc':>9} "
          f"{'bad2 noc':>9} {'invalid':>8} {'MAE':>6} {'time s':>7}")
    for label, (s, seconds) in results.items():
        a, n = s["all"], s["nonocc"]
        print(f"  {label:<16} {100 * a['bad1']:8.2f}% {100 * a['bad2']:8.2f}% "
              f"{100 * n['bad1']:8.2f}% {100 * n['bad2']:8.2f}% {100 * a['invalid']:7.2f}% "
              f"{a['mae']:6.3f} {seconds:7.2f}")


def print_targets(rows: dict[str, dict]) -> None:
    """The issue's targets over the Middlebury and weak-texture pairs that ran."""
    names = [n for n in rows if n in TARGET_PAIRS]
    if not names:
        return
    print("\nTargets (issue 13): default bad-2 (all, invalid = bad) <= OpenCV HH's on each "
          "pair, mean <= 0.8 × OpenCV's; invalid <= 1.5 × OpenCV's on each")
    print(f"  {'pair':<9} {'default':>8} {'census':>8} {'OpenCV':>8} {'ratio':>6} "
          f"{'inv dflt':>9} {'inv OCV':>8} {'bad2':>5} {'inv':>5}")
    ours_all, ref_all, failures = [], [], 0
    for name in names:
        ours = rows[name]["demtool default"][0]["all"]
        census = rows[name]["demtool census"][0]["all"]
        ref = rows[name][OPENCV][0]["all"]
        bad2_ok = ours["bad2"] <= ref["bad2"]
        inv_ok = ours["invalid"] <= 1.5 * ref["invalid"]
        failures += (not bad2_ok) + (not inv_ok)
        ours_all.append(ours["bad2"])
        ref_all.append(ref["bad2"])
        print(f"  {name:<9} {100 * ours['bad2']:7.2f}% {100 * census['bad2']:7.2f}% "
              f"{100 * ref['bad2']:7.2f}% {ours['bad2'] / max(ref['bad2'], 1e-9):6.2f} "
              f"{100 * ours['invalid']:8.2f}% {100 * ref['invalid']:7.2f}% "
              f"{'met' if bad2_ok else 'NOT':>5} {'met' if inv_ok else 'NOT':>5}")
    mean_ours, mean_ref = float(np.mean(ours_all)), float(np.mean(ref_all))
    ratio = mean_ours / max(mean_ref, 1e-9)
    print(f"  mean bad-2: default {100 * mean_ours:.2f}%, OpenCV {100 * mean_ref:.2f}%, "
          f"ratio {ratio:.2f} (target <= 0.80): {'met' if ratio <= 0.8 else 'NOT met'}; "
          f"per-pair targets missed: {failures}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller synthetic pairs")
    parser.add_argument("--pairs", default=",".join(DEFAULT_PAIRS),
                        help="comma-separated pairs to run")
    args = parser.parse_args(argv)
    wanted = [p.strip() for p in args.pairs.split(",") if p.strip()]
    unknown = [p for p in wanted if p not in DEFAULT_PAIRS]
    if unknown:
        print(f"unknown pair(s) {', '.join(unknown)}; known: {', '.join(DEFAULT_PAIRS)}",
              file=sys.stderr)
        return 2
    methods = {"demtool default": {}, "demtool census": {"cost": "census"}}
    rows: dict[str, dict] = {}
    for name in wanted:
        pair = load_pair(name, args.quick)
        if pair is None:
            continue
        rows[name] = run_methods(pair, methods)
        print_pair(name, pair, rows[name])
    print_targets(rows)
    print("\nMiddlebury data © Middlebury College (Scharstein & Szeliski 2002, 2003; "
          "Hirschmüller & Scharstein 2007).")
    return 0


if __name__ == "__main__":
    sys.exit(main())
