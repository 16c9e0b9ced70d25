"""Scale-out of `demtool sgm --cost census`: untiled against tiles on 1 and 2 workers.

Issue 47's first table: the same synthetic pair with exact truth (bench/_scale_pairs.py,
disparities 18 … 78 px, ``--num-disparities 96``), matched as one child process each:

* untiled (the default ``--max-memory-mb`` budget: above about 2400² the aggregated cost
  does not fit and the pass runs in strips),
* ``--tile-size T --workers 1`` (tiles in the command's process),
* ``--tile-size T --workers 2`` (a local Dask cluster of two worker processes).

Per run: wall time; CPU seconds of the process tree, two ways: user + system of the
command and every descendant it waited for (``resource.getrusage(RUSAGE_CHILDREN)``
before and after; Dask's forkserver workers may escape it) and the tree sampled every
50 ms with psutil (bench/scale.py's ``run_measured``; up to 50 ms per process missed);
peak resident memory of the tree (the sum of its processes' resident sets, same
sampler); the untiled match phase's cores (its CPU ÷ wall from the output's sidecar);
bad-2 against the truth; and the efficiency of the tiled runs: untiled CPU ÷ (workers ×
tiled wall) (1.0: the workers add no work and lose no time; issue 47's target ≥ 75 % on
2 workers).

Usage: ``.venv/bin/python bench/scale_out.py [--size 4096] [--tile-size 1024]
[--record MACHINE]`` (``--size 1024 --tile-size 512`` runs in a few minutes on a quiet
2-core machine).  Timings depend on the machine's load: compare only numbers from the
same run.
"""

from __future__ import annotations

import argparse
import datetime
import json
import resource
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def children_cpu() -> float:
    """CPU seconds (user + system) of this process's waited-for descendants so far."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def phase_seconds(sidecar: dict) -> dict:
    """The first mapping in the sidecar that holds the "match" phase's seconds."""
    stack = [sidecar]
    while stack:
        item = stack.pop()
        if isinstance(item, dict):
            if "match" in item and "match_cpu" in item:
                return item
            stack.extend(item.values())
        elif isinstance(item, list):
            stack.extend(item)
    return {}


def main(argv: list[str] | None = None) -> int:
    from bench._scale_pairs import write_pair
    from bench.scale import bad2, run_measured, sgm_command
    from demtool import io as dio

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=4096, help="image side, px")
    parser.add_argument("--tile-size", type=int, default=1024)
    parser.add_argument("--record", metavar="MACHINE", default=None,
                        help="write bench/results/53_scale_out.json, machine described so")
    parser.add_argument("--note", default="", help="appended to the recorded notes")
    args = parser.parse_args(argv)

    runs = (("untiled", 0, ()),
            ("tiled, 1 worker", 1, ("--tile-size", str(args.tile_size), "--workers", "1")),
            ("tiled, 2 workers", 2, ("--tile-size", str(args.tile_size), "--workers", "2")))
    results = []
    with tempfile.TemporaryDirectory() as work:
        folder = Path(work) / f"pair_{args.size}"
        write_pair(folder, args.size)
        truth = np.load(folder / "truth.npy")
        for label, workers, options in runs:
            out = folder / f"{label.replace(' ', '_').replace(',', '')}.tif"
            before = children_cpu()
            result = run_measured(sgm_command(folder, out, *options))
            cpu = children_cpu() - before
            if result["code"] != 0:
                print(f"{label}: failed\n{result['stderr']}")
                return 1
            error, density = bad2(dio.read_raster(out).data, truth)
            phases = phase_seconds(json.loads(Path(f"{out}.json").read_text()))
            match_cores = (phases["match_cpu"] / phases["match"]
                           if phases.get("match") else float("nan"))
            results.append({"run": label, "workers": workers, "wall_s": result["wall_s"],
                            "cpu_s": cpu, "sampled_cpu_s": result["cpu_s"],
                            "peak_mb": result["peak_mb"], "bad2": error,
                            "density": density, "match_cores": match_cores})
    untiled = results[0]
    rows = []
    print(f"sgm census, {args.size}² × 96, tile {args.tile_size}")
    print(f"{'run':<17} {'wall s':>7} {'CPU s':>7} {'sampled':>7} {'peak MB':>8} "
          f"{'match cores':>11} {'eff.':>6} {'bad-2 %':>8}")
    for r in results:
        eff = (untiled["cpu_s"] / (r["workers"] * r["wall_s"]) if r["workers"] else None)
        cores = f"{r['match_cores']:.2f}" if r["workers"] == 0 else "—"
        eff_text = f"{100 * eff:.0f} %" if eff is not None else "—"
        print(f"{r['run']:<17} {r['wall_s']:7.1f} {r['cpu_s']:7.1f} {r['sampled_cpu_s']:7.1f} "
              f"{r['peak_mb']:8.0f} "
              f"{cores:>11} {eff_text:>6} {100 * r['bad2']:8.2f}")
        rows.append([r["run"], f"{r['wall_s']:.1f}", f"{r['cpu_s']:.1f}",
                     f"{r['sampled_cpu_s']:.1f}",
                     f"{r['peak_mb']:.0f}", cores, eff_text,
                     f"{r['wall_s'] / untiled['wall_s']:.2f}", f"{100 * r['bad2']:.2f}"])
    if args.record:
        from bench.validation_page import write_result

        write_result(
            "53_scale_out", section="Large images", order=53,
            title=f"Scale-out of sgm census ({args.size}² × 96): untiled vs tiles on 1 and "
                  "2 workers",
            command=f"python bench/scale_out.py --size {args.size} "
                    f"--tile-size {args.tile_size}",
            date=datetime.date.today().isoformat(), machine=args.record,
            columns=["run", "wall s", "CPU s (waited-for tree)", "CPU s (sampled tree)",
                     "peak MB (tree)",
                     "untiled match cores (CPU ÷ wall)", "efficiency", "wall ÷ untiled",
                     "bad-2 %"],
            rows=rows,
            notes=("Efficiency: untiled CPU ÷ (workers × tiled wall); issue 47's targets: "
                   "untiled match phase ≥ 1.8 cores, 2-worker wall ≤ 0.6× untiled, "
                   "efficiency ≥ 75 %, peak ≤ 2 GB at 4096². CPU: getrusage(RUSAGE_CHILDREN) "
                   "(the processes the command waited for: Dask's forkserver workers may "
                   "escape it) beside the tree's CPU sampled every 50 ms with psutil (may "
                   "miss up to 50 ms per process); peak: sum of the tree's resident sets "
                   "sampled every 50 ms. " + args.note).strip())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
