"""Scale of `demtool sgm` in tiles: memory vs image size, Dask overhead, resume, projection.

Issue 15's checks, each `demtool sgm --cost census --min-disparity 0 --num-disparities 96`
run as a child process on a synthetic pair with exact truth (bench/_scale_pairs.py,
disparities 18 … 78 px):

1. Peak memory of the whole process tree (the command, the Dask scheduler, nannies and
   workers: the sum of their resident sets, sampled every 50 ms with psutil, so shared
   library pages count once per process, an over-estimate) and wall time against the
   image size (2048², 4096², 8192² where it fits): untiled, tiled with 1 worker (in
   process) and with 2 workers (a LocalCluster), tile 1024.  Target at 4096² with 2
   workers: < 2 GB, bad-2 < 5 %; tiled memory flat in the image size.
2. Dask overhead at 2 workers: (wall of the 2-worker run − wall untiled) / wall untiled,
   target ≤ 15 % on this 2-core machine; also the same ratio of the CPU seconds of the
   whole process tree (user + system of every process in it, sampled with the memory,
   so up to 50 ms per process may be missed), which a machine shared with other jobs
   disturbs less than the wall time.
3. Tiled vs untiled on a 1024² crop, tile 256: share of pixels within 0.1 px (≥ 99.5 %).
4. Resume: a 2048² run, tile 512, killed (SIGKILL to its process group) after 3 tiles are
   cached, then run again: the tiles computed by the second run, and whether the file
   is byte-identical to an uninterrupted run's (same path, so the same tags).
5. Projection to N nodes like this one from the per-tile times of the largest run:
   ``wall(N) ≈ start-up + ceil(tiles / N) × mean tile time``.

Usage: ``.venv/bin/python bench/scale.py [--quick] [--sizes 2048 4096 8192]``
(``--quick``: 2048² only, no resume check).  Timings depend on the machine's load (two
cores shared by other jobs here): compare only numbers from the same run.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DEMTOOL = str(Path(sys.executable).with_name("demtool"))
SGM = ["--cost", "census", "--min-disparity", "0", "--num-disparities", "96"]


def tree_sample(process, cpu: dict[int, float]) -> int:
    """Bytes resident in ``process`` and its descendants now; updates ``cpu`` (pid → s)."""
    import psutil

    total = 0
    try:
        members = [process, *process.children(recursive=True)]
    except psutil.Error:
        return 0
    for member in members:
        try:
            with member.oneshot():
                total += member.memory_info().rss
                times = member.cpu_times()
                cpu[member.pid] = times.user + times.system
        except psutil.Error:
            pass
    return total


def run_measured(args: list[str], *, kill_when=None) -> dict:
    """Run a command; its wall time and the peak resident memory of its process tree."""
    import psutil

    start = time.perf_counter()
    child = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             start_new_session=True)
    process = psutil.Process(child.pid)
    peak = 0
    cpu: dict[int, float] = {}
    stop = threading.Event()
    killed = False

    def sample():
        nonlocal peak
        while not stop.is_set():
            peak = max(peak, tree_sample(process, cpu))
            time.sleep(0.05)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    while child.poll() is None:
        if kill_when is not None and kill_when():
            os.killpg(child.pid, signal.SIGKILL)
            killed = True
            break
        time.sleep(0.05)
    stdout, stderr = child.communicate()
    wall = time.perf_counter() - start
    stop.set()
    sampler.join()
    return {"code": child.returncode, "wall_s": wall, "cpu_s": sum(cpu.values()),
            "peak_mb": peak / 2**20, "killed": killed, "stderr": stderr.decode()[-2000:],
            "stdout": stdout.decode()}


def sgm_command(folder: Path, out: Path, *options: str) -> list[str]:
    return [DEMTOOL, "sgm", str(folder / "left_rect.tif"), str(folder / "right_rect.tif"),
            "--out", str(out), *SGM, *options]


def bad2(disparity: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Bad-2 (of the valid pixels) and density over the left pixels with a match."""
    columns = np.arange(truth.shape[1])[None, :]
    mask = columns - truth >= 1
    valid = mask & np.isfinite(disparity)
    error = np.abs(disparity[valid] - truth[valid])
    return float((error > 2).mean()), float(valid.sum() / mask.sum())


