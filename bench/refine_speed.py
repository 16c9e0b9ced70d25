"""Speed and memory of `demtool refine` on a 1024 × 1024 grid with the default iterations.

A synthetic scene with a 1024 × 1024 target image is rendered by `demtool synth`'s
runner; the coarse DEM is its truth low-passed (σ = 6 px) plus 0.2 GSD noise.  Then
``demtool refine`` runs as a separate process with its defaults (the NavCam/LRO NAC
parameters: 15 px median prefilter, 60 iterations at most, albedo and shadows updated
every 5 iterations), pinned to 2 CPU cores (``sched_setaffinity``, numba and FFT
threads set to 2).  A tiny warm-up run first fills numba's on-disk cache, so the
timed run measures the work, not the compilation.

Printed: wall time of the whole command (interpreter start, reading, median, SfS,
writing), the stage's own wall time and peak resident memory (from the sidecar,
``ru_maxrss``), iterations, beside the targets (≤ 60 s on 2 cores, ≤ 1 GB); also the
command's CPU time (user + system): on a machine shared with other jobs the wall time
is inflated, while CPU time ≤ 120 s means ≤ 60 s on 2 idle cores at best.  No
reference SfS tool is available in the environment.  On a shared machine the times
are inflated by the other users' load (the load average is printed).

Usage: ``.venv/bin/python bench/refine_speed.py [--quick]`` (--quick: 512 × 512).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

from demtool import io
from demtool.logs import configure_logging
from demtool.synth import SceneParams
from demtool.synth.run import run_synth

DEMTOOL = Path(sys.executable).with_name("demtool")
CORES = 2


def pin_to_two_cores() -> None:  # runs in the child before exec
    available = sorted(os.sched_getaffinity(0))
    os.sched_setaffinity(0, set(available[:CORES]))


def run(args: list[str]) -> tuple[float, float]:
    """Wall time and CPU time (user + system) of one demtool run."""
    import resource

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    env = {**os.environ, "NUMBA_NUM_THREADS": str(CORES), "OMP_NUM_THREADS": str(CORES),
           "OPENBLAS_NUM_THREADS": str(CORES)}
    start = time.perf_counter()
    completed = subprocess.run([str(DEMTOOL), "-q", *args], env=env, capture_output=True,
                               text=True, preexec_fn=pin_to_two_cores, check=False)
    elapsed = time.perf_counter() - start
    if completed.returncode != 0:
        raise SystemExit(f"demtool refine failed:\n{completed.stderr}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return elapsed, cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="512 × 512 instead of 1024")
    args = parser.parse_args()
    configure_logging(-1)
    size = 512 if args.quick else 1024
    with tempfile.TemporaryDirectory(prefix="refine_speed_") as tmp:
        folder = Path(tmp)
        # the demo scene's proportions: DEM cells of 1 m, twice the 0.5 m GSD footprint
        params = SceneParams(image_size=size, dem_size=size, n_views=2)
        start = time.perf_counter()
        run_synth(folder / "scene", params)
        render_s = time.perf_counter() - start
        description = io.read_json(folder / "scene" / "scene.json")
        image = folder / "scene" / f"{description['target']}.tif"
        truth = io.read_raster(folder / "scene" / "truth_dem_target.tif")
        gsd = truth.spacing[0]
        rng = np.random.default_rng(0)
        coarse = ndimage.gaussian_filter(truth.data.astype(float), 6.0) + rng.normal(
            0.0, 0.2 * gsd, truth.data.shape)
        dem = folder / "coarse.tif"
        io.write_raster(dem, coarse, transform=truth.transform, tags=truth.tags)
        # warm-up: fill numba's cache on a small crop
        io.write_raster(folder / "crop.tif", coarse[:64, :64], transform=truth.transform,
                        tags=truth.tags)
        io.write_raster(folder / "crop_image.tif", io.read_image(image).data[:64, :64],
                        tags=io.read_image(image).tags)
        run(["refine", str(folder / "crop_image.tif"), str(folder / "crop.tif"), "--out",
             str(folder / "warm.tif"), "--iterations", "2"])
        out = folder / "refined.tif"
        load = os.getloadavg()[0]
        wall, cpu = run(["refine", str(image), str(dem), "--out", str(out)])
        sidecar = json.loads(Path(f"{out}.json").read_text())
        refined = io.read_raster(out).data
    rmse_before = float(np.sqrt(np.mean((coarse - truth.data) ** 2)))
    rmse_after = float(np.sqrt(np.mean((refined - truth.data) ** 2)))
    stage_s = sidecar["wall_time_s"]
    peak_mb = sidecar["peak_memory_mb"]
    iterations = sidecar["summary"]["iterations"]
    timings = sidecar["summary"].get("timings_s", {})
    print(f"refine speed: {size} × {size} grid, defaults, {CORES} cores pinned; scene "
          f"rendered in {render_s:.1f} s; load average at start {load:.1f} on "
          f"{os.cpu_count()} CPUs")
    print(f"{'measure':<34} {'demtool':>12} {'target':>10}  {'met':>4}")
    print("-" * 64)
    rows = [
        ("wall time, whole command (s)", f"{wall:.1f}", "≤ 60", wall <= 60),
        ("CPU time, whole command (s)", f"{cpu:.1f}", "≤ 120", cpu <= 120),
        ("wall time, stage (s)", f"{stage_s:.1f}", "", None),
        ("  DEM preparation (median) (s)", f"{timings.get('prepare_dem', 0):.1f}", "", None),
        ("  shape from shading (s)", f"{timings.get('sfs', 0):.1f}", "", None),
        ("per iteration, stage (s)", f"{stage_s / max(iterations, 1):.2f}", "", None),
        ("iterations", f"{iterations}", "default", None),
        ("peak resident memory (MiB)", f"{peak_mb:.0f}", "≤ 1024", peak_mb <= 1024),
        ("RMSE vs truth before → after (m)", f"{rmse_before:.3f}→{rmse_after:.3f}", "", None),
    ]
    for name, value, target, met in rows:
        flag = "" if met is None else ("yes" if met else "NO")
        print(f"{name:<34} {value:>12} {target:>10}  {flag:>4}")


if __name__ == "__main__":
    main()
