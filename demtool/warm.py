"""Compile every cached numba kernel once, at install, instead of in a user's first run.

:func:`warm` runs the demo's chains (``make demo``: the BAM and SIAM routes, area-based
matching, SfS refinement, the calibrated frame pair and the map-projected line-scan
pair) in miniature in a temporary folder, each stage as its own ``demtool`` process,
so the kernels compile with exactly the argument types the stages give them and land
in the cache :mod:`demtool.jitcache` chose.  Every cost and path count of ``sgm`` runs
once, since each cost compiles its own kernels.  The scenes are the test suite's small
ones (192 px images); the products are thrown away.

First, :func:`compile_bytecode` writes the package's bytecode (``__pycache__/*.pyc``)
where the package folder is writable: an editable install (``make install``) has none,
and where Python may not write it (``PYTHONDONTWRITEBYTECODE``, or users of a shared
install that only its administrator can write) every command would compile demtool's
modules from source again (0.13 s of a small ``sgm`` run's 1.3 s).
"""

from __future__ import annotations

import compileall
import importlib
import importlib.util
import os
import pkgutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from demtool import jitcache
from demtool.errors import InputError, ProcessingError
from demtool.logs import get_logger

log = get_logger(__name__)

# the test suite's small scene (tests/conftest.py), big enough for every stage to succeed
SMALL_SCENE = ["--seed", "0", "--size", "256", "--views", "4", "--image-size", "192",
               "--craters", "20", "--crater-max", "50", "--boulders", "100"]
SENSOR_SCENE = ["--size", "128", "--image-size", "128"]
SGM_VARIANTS = (("mi", 16), ("hmi", 8), ("census", 8), ("ad", 8), ("auto", 8))


def warm_steps(work: Path) -> list[list[str]]:
    """The ``demtool`` argument lists :func:`warm` runs in order, writing under ``work``."""
    scene, stereo, w = work / "scene", work / "stereo", work
    steps: list[list] = [
        ["synth", "--out", scene, *SMALL_SCENE],
        ["select", *(scene / f"view_{i:02d}.tif" for i in range(4)),
         "--target", scene / "view_00.tif", "--cameras", scene / "cameras.npz",
         "--scene", scene / "scene.json", "--out", w / "selection.json"],
        ["bundle", w / "selection.json", "--cameras", scene / "cameras.npz",
         "--align-cameras", scene / "cameras.npz", "--out", w / "bundle.npz"],
        ["dem", "--points", w / "bundle.npz", "--scene", scene / "scene.json",
         "--out", w / "dem_bam.tif"],
        ["rectify", scene / "view_00.tif", scene / "view_01.tif", "--out", stereo],
    ]
    pair = [stereo / "left_rect.tif", stereo / "right_rect.tif", "--rectify",
            stereo / "rectify.npz"]
    for cost, paths in SGM_VARIANTS:
        steps.append(["sgm", *pair, "--cost", cost, "--paths", str(paths),
                      "--out", stereo / f"disparity_{cost}.tif"])
    disparity = stereo / f"disparity_{SGM_VARIANTS[0][0]}.tif"
    steps += [
        ["dem", "--disparity", disparity, "--rectify", stereo / "rectify.npz",
         "--cameras", scene / "cameras.npz", "--scene", scene / "scene.json",
         "--out", w / "dem_siam.tif"],
        ["dem", "--disparity", disparity, "--rectify", stereo / "rectify.npz",
         "--reference", w / "dem_bam.tif", "--out", w / "dem_siam_projective.tif"],
        ["match", *pair, "--out", stereo / "disparity_match.tif"],
        ["refine", scene / "view_00.tif", w / "dem_siam.tif", "--out", w / "dem_refined.tif"],
        ["compare", w / "dem_siam.tif", scene / "truth_dem_target.tif",
         "--out", w / "reports" / "dem_siam"],
    ]
    # map-projected line-scan pair (issue 12)
    ls, lst = work / "scene_linescan", work / "stereo_linescan"
    orthos = [lst / "left_ortho.tif", lst / "right_ortho.tif"]
    steps += [
        ["synth", "--sensor", "linescan", *SENSOR_SCENE, "--out", ls],
        ["camera", ls / "view_00.json", ls / "view_01.json"],
        ["mapproject", ls / "view_00.tif", "--sensor", ls / "view_00.json", "--height", "0",
         "--out", orthos[0]],
        ["mapproject", ls / "view_01.tif", "--sensor", ls / "view_01.json", "--height", "0",
         "--grid-like", orthos[0], "--out", orthos[1]],
        ["sgm", *orthos, "--out", lst / "disparity_sgm.tif"],
        ["dem", "--disparity", lst / "disparity_sgm.tif", "--mapprojected", *orthos,
         "--error-out", w / "dem_linescan_error.tif", "--out", w / "dem_linescan.tif"],
        ["match", *orthos, "--out", lst / "disparity_match.tif"],
        ["refine", ls / "view_00.tif", w / "dem_linescan.tif", "--sensor", ls / "view_00.json",
         "--spike-threshold", "4", "--out", w / "dem_linescan_refined.tif"],
        ["compare", w / "dem_linescan.tif", ls / "truth_dem_map.tif",
         "--out", w / "reports" / "dem_linescan"],
    ]
    # calibrated frame pair (issue 11)
    fr, frs = work / "scene_frame", work / "stereo_frame"
    steps += [
        ["synth", "--sensor", "frame", *SENSOR_SCENE, "--out", fr],
        ["rectify", fr / "view_00.tif", fr / "view_01.tif", "--sensor-left",
         fr / "view_00.json", "--sensor-right", fr / "view_01.json", "--out", frs],
        ["sgm", frs / "left_rect.tif", frs / "right_rect.tif", "--rectify",
         frs / "rectify.npz", "--out", frs / "disparity_sgm.tif"],
        ["dem", "--disparity", frs / "disparity_sgm.tif", "--rectify", frs / "rectify.npz",
         "--error-out", w / "dem_frame_error.tif", "--out", w / "dem_frame.tif"],
        # a block's pairs and the fusion of DEMs (issue 29; the pair's DEM twice)
        ["pairs", fr / "view_00.json", fr / "view_01.json", "--min-bh", "0.01", "--max-bh",
         "10", "--min-convergence", "0", "--out", frs / "pairs.txt"],
        ["fuse", w / "dem_frame.tif", w / "dem_frame.tif", "--out", w / "dem_fused.tif"],
    ]
    return [[str(a) for a in step] for step in steps]