def memory_table(work: Path, sizes: list[int]) -> list[dict]:
    from bench._scale_pairs import write_pair
    from demtool import io as dio

    rows = []
    for size in sizes:
        folder = work / f"pair_{size}"
        write_pair(folder, size)
        truth = np.load(folder / "truth.npy")
        for label, options in (("untiled", ()),
                               ("tiled, 1 worker", ("--tile-size", "1024", "--workers", "1")),
                               ("tiled, 2 workers", ("--tile-size", "1024", "--workers",
                                                     "2"))):
            out = folder / f"{label.replace(' ', '_').replace(',', '')}.tif"
            result = run_measured(sgm_command(folder, out, *options))
            if result["code"] != 0:
                print(f"{size}² {label}: failed\n{result['stderr']}")
                continue
            error, density = bad2(dio.read_raster(out).data, truth)
            sidecar = json.loads(Path(f"{out}.json").read_text())
            rows.append({"size": size, "run": label, "wall_s": result["wall_s"],
                         "cpu_s": result["cpu_s"],
                         "peak_mb": result["peak_mb"], "bad2": error, "density": density,
                         "tiling": sidecar["summary"].get("tiling")})
            print(f"{size:>5}²  {label:<17} {result['wall_s']:7.1f} s  "
                  f"{result['cpu_s']:7.1f} s  "
                  f"{result['peak_mb']:7.0f} MB  bad-2 {100 * error:5.2f} %  "
                  f"density {100 * density:5.1f} %", flush=True)
            out.unlink()
        del truth
    return rows


def agreement(work: Path) -> float:
    from bench._scale_pairs import write_pair
    from demtool import io as dio

    folder = work / "pair_1024"
    write_pair(folder, 1024)
    untiled, tiled = folder / "untiled.tif", folder / "tiled.tif"
    for out, options in ((untiled, ()), (tiled, ("--tile-size", "256"))):
        result = run_measured(sgm_command(folder, out, *options))
        assert result["code"] == 0, result["stderr"]
    a, b = dio.read_raster(untiled).data, dio.read_raster(tiled).data
    same = (np.isfinite(a) & np.isfinite(b) & (np.abs(a - b) <= 0.1)) | (
        np.isnan(a) & np.isnan(b))
    return float(same.mean())


def resume(work: Path) -> dict:
    from bench._scale_pairs import write_pair
    from demtool.tiling import work_folder

    folder = work / "pair_2048"
    if not (folder / "left_rect.tif").exists():
        write_pair(folder, 2048)
    out = folder / "resumed.tif"
    options = ("--tile-size", "512", "--workers", "1")
    first = run_measured(sgm_command(folder, out, *options))
    assert first["code"] == 0, first["stderr"]
    reference = out.read_bytes()
    out.unlink()
    Path(f"{out}.json").unlink()
    cache = work_folder(out)
    killed = run_measured(sgm_command(folder, out, *options),
                          kill_when=lambda: len(list(cache.glob("*/tile_*.npy"))) >= 3)
    cached = len(list(cache.glob("*/tile_*.npy")))
    again = run_measured(sgm_command(folder, out, *options))
    assert again["code"] == 0, again["stderr"]
    return {"killed": killed["killed"], "cached_after_kill": cached,
            "byte_identical": out.read_bytes() == reference,
            "log": [line for line in again["stderr"].splitlines() if "found in" in line]}


