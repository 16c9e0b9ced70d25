"""Scale-out of demtool's stages: untiled against tiles on 1 and 2 workers (issue 47).

For each stage (``--stage``; the cases and how to add one: bench/_scale_cases.py) the
same inputs, made once (synthetic, with known truth), run as one child process each:

* untiled (the stage's default: for sgm, the default ``--max-memory-mb`` budget, so above
  about 2400² the aggregated cost does not fit and the pass runs in strips),
* ``--tile-size T --workers 1`` (tiles in the command's process),
* ``--tile-size T --workers 2``: two tiles at a time on threads of the command's process
  (demtool/tiling/local_threads.py; a job not declared thread-safe: a local Dask cluster
  of two worker processes), the row labelled with where the tiles ran (the sidecar's
  ``tiling.executor``),
* with ``--processes``, also ``--tile-size T --workers 2`` on a local Dask cluster of two
  worker processes (``DEMTOOL_TILE_PROCESSES=1``, as before issue 47's threads), for an
  A/B in one run.

Per run: wall time; CPU seconds of the process tree, two ways: user + system of the
command and every descendant it waited for (``resource.getrusage(RUSAGE_CHILDREN)``
before and after; Dask's forkserver workers may escape it) and the tree sampled every
50 ms with psutil (bench/scale.py's ``run_measured``; up to 50 ms per process missed);
peak resident memory of the tree (the sum of its processes' resident sets, same
sampler); the untiled run's cores in each of the stage's phases (CPU ÷ wall from the
output's sidecar ``timings_s``); the stage's quality against the truth; the efficiency
of the tiled runs: untiled CPU ÷ (workers × tiled wall) (1.0: the workers add no work
and lose no time; issue 47's target ≥ 75 % on 2 workers); and the agreement of each
tiled output with the untiled one.

Usage: ``.venv/bin/python bench/scale_out.py [--stage sgm-census|sgm-default|mapproject|
dem|refine|fuse|compare|all] [--size 4096] [--tile-size T] [--processes] [--repeat N]
[--record MACHINE]``
(``--size 1024 --tile-size 512`` runs in a few minutes on a quiet 2-core machine).  Each
stage records its own ``bench/results/<result>.json`` (sgm census: 53_scale_out.json).
Timings depend on the machine's load: compare only numbers from the same run.
"""

from __future__ import annotations