def step_label(step: list[str]) -> str:
    """The stage and its kernel-choosing options, e.g. ``sgm --cost mi --paths 16``."""
    label = [step[0]]
    for key in ("--sensor", "--cost", "--paths", "--points", "--reference", "--mapprojected"):
        if key in step:
            value = step[step.index(key) + 1]
            label.append(key if key in ("--points", "--reference", "--mapprojected")
                         else f"{key} {value}")
    return " ".join(label)


def import_kernel_modules() -> None:
    """Import every demtool module that defines numba kernels (for :func:`coverage`)."""
    import demtool

    for info in pkgutil.walk_packages(demtool.__path__, "demtool."):
        if info.ispkg or ".commands." in info.name:
            continue
        spec = importlib.util.find_spec(info.name)
        origin = getattr(spec, "origin", None)
        if origin and "njit" in Path(origin).read_text(encoding="utf-8"):
            importlib.import_module(info.name)


def coverage() -> tuple[list[str], list[str]]:
    """Cached kernels (``module.function``) with and without a cache index on disk."""
    import_kernel_modules()
    kernels = jitcache.cached_kernels()
    return [k for k, ok in kernels if ok], [k for k, ok in kernels if not ok]


def compile_bytecode(package_dir: Path | None = None) -> bool:
    """Write the bytecode of every module of the package (``compileall``, all cores).

    Python checks a ``.pyc`` against its source's modification time and size, so a file
    edited later is compiled from source again, never run stale.

    Parameters
    ----------
    package_dir : Path, optional
        The package folder (default: the installed ``demtool``).

    Returns
    -------
    bool
        False when the folder cannot be written (a non-editable ``pip install`` wrote
        the bytecode itself); True when every module compiled.

    Raises
    ------
    ProcessingError
        A module does not compile (a syntax error in an edited source).
    """
    folder = jitcache.PACKAGE_DIR if package_dir is None else Path(package_dir)
    if not jitcache.writable(folder):
        return False
    if not compileall.compile_dir(folder, quiet=1, workers=0):
        raise ProcessingError(f"{folder}: a module does not compile (python -m compileall "
                              f"{folder} names it)")
    return True


def warm(*, work: Path | None = None,
         report: Callable[[str, float], None] | None = None) -> dict[str, float]:
    """Write the package's bytecode (:func:`compile_bytecode`), then run
    :func:`warm_steps` as ``demtool`` child processes, filling numba's cache.

    Parameters
    ----------
    work : Path, optional
        Folder for the miniature products (default: a temporary folder, removed after).
    report : callable, optional
        Called with (step, seconds) after each step (the first: "bytecode", when the
        package folder is writable).

    Returns
    -------
    dict of str to float
        Wall seconds per stage name, summed over its steps (and "bytecode").

    Raises
    ------
    InputError
        ``NUMBA_CACHE_DIR`` names a folder that cannot be written (numba would ignore
        it and the users' runs would not find the kernels).
    ProcessingError
        A step failed (its command and the last line of its error output).
    """
    folder = jitcache.choose_cache_dir()
    if folder is not None and not jitcache.usable(folder):
        raise InputError(f"{jitcache.ENV}={folder}: cannot create or write that folder, so "
                         "numba would not use it; make it writable or point "
                         f"{jitcache.ENV} elsewhere")
    if work is None:
        with tempfile.TemporaryDirectory(prefix="demtool_warm_") as tmp:
            return warm(work=Path(tmp), report=report)
    env = dict(os.environ)
    folder = jitcache.configure()
    if folder is not None:
        env[jitcache.ENV] = str(folder)
    seconds: dict[str, float] = {}
    start = time.perf_counter()
    if compile_bytecode():
        seconds["bytecode"] = time.perf_counter() - start
        if report is not None:
            report("bytecode", seconds["bytecode"])
    for step in warm_steps(Path(work)):
        start = time.perf_counter()
        result = subprocess.run([sys.executable, "-m", "demtool", "-q", *step], env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        elapsed = time.perf_counter() - start
        if result.returncode != 0:
            lines = result.stderr.strip().splitlines() or ["(no error output)"]
            raise ProcessingError(f"warm-up step `demtool {' '.join(step)}` failed "
                                  f"(status {result.returncode}): {lines[-1]}")
        seconds[step[0]] = seconds.get(step[0], 0.0) + elapsed
        if report is not None:
            report(step_label(step), elapsed)
    return seconds