def dem_table(work: Path, sizes: list[int], untiled_max: int = 2048) -> None:
    """`demtool dem` (calibrated disparity route, bench/_scale_dem.py pairs): untiled (up to
    ``untiled_max``², its memory grows with the image) vs tiles of 1024 px, 1 worker;
    wall, peak memory of the tree, share of cells within 0.01 m of the untiled DEM and
    RMSE against the truth."""
    from bench._scale_dem import write_dem_pair
    from demtool import io as dio

    print("\ndem   run                  wall       CPU      peak tree   vs untiled "
          "(target: ≥ 99.5 % within 0.01 m)   RMSE vs truth")
    for size in sizes:
        folder = work / f"dem_{size}"
        write_dem_pair(folder, size)
        truth, untiled = np.load(folder / "truth.npy"), None
        runs = [("untiled", ())] if size <= untiled_max else []
        for label, options in (*runs, ("tiled, 1 worker", ("--tile-size", "1024"))):
            out = folder / f"{label.replace(' ', '_').replace(',', '')}.tif"
            result = run_measured([DEMTOOL, "dem", "--disparity", str(folder / "disparity.tif"),
                                   "--rectify", str(folder / "rectify.npz"), "--cameras",
                                   str(folder / "cameras.npz"), "--out", str(out), *options])
            if result["code"] != 0:
                print(f"{size}² {label}: failed\n{result['stderr']}")
                continue
            heights = dio.read_raster(out).data
            untiled = heights if label == "untiled" else untiled
            same = ("—" if untiled is None or label == "untiled" else
                    f"{100 * np.mean(np.abs(heights - untiled) <= 0.01):.4f} %, max "
                    f"{np.abs(heights - untiled).max():.3f} m")
            print(f"{size:>5}²  {label:<17} {result['wall_s']:7.1f} s  {result['cpu_s']:7.1f} s"
                  f"  {result['peak_mb']:7.0f} MB  {same:<34}  "
                  f"{np.sqrt(np.mean((heights - truth) ** 2)):.4f} m", flush=True)
        del truth, untiled


def projection(rows: list[dict]) -> None:
    tiled = [r for r in rows if r["run"] == "tiled, 1 worker" and r["tiling"]]
    if not tiled:
        return
    largest = max(tiled, key=lambda r: r["size"])
    info = largest["tiling"]
    tiles, mean = info["tiles"], info["tile_seconds_sum"] / info["tiles"]
    startup = max(0.0, largest["wall_s"] - info["tiles_wall_s"])
    print(f"\nprojection from the {largest['size']}² run ({tiles} tiles, mean tile "
          f"{mean:.1f} s on this machine's cores, start-up + writing {startup:.1f} s):")
    for scale in (1, 4, 16):
        pixels = tiles * scale
        cells = ", ".join(f"{n} nodes {startup + math.ceil(pixels / n) * mean:7.0f} s"
                          for n in (1, 2, 4, 8, 16, 64))
        print(f"  {scale:>2}× the image ({pixels} tiles): {cells}")