import argparse
import datetime
import math
import resource
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def children_cpu() -> float:
    """CPU seconds (user + system) of this process's waited-for descendants so far."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


PROCESSES_ENV = "DEMTOOL_TILE_PROCESSES"  # demtool.tiling.local_threads.PROCESSES_ENV


def executor_of(found: dict) -> str | None:
    """Where a tiled run's tiles ran: the sidecar's ``tiling.executor`` (None: not said)."""
    stack = [found]
    while stack:
        item = stack.pop()
        if isinstance(item, dict):
            if isinstance(item.get("tiling"), dict) and "executor" in item["tiling"]:
                return str(item["tiling"]["executor"])
            stack.extend(item.values())
        elif isinstance(item, list):
            stack.extend(item)
    return None


def measure(case, inputs: dict, folder: Path, tile: int, processes: bool = False,
            repeat: int = 1) -> list[dict] | None:
    """The runs of one case, ``repeat`` rounds of them one after the other (untiled, 1
    worker, 2 workers, …, then again: each round's runs in the same minute of the
    machine's load), merged by :func:`merge_rounds`; None (after printing why) when one
    fails."""
    rounds = []
    for _ in range(max(1, repeat)):
        results = one_round(case, inputs, folder, tile, processes)
        if results is None:
            return None
        rounds.append(results)
    results = merge_rounds(rounds)
    for r in results[1:]:
        r["agreement"] = case.agreement(inputs, results[0]["out"], r["out"])
    results[0]["agreement"] = "—"
    return results


def merge_rounds(rounds: list[list[dict]]) -> list[dict]:
    """Each run's median wall, CPU and phase cores over the rounds, its largest peak, and
    its efficiency in each round (against that round's untiled CPU: ``efficiencies``,
    whose median the table shows); the last round's outputs and quality."""
    from statistics import median

    merged = []
    for index, last in enumerate(rounds[-1]):
        runs = [results[index] for results in rounds]
        workers = last["workers"]
        efficiencies = [results[0]["cpu_s"] / (workers * results[index]["wall_s"])
                        for results in rounds] if workers else []
        merged.append({**last,
                       "wall_s": median(r["wall_s"] for r in runs),
                       "cpu_s": median(r["cpu_s"] for r in runs),
                       "sampled_cpu_s": median(r["sampled_cpu_s"] for r in runs),
                       "peak_mb": max(r["peak_mb"] for r in runs),
                       "cores": {p: median(r["cores"][p] for r in runs)
                                 for p in last["cores"]},
                       "efficiencies": efficiencies})
    return merged


def one_round(case, inputs: dict, folder: Path, tile: int,
              processes: bool = False) -> list[dict] | None:
    """One run of each configuration (no agreement yet); None when one fails."""
    import os

    from bench._scale_cases import phase_seconds, sidecar
    from bench.scale import run_measured

    tiled = ("--tile-size", str(tile))
    runs = [(case.untiled_label, 0, case.untiled_options(tile), False),
            ("tiled, 1 worker", 1, (*tiled, "--workers", "1"), False),
            ("tiled, 2 workers", 2, (*tiled, "--workers", "2"), False)]
    if processes:
        runs.append(("tiled, 2 worker processes", 2, (*tiled, "--workers", "2"), True))
    if not case.tile_size:
        runs = runs[:1]  # no worker processes: the untiled run's phases only
    results = []
    for label, workers, options, on_processes in runs:
        out = folder / f"{label.replace(' ', '_').replace(',', '')}{case.suffix}"
        before = children_cpu()
        saved = os.environ.pop(PROCESSES_ENV, None)
        if on_processes:
            os.environ[PROCESSES_ENV] = "1"
        try:
            result = run_measured([*case.command(inputs, out), *options])
        finally:
            os.environ.pop(PROCESSES_ENV, None)
            if saved is not None:
                os.environ[PROCESSES_ENV] = saved
        cpu = children_cpu() - before
        if result["code"] != 0:
            print(f"{case.stage}, {label}: failed\n{result['stderr']}")
            return None
        found = sidecar(out, case.sidecar)
        if workers >= 2 and not on_processes:
            label = f"{label} ({executor_of(found) or 'executor not recorded'})"
        phases = phase_seconds(found, case.phases)
        cores = {p: (phases[f"{p}_cpu"] / phases[p] if phases.get(p) else math.nan)
                 for p in case.phases}
        results.append({"run": label, "workers": workers, "out": out,
                        "wall_s": result["wall_s"], "cpu_s": cpu,
                        "sampled_cpu_s": result["cpu_s"], "peak_mb": result["peak_mb"],
                        "cores": cores, "quality": case.quality(inputs, out)})
    return results


def table(case, results: list[dict]) -> tuple[list[str], list[list[str]]]:
    """The recorded columns and rows (and the printed table); with rounds, the medians
    (efficiency: the median of the rounds' own) and each round's efficiency."""
    from statistics import median

    untiled = results[0]
    quality = list(untiled["quality"])
    columns = ["run", "wall s", "CPU s (waited-for tree)", "CPU s (sampled tree)",
               "peak MB (tree)",
               *(f"{case.untiled_label} {p} cores (CPU ÷ wall)" for p in case.phases),
               "efficiency", "wall ÷ untiled", *quality, "agreement with untiled"]
    repeated = len(results[-1]["efficiencies"]) > 1  # (the untiled run has none)
    if repeated:
        columns.insert(columns.index("efficiency") + 1, "efficiency in each round")
    rows = []
    for r in results:
        rounds = r["efficiencies"]
        eff = median(rounds) if rounds else None
        cores = [f"{r['cores'][p]:.2f}" if r["workers"] == 0 else "—" for p in case.phases]
        rows.append([r["run"], f"{r['wall_s']:.1f}", f"{r['cpu_s']:.1f}",
                     f"{r['sampled_cpu_s']:.1f}", f"{r['peak_mb']:.0f}", *cores,
                     f"{100 * eff:.0f} %" if eff is not None else "—",
                     *([", ".join(f"{100 * e:.0f}" for e in rounds) + " %" if rounds
                        else "—"] if repeated else []),
                     f"{r['wall_s'] / untiled['wall_s']:.2f}",
                     *(r["quality"].get(q, "—") for q in quality), r["agreement"]])
    widths = [max(len(c), *(len(row[i]) for row in rows)) for i, c in enumerate(columns)]
    for line in (columns, *rows):
        print("  ".join(cell.ljust(w) for cell, w in zip(line, widths, strict=True)))
    return columns, rows


def main(argv: list[str] | None = None) -> int:
    from bench._scale_cases import CASES

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stage", choices=[*CASES, "all"], default="sgm-census",
                        help="the stage's case (bench/_scale_cases.py), or all")
    parser.add_argument("--size", type=int, default=4096, help="image side, px")
    parser.add_argument("--tile-size", type=int, default=None,
                        help="tile side of the tiled runs (default: the case's)")
    parser.add_argument("--record", metavar="MACHINE", default=None,
                        help="write each stage's bench/results/<result>.json, machine "
                             "described so")
    parser.add_argument("--note", default="", help="appended to the recorded notes")
    parser.add_argument("--record-as", metavar="SUFFIX", default="",
                        help="record into bench/results/<result>_SUFFIX.json instead: a "
                             "second size of a stage beside its usual one (e.g. 8192)")
    parser.add_argument("--repeat", type=int, default=1, metavar="N",
                        help="N rounds of the runs, one round after the other: the table "
                             "gives medians and each round's efficiency (a shared machine's "
                             "load moves a single run's efficiency by several points)")
    parser.add_argument("--processes", action="store_true",
                        help="also run the 2 workers as a local Dask cluster of processes "
                             "(DEMTOOL_TILE_PROCESSES=1), for an A/B in one run")
    args = parser.parse_args(argv)
    cases = list(CASES.values()) if args.stage == "all" else [CASES[args.stage]]
    status = 0
    for case in cases:
        tile = args.tile_size or case.tile_size
        if case.tile_size and not args.tile_size and tile >= args.size:
            tile = args.size // 2  # one tile would take the untiled path: no tiles to measure
            print(f"{case.stage}: tiles of {tile} px (the case's {case.tile_size} px would "
                  f"cover the {args.size}² image in one tile, run untiled)")
        with tempfile.TemporaryDirectory() as work:
            folder = Path(work) / f"{case.stage}_{args.size}"
            inputs = case.prepare(folder, args.size)
            results = measure(case, inputs, folder, tile, args.processes, args.repeat)
            if results is None:
                status = 1
                continue
            print(f"\n{case.title(args.size, tile)}"
                  + (f", tile {tile}" if case.tile_size else ""))
            columns, rows = table(case, results)
        if args.record:
            record(case, args, tile, columns, rows)
    return status


