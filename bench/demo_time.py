"""Time ``make demo`` from a fresh clone, step by step, for one or more commits.

For each ``--ref`` (default: this checkout's HEAD) the repository is cloned into a
temporary folder, its virtualenv installed (``make .venv/.installed``: the user's
install, timed on its own) and ``make demo`` run (the chain, timed on its own; numba's
kernels compile inside it, as for a user: a fresh clone has no kernel cache).  Every
recipe make runs goes through a small wrapper (make's ``SHELL``) that records its wall
time, CPU time (user + system of the recipe's process tree) and peak resident memory,
so a slower demo shows which step grew.  With several refs the installs run back to
back, then the chains, so that each pair of numbers saw the same load; on a shared
machine judge by CPU seconds, not by wall time.  The comparison tables the demos print
are checked to be identical across refs.

With ``--kernels``, every process of the chain logs numba's compile events
(``numba.core.event``, kind ``numba:compile``: a kernel compiled, not read from the cache)
through a ``sitecustomize`` module put on ``PYTHONPATH``, and a table lists each kernel
compiled: the CPU seconds of its compile (the compiling thread's, kernels it calls
compiled inside it included), in how many processes and for how many type signatures
(more than one of either is a compile a fresh clone pays more than once), whether it is
``parallel=True``, and the stages that compiled it.

Usage: ``.venv/bin/python bench/demo_time.py [--ref REF ...] [--jobs N] [--goal GOAL]
[--keep DIR] [--kernels] [--record MACHINE]`` (``--record`` writes bench/results/03_demo_time.json;
then ``python bench/validation_page.py``).  ``--goal`` builds another make goal instead
of ``demo`` (a quick check: ``--goal work/demo/scene/scene.json``).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# make's SHELL: runs the recipe with bash, then appends one JSON line to $DEMO_TIME_LOG.
WRAPPER = """#!{python}
import json, os, resource, subprocess, sys, time
start = time.perf_counter()
code = subprocess.call(["/bin/bash", *sys.argv[1:]])
usage = resource.getrusage(resource.RUSAGE_CHILDREN)
with open(os.environ["DEMO_TIME_LOG"], "a") as log:
    log.write(json.dumps({{"command": sys.argv[-1], "start": time.time(),
                          "wall_s": time.perf_counter() - start,
                          "cpu_s": usage.ru_utime + usage.ru_stime,
                          "peak_mb": usage.ru_maxrss / 1024.0}}) + "\\n")
sys.exit(code)
"""

# PYTHONPATH's sitecustomize with --kernels: once numba.core.event is imported, a listener
# appends one JSON line per compile (not per cache load) to $DEMO_KERNEL_LOG.
KERNEL_HOOK = """import importlib.abc, importlib.util, json, os, sys, time


def _listen():
    from numba.core import event

    started = []

    class Compiles(event.Listener):
        def on_start(self, ev):
            started.append((time.perf_counter(), time.thread_time()))

        def on_end(self, ev):
            wall, cpu = started.pop()
            data = ev.data or {}
            function = getattr(data.get("dispatcher"), "py_func", None)
            options = getattr(data.get("dispatcher"), "targetoptions", {})
            row = {"pid": os.getpid(), "stage": next((a for a in sys.argv[1:] if a in
                                                       STAGES), "?"),
                   "kernel": getattr(function, "__module__", "?") + "."
                   + getattr(function, "__qualname__", "?"),
                   "signature": str(data.get("args")), "nested": len(started),
                   "wall_s": time.perf_counter() - wall, "cpu_s": time.thread_time() - cpu,
                   "parallel": bool(options.get("parallel"))}
            with open(os.environ["DEMO_KERNEL_LOG"], "a") as log:
                log.write(json.dumps(row) + "\\n")

    event.register("numba:compile", Compiles())


STAGES = {STAGES!r}


class _Finder(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name != "numba.core.event":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)
        run = spec.loader.exec_module

        def exec_module(module):
            run(module)
            sys.modules[name] = module
            _listen()

        spec.loader.exec_module = exec_module
        return spec


if os.environ.get("DEMO_KERNEL_LOG"):
    sys.meta_path.insert(0, _Finder())