def refine_table(work: Path, sizes: list[int], tile: int = 512) -> None:
    """`demtool refine` untiled and in tiles of ``tile`` px (1 worker): wall, peak memory
    of the process tree, RMSE tiled − untiled (target < 0.02 GSD), both against the truth.

    Scene: smoothed noise relief (features of 4–40 px, slopes up to ~25°), sun 30° high,
    lunar-Lambert, 0.5 % noise; the input DEM is the truth ⊗ Gaussian(6 px).
    """
    from scipy import ndimage

    from demtool import io as dio
    from tests.helpers.refine import render, sun_vector

    gsd = 1.0
    for size in sizes:
        folder = work / f"refine_{size}"
        folder.mkdir(parents=True, exist_ok=True)
        rng = np.random.default_rng(size)
        noise = rng.normal(size=(size, size))
        truth = sum(ndimage.gaussian_filter(noise, s) * s * 1.2 for s in (2.0, 5.0, 12.0))
        sun = sun_vector(120.0, 30.0)
        image = render(truth, gsd, sun) * 800.0 * (1 + 0.005 * rng.normal(size=truth.shape))
        dio.write_raster(folder / "view_00.tif", image.astype(np.float32),
                         transform=dio.image_frame_transform(1.0),
                         tags={"frame": "image:view_00", "sun_vector_grid": list(sun)})
        dio.write_raster(folder / "dem.tif", ndimage.gaussian_filter(truth, 6.0),
                         transform=dio.image_frame_transform(gsd),
                         tags={"frame": "image:view_00"})
        results = {}
        for label, options in (("untiled", ()),
                               (f"tiled {tile}, 1 worker", ("--tile-size", str(tile)))):
            out = folder / f"{label.split()[0]}.tif"
            run = run_measured([DEMTOOL, "refine", str(folder / "view_00.tif"),
                                str(folder / "dem.tif"), "--out", str(out), *options])
            if run["code"] != 0:
                print(f"refine {size}² {label}: failed\n{run['stderr']}")
                break
            results[label] = dio.read_raster(out).data
            error = float(np.sqrt(np.mean((results[label] - truth) ** 2)))
            print(f"refine {size:>5}²  {label:<20} {run['wall_s']:7.1f} s  "
                  f"{run['cpu_s']:7.1f} s CPU  {run['peak_mb']:7.0f} MB  RMSE vs truth "
                  f"{error:.3f} m", flush=True)
        if len(results) == 2:
            untiled, tiled = results.values()
            difference = float(np.sqrt(np.mean((tiled - untiled) ** 2))) / gsd
            coarse = float(np.sqrt(np.mean((ndimage.gaussian_filter(truth, 6.0) - truth)
                                           ** 2)))
            print(f"refine {size}²: tiled − untiled RMSE {difference:.4f} GSD (target < 0.02); "
                  f"input DEM vs truth {coarse:.3f} m")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--sizes", type=int, nargs="+", default=[2048, 4096, 8192])
    parser.add_argument("--work", type=Path, default=None)
    args = parser.parse_args()
    sizes = [2048] if args.quick else args.sizes
    with tempfile.TemporaryDirectory(dir=args.work) as temporary:
        work = Path(temporary)
        # Warm-up: numba's cache, so no run pays for compilation.
        from bench._scale_pairs import write_pair

        write_pair(work / "warm", 512)
        run_measured(sgm_command(work / "warm", work / "warm" / "d.tif"))
        print("size   run                  wall       CPU      peak tree   accuracy (target at "
              "4096², 2 workers: < 2 GB, bad-2 < 5 %)")
        rows = memory_table(work, sizes)
        for size in sizes:
            by_run = {r["run"]: r for r in rows if r["size"] == size}
            if "untiled" in by_run and "tiled, 2 workers" in by_run:
                untiled, dask = by_run["untiled"], by_run["tiled, 2 workers"]
                wall = (dask["wall_s"] - untiled["wall_s"]) / untiled["wall_s"]
                cpu = (dask["cpu_s"] - untiled["cpu_s"]) / untiled["cpu_s"]
                print(f"{size}²: overhead of 2 Dask workers over the untiled run: wall "
                      f"{100 * wall:+.1f} %, CPU {100 * cpu:+.1f} % (target ≤ 15 %)")
        print(f"\n1024² crop, tile 256: {100 * agreement(work):.2f} % of the pixels within "
              "0.1 px of the untiled run (target ≥ 99.5 %)")
        if not args.quick:
            outcome = resume(work)
            print(f"\nresume: killed {outcome['killed']} after {outcome['cached_after_kill']} "
                  f"cached tiles; rerun byte-identical to an uninterrupted run: "
                  f"{outcome['byte_identical']}  {outcome['log']}")
        projection(rows)
        refine_table(work, [1024] if args.quick else [1024, 2048])
        dem_table(work, [1024] if args.quick else [2048, 4096])


if __name__ == "__main__":
    main()
