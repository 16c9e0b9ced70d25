"""Accuracy of `demtool match` (LSM) beside `demtool sgm` on stereo pairs with truth.

For every pair, `demtool.match.match` runs with templates 9, 13, 17, 21, 25 px and
acceptance thresholds 0.9 and 0.8 (the HiRISE Dense Matcher study's settings; its
figures 2 and 8 report completeness against template size and threshold, here with
truth), and `demtool.sgm.sgm` runs with parabola and equiangular sub-pixel fits (plus
OpenCV's StereoSGBM MODE_HH, the reference of the shared data README).

Metrics, over the scored mask: ``compl`` = percentage of the mask with a disparity;
``MAE`` = mean absolute error (px) of those pixels; ``bad.5`` / ``bad1`` = percentage
of them with error above 0.5 / 1 px.

On the synthetic pair, centre-weighted LSM (``--weighting``, Gaussian σ = 3 px) runs
too, at the first threshold.

Target (issue 7): on the synthetic pair, LSM's MAE on its accepted pixels is below
SGM's with the parabola sub-pixel fit.

Pairs
-----
synthetic
    The synthetic scene's target/partner pair (``demtool.synth``), rectified by
    ``demtool.rectify.core``; truth from ``demtool.synth.truth.truth_disparity``, scored on
    its visible pixels.  Needs no outside data.
synthetic1024
    The same scene rendered at 1024 × 1024 px (over a 1024-cell DEM): the pair of
    issue 13's speed target (``--pairs synthetic1024``; not run by default).
tsukuba, venus, cones, teddy
    Middlebury pairs from ``../shared/data/middlebury`` when that folder exists
    (skipped otherwise).  © Middlebury College; Scharstein, D., Szeliski, R. (2002),
    A taxonomy and evaluation of dense two-frame stereo correspondence algorithms,
    IJCV 47, 7-42; (2003) High-accuracy stereo depth maps using structured light,
    CVPR.  Scored on all pixels with truth, and for cones and teddy also on
    ``derived/nonocc_lrcheck.png`` (a stand-in for the official non-occlusion mask,
    see the data README).  The truths are quantised (tsukuba 1 px, venus 1/8 px,
    cones and teddy 1/4 px), which puts a floor under every method's MAE.

Usage: ``.venv/bin/python bench/match_accuracy.py [--quick] [--pairs synthetic,cones]
[--templates 9,17] [--thresholds 0.9,0.8] [--refine 0,1] [--no-references]``
(``--no-references``: the `match` rows only; ``--refine 0,1``: each `match` run without
and with the IC-GN refinement of its disparities).  Each `match` run prints its wall
and CPU time per megapixel (issue 13's target: ≤ 15 s/MP wall on 2 cores at the
defaults).  ``--quick`` uses a 256-px synthetic scene, templates 9, 17, 25 and the
pairs synthetic, tsukuba, venus.  Timings depend on the machine's load; they are printed
for orientation only.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from _stereo_pairs import (
    MIDDLEBURY,
    MIDDLEBURY_PAIRS,
    StereoPair,
    middlebury_pair,
    opencv_sgbm,
    synthetic_pair,
)

ALL_TEMPLATES = (9, 13, 17, 21, 25)
ALL_THRESHOLDS = (0.9, 0.8)


def synthetic_pair_1024() -> StereoPair:
    """The synthetic scene rendered at 1024 × 1024 px over a 1024-cell DEM (speed target).

    As :func:`_stereo_pairs.synthetic_pair`, larger: issue 13 reports `match`'s
    seconds per megapixel on this pair.
    """
    from demtool.synth import SceneParams

    return synthetic_pair(False, SceneParams(n_views=2, image_size=1024, dem_size=1024))


def scores(disparity: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> dict[str, float]:
    """Completeness, MAE, bad-0.5 and bad-1 (percent) of ``disparity`` over ``mask``."""
    valid = mask & np.isfinite(disparity)
    error = np.abs(disparity[valid] - truth[valid])
    empty = error.size == 0
    return {"compl": 100.0 * valid.sum() / max(int(mask.sum()), 1),
            "mae": math.nan if empty else float(error.mean()),
            "bad05": math.nan if empty else 100.0 * float((error > 0.5).mean()),
            "bad1": math.nan if empty else 100.0 * float((error > 1.0).mean())}


def run_pair(name: str, data, templates, thresholds, weighting: float = 0.0,
             references: bool = True, refines: tuple[int, ...] = (1,)) -> list[dict]:
    """Every method on one pair; prints its table and returns the rows."""
    from demtool.errors import DemtoolError
    from demtool.match import match

    left, right, truth, masks, min_disparity, count, seeds = data
    print(f"\n{name}: {left.shape[1]} x {left.shape[0]} px, disparities {min_disparity} … "
          f"{min_disparity + count - 1}; scored pixels: "
          + ", ".join(f"{k} {int(m.sum())}" for k, m in masks.items()), flush=True)
    runs: list[tuple[str, np.ndarray, float]] = []
    try:
        from demtool.sgm import sgm
    except ImportError:
        print("  demtool.sgm is not available: SGM rows skipped")
        sgm = None
    if sgm is not None and references:
        for subpixel in ("parabola", "equiangular"):
            start = time.perf_counter()
            result = sgm(left, right, min_disparity=min_disparity, num_disparities=count,
                         subpixel=subpixel)
            runs.append((f"sgm hmi {subpixel}", result.disparity, time.perf_counter() - start))
    if references:
        start = time.perf_counter()
        runs.append(("OpenCV SGBM HH", opencv_sgbm(left, right, min_disparity, count)[0],
                     time.perf_counter() - start))
    configs = [(t, r, 0.0, n) for t in templates for r in thresholds for n in refines]
    if weighting > 0:  # centre-weighted LSM at the study's threshold
        configs += [(t, thresholds[0], weighting, n) for t in templates for n in refines]
    for template, threshold, sigma_w, refine in configs:
        label = (f"match t={template} r>={threshold}" + (f" w={sigma_w:g}" if sigma_w else "")
                 + (f" ref={refine}" if len(refines) > 1 else ""))
        start = time.perf_counter()
        cpu = time.process_time()
        try:
            result = match(left, right, template=template, threshold=threshold,
                           seed_points=seeds, weighting=sigma_w, refine=refine)
            disparity = result.disparity
        except DemtoolError as exc:
            print(f"  {label}: failed: {exc}")
            disparity = np.full(left.shape, np.nan, np.float32)
        runs.append((label, disparity, time.perf_counter() - start))
        megapixels = left.size / 1e6
        print(f"  … {label}: {runs[-1][2]:.1f} s wall = {runs[-1][2] / megapixels:.1f} s/MP, "
              f"CPU {(time.process_time() - cpu) / megapixels:.1f} s/MP (all threads)",
              flush=True)
    rows = []
    for mask_name, mask in masks.items():
        print(f"  [{mask_name}]\n  {'method':<24} {'compl%':>7} {'MAE':>7} {'bad.5%':>7} "
              f"{'bad1%':>7} {'time s':>7}")
        for label, disparity, seconds in runs:
            s = scores(disparity, truth, mask)
            rows.append({"pair": name, "mask": mask_name, "method": label, **s,
                         "seconds": seconds})
            print(f"  {label:<24} {s['compl']:7.1f} {s['mae']:7.3f} {s['bad05']:7.2f} "
                  f"{s['bad1']:7.2f} {seconds:7.1f}")
    return rows


def verdict(rows: list[dict]) -> None:
    """The issue's target on the synthetic pair."""
    synthetic = [r for r in rows if r["pair"] == "synthetic"]
    reference = [r for r in synthetic if r["method"] == "sgm hmi parabola"]
    if not synthetic:
        return
    if not reference:
        print("\ntarget: SGM (parabola) did not run; cannot compare")
        return
    sgm_mae = reference[0]["mae"]
    print(f"\ntarget (synthetic): LSM MAE on accepted pixels < SGM parabola MAE "
          f"{sgm_mae:.3f} px")
    for r in synthetic:
        if r["method"].startswith("match"):
            state = "met" if r["mae"] < sgm_mae else "NOT met"
            print(f"  {r['method']:<24} MAE {r['mae']:.3f} px, completeness "
                  f"{r['compl']:.1f} %: {state}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller, faster run")
    parser.add_argument("--pairs", default=None,
                        help="comma-separated: synthetic, synthetic1024, tsukuba, venus, "
                             "cones, teddy, cloth3")
    parser.add_argument("--templates", default=None, help="comma-separated template sizes")
    parser.add_argument("--thresholds", default=None, help="comma-separated thresholds")
    parser.add_argument("--no-references", action="store_true",
                        help="match only: no SGM and OpenCV rows")
    parser.add_argument("--refine", default="1",
                        help="comma-separated IC-GN refinement iterations of match "
                             "(e.g. 0,1: before and after the refinement)")
    parser.add_argument("--weighting", type=float, default=3.0,
                        help="also run centre-weighted LSM (Gaussian sigma, px) on the "
                             "synthetic pair; 0 = no")
    args = parser.parse_args()
    default_pairs = ["synthetic", "tsukuba", "venus"] if args.quick else \
        ["synthetic", *MIDDLEBURY_PAIRS]
    pairs = args.pairs.split(",") if args.pairs else default_pairs
    templates = ([int(t) for t in args.templates.split(",")] if args.templates
                 else ([9, 17, 25] if args.quick else list(ALL_TEMPLATES)))
    thresholds = ([float(t) for t in args.thresholds.split(",")] if args.thresholds
                  else list(ALL_THRESHOLDS))
    refines = tuple(int(n) for n in args.refine.split(","))
    rows: list[dict] = []
    for name in pairs:
        if name == "synthetic":
            rows += run_pair(name, synthetic_pair(args.quick), templates, thresholds,
                             args.weighting, references=not args.no_references,
                             refines=refines)
        elif name == "synthetic1024":
            rows += run_pair(name, synthetic_pair_1024(), templates, thresholds,
                             args.weighting, references=not args.no_references,
                             refines=refines)
        elif name in MIDDLEBURY_PAIRS:
            if not (MIDDLEBURY / name).is_dir():
                print(f"\n{name}: {MIDDLEBURY / name} not found; skipped")
                continue
            rows += run_pair(name, middlebury_pair(name), templates, thresholds,
                             references=not args.no_references, refines=refines)
        else:
            raise SystemExit(f"unknown pair {name!r}; choose from synthetic, synthetic1024, "
                             + ", ".join(MIDDLEBURY_PAIRS))
    verdict(rows)


if __name__ == "__main__":
    main()