"""


def step_name(command: str) -> str | None:
    """A short name for a recipe (``sgm stereo_frame/disparity_sgm.tif``); None for the
    sub-makes (their steps are logged one by one) and make's ``$(shell …)`` calls."""
    words = command.replace("\\\n", " ").split()
    if not words or "--no-print-directory" in words or words[0] in ("tr", "touch"):
        return None
    if words[0] == "test" and "venv" in words:
        return "venv"
    if words[0].endswith("/demtool"):
        words = [w for w in words[1:] if w != "--config"]
        words = words[1:] if words and words[0].endswith(".toml") else words
        stage = words[0] if words else "?"
        out = next((words[i + 1] for i, w in enumerate(words[:-1]) if w == "--out"), "")
        return f"{stage} {out.removeprefix('work/demo/')}".strip()
    if "pip" in words and "install" in words:
        return "pip install " + words[-1]
    return " ".join(words[:4])[:60]


def run_logged(args: list[str], cwd: Path, log: Path, kernel_log: Path | None = None) -> dict:
    """Run ``args`` (a make command) in ``cwd``; its wall and CPU time and stdout.  With
    ``kernel_log``, numba's compiles are logged there (:data:`KERNEL_HOOK`)."""
    env = dict(os.environ, DEMO_TIME_LOG=str(log))
    if kernel_log is not None:
        env["DEMO_KERNEL_LOG"] = str(kernel_log)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(kernel_log.parent / "hook"),
                                                          env.get("PYTHONPATH")]))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode:
        sys.stderr.write(done.stdout[-3000:] + done.stderr[-3000:])
        raise SystemExit(f"Error: {' '.join(args)} failed in {cwd} (exit {done.returncode})")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": wall, "cpu_s": cpu, "stdout": done.stdout}


