"""Leave-one-out choice of `sgm`'s settings over the stereo pairs with truth (issue 13).

A small grid of settings (cost, penalty scale, adaptive P2) runs on every pair of
``bench/stereo_accuracy.py`` (the five Middlebury pairs when ``../shared/data`` is
present, and the generated weak-texture family).  The score of a setting on a pair
is its bad-2 (all pixels with truth, invalid = bad) divided by OpenCV HH's on that
pair in the same run, so that pairs of different difficulty weigh alike.  For each
pair in turn, the setting with the lowest mean score on the *other* pairs is chosen,
and its score on the held-out pair is reported: that is what a user gets on a pair
the defaults were not chosen on.  The last line names the setting chosen on all
pairs, to compare with the library's defaults.

Usage: ``.venv/bin/python bench/stereo_tuning.py [--quick] [--pairs ...]``
"""

from __future__ import annotations

import argparse
import itertools
import sys

import numpy as np
from _stereo_pairs import opencv_sgbm, score, scored_masks
from stereo_accuracy import TARGET_PAIRS, load_pair


def grid() -> dict[str, dict]:
    """The candidate settings: cost × penalty scale × adaptive P2 (fill on)."""
    from demtool.sgm import COST_DEFAULTS

    settings = {}
    for cost, scale, adaptive in itertools.product(("hmi", "census"), (0.7, 1.0, 1.4),
                                                   (True, False)):
        base = COST_DEFAULTS["mi" if cost == "hmi" else cost]
        settings[f"{cost} P×{scale:g} {'adaptive' if adaptive else 'fixed'}"] = dict(
            cost=cost, p1=round(scale * base.p1), p2=round(scale * base.p2),
            adaptive_p2=adaptive)
    return settings


def main(argv: list[str] | None = None) -> int:
    from demtool.sgm import sgm

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller generated pairs")
    parser.add_argument("--pairs", default=",".join(TARGET_PAIRS))
    args = parser.parse_args(argv)
    settings = grid()
    names, table = [], []
    for name in [p.strip() for p in args.pairs.split(",") if p.strip()]:
        pair = load_pair(name, args.quick)
        if pair is None:
            continue
        mask = scored_masks(pair)["all"]
        reference, _ = opencv_sgbm(pair.left, pair.right, pair.min_disparity,
                                   pair.num_disparities, 5)
        ref = max(score(reference, pair.truth, mask)["bad2"], 1e-4)
        row = []
        for options in settings.values():
            disparity = sgm(pair.left, pair.right, min_disparity=pair.min_disparity,
                            num_disparities=pair.num_disparities, **options).disparity
            row.append(score(disparity, pair.truth, mask)["bad2"] / ref)
        names.append(name)
        table.append(row)
        print(f"{name}: OpenCV bad-2 {100 * ref:.2f}%; best setting here "
              f"{list(settings)[int(np.argmin(row))]} ({min(row):.2f}×)", flush=True)
    scores = np.array(table)  # pairs × settings, bad-2 / OpenCV's
    labels = list(settings)
    print(f"\n{'held-out pair':<14} {'chosen on the others':<28} {'held-out ratio':>14} "
          f"{'best possible':>13}")
    held = []
    for i, name in enumerate(names):
        others = np.delete(scores, i, axis=0)
        choice = int(np.argmin(others.mean(axis=0)))
        held.append(scores[i, choice])
        print(f"{name:<14} {labels[choice]:<28} {scores[i, choice]:14.2f} "
              f"{scores[i].min():13.2f}")
    overall = int(np.argmin(scores.mean(axis=0)))
    print(f"\nmean held-out bad-2 / OpenCV: {np.mean(held):.2f} (target <= 0.80); "
          f"pairs above 1: {int(np.sum(np.array(held) > 1))}")
    print(f"chosen on all pairs: {labels[overall]} (mean {scores[:, overall].mean():.2f})")
    for label, column in zip(labels, scores.T, strict=True):
        print(f"  {label:<28} mean {column.mean():.2f}  max {column.max():.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