def record(case, args, tile: int, columns: list[str], rows: list[list[str]]) -> None:
    from bench.validation_page import write_result

    stage = "" if case.stage == "sgm-census" else f" --stage {case.stage}"
    stage += " --processes" if args.processes else ""
    stage += f" --repeat {args.repeat}" if args.repeat > 1 else ""
    write_result(
        f"{case.result}_{args.record_as}" if args.record_as else case.result,
        section="Large images", order=53,
        title=case.title(args.size, tile),
        command=f"python bench/scale_out.py{stage} --size {args.size}"
                + (f" --tile-size {tile}" if case.tile_size else ""),
        date=datetime.date.today().isoformat(), machine=args.record,
        columns=columns, rows=rows,
        notes=("Efficiency: untiled CPU ÷ (workers × tiled wall); issue 47's targets: "
               "untiled phases on every core (sgm's match ≥ 1.8 cores), 2-worker "
               "efficiency ≥ 75 % (sgm census at 4096²: 2-worker wall ≤ 0.6× untiled, peak "
               "≤ 2 GB). CPU: getrusage(RUSAGE_CHILDREN) (the processes the command waited "
               "for: Dask's forkserver workers may escape it) beside the tree's CPU sampled "
               "every 50 ms with psutil (may miss up to 50 ms per process); peak: sum of "
               "the tree's resident sets sampled every 50 ms. 2 workers: threads of the "
               "command's process (the row says where the tiles ran); 2 worker "
               "processes: a local Dask cluster (DEMTOOL_TILE_PROCESSES=1). "
               + (f"{args.repeat} rounds of the runs one after the other: medians of wall, "
                  "CPU and phase cores, the largest peak, and the median of the rounds' "
                  "efficiencies (each against its round's untiled CPU), listed. "
                  if args.repeat > 1 else "")
               + args.note).strip())


if __name__ == "__main__":
    raise SystemExit(main())