def steps(log: Path) -> dict[str, dict]:
    """The logged recipes by name (in the order they started)."""
    rows = [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
    out: dict[str, dict] = {}
    for row in sorted(rows, key=lambda r: r["start"] - r["wall_s"]):
        name = step_name(row["command"])
        if name:
            while name in out:
                name += "'"
            out[name] = row
    return out


def kernel_table(log: Path) -> list[list]:
    """The kernels compiled in a chain (the log of :data:`KERNEL_HOOK`), most CPU first:
    [kernel, compile CPU s, compile wall s, processes, signatures, parallel, stages]."""
    rows = [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
    by_kernel: dict[str, list[dict]] = {}
    for row in rows:
        if not row["nested"]:  # callees compile inside their caller's time
            by_kernel.setdefault(row["kernel"], []).append(row)
    table = [[name, sum(r["cpu_s"] for r in group), sum(r["wall_s"] for r in group),
              len({r["pid"] for r in group}), len({r["signature"] for r in group}),
              group[0]["parallel"], ",".join(sorted({r["stage"] for r in group}))]
             for name, group in by_kernel.items()]
    return sorted(table, key=lambda row: -row[1])


def print_kernels(commit: str, table: list[list]) -> None:
    """Print :func:`kernel_table`'s rows and their total."""
    print(f"\nnumba kernels compiled in {commit}'s chain: {len(table)}, "
          f"{sum(r[1] for r in table):.1f} CPU s ({sum(r[2] for r in table):.1f} s wall)")
    print(f"{'kernel':<64} {'CPU s':>6} {'wall s':>7} {'procs':>5} {'sigs':>4} {'par':>3} "
          "stages")
    for name, cpu, wall, procs, sigs, parallel, stages in table:
        print(f"{name[-64:]:<64} {cpu:6.1f} {wall:7.1f} {procs:5d} {sigs:4d} "
              f"{'yes' if parallel else '':>3} {stages}")


def products_table(stdout: str) -> str:
    """The demo's closing comparison table (``demtool.compare.summary``'s, on stdout:
    its header and the lines after it)."""
    lines = stdout.splitlines()
    heads = [i for i, line in enumerate(lines) if line.startswith("product ")]
    return "\n".join(lines[heads[-1]:]) if heads else ""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ref", action="append", help="commit to time (repeatable; "
                        "default: this checkout's HEAD)")
    parser.add_argument("--jobs", type=int, help="DEMO_JOBS (default: the Makefile's)")
    parser.add_argument("--goal", default="demo", help="make goal (default demo)")
    parser.add_argument("--keep", type=Path, help="clone into this folder and keep it")
    parser.add_argument("--kernels", action="store_true",
                        help="log numba's compiles in the chain and list the kernels")
    parser.add_argument("--record", metavar="MACHINE",
                        help="write bench/results/03_demo_time.json, naming the machine")
    args = parser.parse_args(argv)
    refs = args.ref or ["HEAD"]
    commits = [subprocess.run(["git", "rev-parse", "--short", r], cwd=ROOT, check=True,
                              capture_output=True, text=True).stdout.strip() for r in refs]
    base = args.keep or Path(tempfile.mkdtemp(prefix="demo_time_"))
    base.mkdir(parents=True, exist_ok=True)
    wrapper = base / "timed_shell"
    wrapper.write_text(WRAPPER.format(python=sys.executable))
    wrapper.chmod(0o755)
    if args.kernels:
        sys.path.insert(0, str(ROOT))
        from demtool.stages import STAGES

        (base / "hook").mkdir(exist_ok=True)
        (base / "hook" / "sitecustomize.py").write_text(
            KERNEL_HOOK.replace("{STAGES!r}", repr(sorted(STAGES))))
    make = ["make", f"SHELL={wrapper}"] + ([f"DEMO_JOBS={args.jobs}"] if args.jobs else [])
    clones = {}
    for commit in commits:
        clone = base / commit
        if not clone.exists():
            subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        subprocess.run(["git", "checkout", "-q", commit], cwd=clone, check=True)
        clones[commit] = clone
    load = os.getloadavg()[0]
    install = {c: run_logged(make + [".venv/.installed"], clones[c], base / f"{c}.install")
               for c in commits}
    chain = {c: run_logged(make + [args.goal], clones[c], base / f"{c}.chain",
                           base / f"{c}.kernels" if args.kernels else None)
             for c in commits}
    load = max(load, os.getloadavg()[0])
    tables = {c: products_table(chain[c]["stdout"]) for c in commits}
    per_step = {c: {**steps(base / f"{c}.install"), **steps(base / f"{c}.chain")}
                for c in commits}
    names = list(dict.fromkeys(n for c in commits for n in per_step[c]))
    head = f"{'step':<44}" + "".join(f" {c + ' wall':>13} {'CPU s':>7}" for c in commits)
    print(head)
    rows = []
    for name in names + ["install (total)", "chain (total)"]:
        cells = []
        for c in commits:
            row = (install[c] if name == "install (total)" else chain[c]
                   if name == "chain (total)" else per_step[c].get(name))
            cells += [f"{row['wall_s']:.1f}", f"{row['cpu_s']:.1f}"] if row else ["—", "—"]
        pairs = zip(cells[::2], cells[1::2], strict=True)
        print(f"{name:<44}" + "".join(f" {w:>13} {u:>7}" for w, u in pairs))
        rows.append([name] + cells)
    same = len(set(tables.values())) == 1
    print(f"load average up to {load:.1f}; products tables "
          f"{'identical' if same else 'DIFFER'} across {', '.join(commits)}")
    if same and tables[commits[0]]:
        print(tables[commits[0]])
    if not same:
        for c in commits:
            print(f"--- {c}\n{tables[c]}")
    if args.kernels:
        for c in commits:
            print_kernels(c, kernel_table(base / f"{c}.kernels"))
    if args.record:
        import datetime

        sys.path.insert(0, str(ROOT / "bench"))
        from validation_page import write_result

        columns = ["step"] + [f"{c} {k}" for c in commits for k in ("wall s", "CPU s")]
        write_result(
            "03_demo_time", section="Demo products", order=3,
            title="`make demo` from a fresh clone, step by step (install and chain)",
            command="python bench/demo_time.py " + " ".join(f"--ref {r}" for r in refs),
            date=datetime.date.today().isoformat(), machine=args.record,
            columns=columns, rows=rows,
            notes=(f"Load average up to {load:.1f} during the run.  Install: venv, pip, "
                   "editable install, compileall (pip cache warm when the machine has "
                   "installed demtool before).  Chain: make demo with its numba kernels "
                   "compiled in the run (a fresh clone has no kernel cache).  CPU s: user + "
                   "system of each step's process tree.  Products tables "
                   + ("identical across the commits." if same else "DIFFER.")))
    return 0


if __name__ == "__main__":
    sys.exit(main())
