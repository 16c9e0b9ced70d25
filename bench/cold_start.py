"""First run of each stage against a warm run: what numba's compilation costs a user.

The demo's chains in miniature (:func:`demtool.warm.warm_steps`, the test suite's small
scenes, with the demo's ``--config configs/navcam.toml``; of ``warm``'s four SGM costs only
the demo's) run stage by stage as ``python -m demtool`` child processes, three times:

- **cold**: an empty numba cache (``NUMBA_CACHE_DIR`` = a fresh folder) — what a user
  paid before ``demtool warm`` (every kernel compiles in its first run);
- **installed**: after ``demtool warm`` filled another fresh folder — a user's first run
  after ``make install``;
- **warm**: the same again (everything cached, files in the OS cache).

and, with ``--read-only``, a fourth: the package copied to a folder made read-only
(``chmod a-w``; root can still write there, so the table also counts numba index files
found beside the copy afterwards: 0 means every kernel came from the shared cache) with
the documented setting: an installer ran ``demtool warm`` with ``NUMBA_CACHE_DIR``
pointing at a shared folder the users can write to, and the jobs set the same
``NUMBA_CACHE_DIR``.

Per stage (summed over its steps) the table prints wall and CPU seconds (user + system of
the child: on a shared machine CPU time is the load-independent number) and the excess of
a first run over the warm one, against the target of issue 28: ≤ 3 s.

Usage: ``.venv/bin/python bench/cold_start.py [--read-only] [--skip-cold] [--cache DIR]``;
about
3 × 1.5 min of CPU plus one ``demtool warm`` (about 1.5 min of CPU) per scenario that
needs one.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "navcam.toml"
TARGET_S = 3.0


def chain(work: Path) -> list[list[str]]:
    """The measured steps: warm's chain with the demo's preset and only the demo's SGM."""
    from demtool.warm import SGM_VARIANTS, warm_steps

    demo_cost = SGM_VARIANTS[0][0]
    steps = [s for s in warm_steps(work) if "--cost" not in s or s[s.index("--cost") + 1]
             == demo_cost]
    return [["--config", str(CONFIG), *s] for s in steps]


def run(args: list[str], env: dict[str, str]) -> tuple[float, float]:
    """Wall and CPU seconds of ``python -m demtool -q ARGS``; raises on failure."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "demtool", "-q", *args], env=env,
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                          check=False)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise RuntimeError(f"demtool {' '.join(args)} failed: {done.stderr.strip()[-500:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def run_chain(work: Path, env: dict[str, str]) -> dict[str, list[float]]:
    """Per stage: [wall, CPU] seconds summed over its steps."""
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    work.chmod(0o777)
    totals: dict[str, list[float]] = {}
    for step in chain(work):
        wall, cpu = run(step, env)
        entry = totals.setdefault(step[2], [0.0, 0.0])
        entry[0] += wall
        entry[1] += cpu
    return totals


def fresh_cache(base: Path, name: str) -> Path:
    folder = base / name
    folder.mkdir()
    folder.chmod(0o777)
    return folder


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--read-only", action="store_true",
                        help="also measure a read-only install run by another user")
    parser.add_argument("--skip-cold", action="store_true",
                        help="skip the empty-cache run (the 'before' column)")
    parser.add_argument("--skip-installed", action="store_true",
                        help="skip the first run after `demtool warm` (with --read-only)")
    parser.add_argument("--cache", type=Path, default=None,
                        help="a NUMBA_CACHE_DIR `demtool warm` has filled for this source "
                             "tree: the 'installed' run uses it instead of warming a new one")
    args = parser.parse_args(argv)
    base_env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    base_env["PYTHONPATH"] = str(ROOT)
    results: dict[str, dict[str, list[float]]] = {}
    warm_cost: dict[str, float] = {}
    with tempfile.TemporaryDirectory(prefix="cold_start_") as tmp:
        base = Path(tmp)
        base.chmod(0o755)
        if not args.skip_cold:
            env = {**base_env, "NUMBA_CACHE_DIR": str(fresh_cache(base, "cache_cold"))}
            results["cold"] = run_chain(base / "work", env)
        if args.cache is not None:
            env = {**base_env, "NUMBA_CACHE_DIR": str(args.cache)}
        else:
            env = {**base_env, "NUMBA_CACHE_DIR": str(fresh_cache(base, "cache_installed"))}
            warm_cost["installed"] = run(["warm"], env)[1]
        if not args.skip_installed:
            results["installed"] = run_chain(base / "work", env)
        results["warm"] = run_chain(base / "work", env)
        if args.read_only:
            install = base / "site"
            shutil.copytree(ROOT / "demtool", install / "demtool",
                            ignore=shutil.ignore_patterns("__pycache__"))
            for path in [install, *install.rglob("*")]:
                path.chmod(0o555 if path.is_dir() else 0o444)
            shared = fresh_cache(base, "cache_shared")
            env = {**base_env, "PYTHONPATH": str(install), "NUMBA_CACHE_DIR": str(shared)}
            warm_cost["read-only"] = run(["warm"], env)[1]  # the installer
            for path in [shared, *shared.rglob("*")]:  # a group-writable shared folder
                path.chmod(0o777 if path.is_dir() else 0o666)
            results["read-only"] = run_chain(base / "work", env)
            in_tree = list(install.rglob("*.nbi"))  # numba must not have cached beside it
            print(f"read-only install: {len(in_tree)} numba index files beside the package "
                  f"(expected 0), {len(list(shared.rglob('*.nbi')))} in NUMBA_CACHE_DIR")
    warm = results["warm"]
    firsts = [k for k in ("cold", "installed", "read-only") if k in results]
    print(f"\nfirst run vs warm run per stage, small demo scenes, {os.cpu_count()} CPU(s), "
          f"load average {os.getloadavg()[0]:.1f}; seconds wall / CPU; excess = first − "
          f"warm (CPU), target ≤ {TARGET_S:.0f} s after `demtool warm`")
    header = f"{'stage':<11}" + "".join(f"{k:>16}" for k in firsts) + f"{'warm':>16}"
    header += "".join(f"{'excess ' + k:>20}" for k in firsts)
    print(header)
    worst: dict[str, float] = {k: 0.0 for k in firsts}
    for stage in warm:
        row = f"{stage:<11}"
        for k in (*firsts, "warm"):
            wall, cpu = results[k][stage]
            row += f"{wall:9.1f} /{cpu:5.1f}"
        for k in firsts:
            excess = results[k][stage][1] - warm[stage][1]
            worst[k] = max(worst[k], excess)
            met = "" if k == "cold" else (" met" if excess <= TARGET_S else " NOT")
            row += f"{excess:16.1f}{met:>4}"
        print(row)
    total = f"{'all':<11}"
    for k in (*firsts, "warm"):
        total += f"{sum(v[0] for v in results[k].values()):9.1f} /" \
                 f"{sum(v[1] for v in results[k].values()):5.1f}"
    print(total)
    for k in firsts:
        note = f" (demtool warm: {warm_cost[k]:.0f} s CPU, once)" if k in warm_cost else ""
        print(f"largest excess, {k}: {worst[k]:.1f} s CPU{note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
