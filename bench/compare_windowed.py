"""Peak memory and wall time of `demtool compare` in memory and in windows (issue 15).

A synthetic reference (fractal terrain) and a DEM displaced by (1.3, −0.7) px and +2 m
with noise are written at each size; `demtool compare --align nuth-kaab --no-plots` runs
as a child process, in memory and with `--tile-size 512`, and its peak resident memory
(``ru_maxrss`` of the child, from ``os.wait4``) and wall time are printed beside the
statistics of both runs (count, RMSE, NMAD; exactly equal where the alignment ran on the
whole grid, i.e. grids up to 2 M cells, and within the decimated alignment's effect
above).  The windowed run keeps the grid and the differences in memory between its passes
while they fit in ``--max-memory-mb`` (4096 MiB by default: each raster read once); a third
run with ``--max-memory-mb 600`` shows the peak a small budget keeps flat in the DEM size
(every pass reads its windows again).

Usage: ``.venv/bin/python bench/compare_windowed.py [--sizes 1024 2048 4096] [--windows-only]
[--record MACHINE]`` (``--record`` writes bench/results/51_scale_compare.json; then
``python bench/validation_page.py``)
(timings depend on the machine's load: compare numbers from the same run only).
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

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DEMTOOL = str(Path(sys.executable).with_name("demtool"))


MAKE_PAIR = """
import sys
from pathlib import Path
import numpy as np
sys.path.insert(0, {root!r})
from demtool import io as dio
from tests.helpers.compare import fourier_shift, fractal
size, folder = {size}, Path({folder!r})
truth = fractal(size, relief=25.0 * size / 96, seed=11).astype(np.float32)
dem = fourier_shift(truth, 1.3, -0.7) + 2.0
dem += np.random.default_rng(12).normal(scale=0.05, size=dem.shape)
transform = dio.image_frame_transform(2.0)
dio.write_raster(folder / "reference.tif", truth, transform=transform)
dio.write_raster(folder / "dem.tif", dem.astype(np.float32), transform=transform)
"""


def make_pair(folder: Path, size: int) -> tuple[Path, Path]:
    """A fractal reference and its displaced, noisy copy, ``size`` × ``size``, 2 m cells.

    Made in a child process: a child started later inherits the high-water mark of this
    process's memory (Linux records the old address space's peak at ``exec``, and
    ``subprocess`` forks with ``vfork``), so this process must stay small.
    """
    subprocess.run([sys.executable, "-c", MAKE_PAIR.format(root=str(ROOT), size=size,
                                                           folder=str(folder))], check=True)
    return folder / "dem.tif", folder / "reference.tif"


def run(args: list[str]) -> tuple[float, float]:
    """Wall seconds and peak resident MiB of one child process."""
    start = time.perf_counter()
    process = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(process.pid, 0)
    wall = time.perf_counter() - start
    if status != 0:
        raise RuntimeError(process.stderr.read().decode())
    return wall, usage.ru_maxrss / 1024.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1024, 2048, 4096])
    parser.add_argument("--windows-only", action="store_true",
                        help="Skip the in-memory runs (sizes that do not fit).")
    parser.add_argument("--record", metavar="MACHINE", default=None,
                        help="Record the table into bench/results/51_scale_compare.json.")
    options = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for size in options.sizes:
            folder = Path(tmp) / str(size)
            folder.mkdir()
            dem, reference = make_pair(folder, size)
            modes = [("in memory", []), ("windows 512", ["--tile-size", "512"]),
                     ("windows, 600 MiB", ["--tile-size", "512", "--max-memory-mb", "600"])]
            for mode, extra in modes[1:] if options.windows_only else modes:
                out = folder / mode.replace(" ", "_")
                wall, peak = run([DEMTOOL, "-q", "compare", str(dem), str(reference), "--out",
                                  str(out), "--no-plots", *extra])
                report = json.loads((out / "report.json").read_text())
                windowed = report.get("windowed") or {}
                rows.append((size, mode, wall, peak, report["count"], report["rmse"],
                             report["nmad"], windowed.get("passes", "—"),
                             windowed.get("alignment_decimation", "—")))
    print(f"{'size':>6} {'mode':<17} {'wall s':>7} {'peak MiB':>9} {'count':>10} "
          f"{'RMSE m':>10} {'NMAD m':>10} {'passes':>6} {'align f':>7}")
    for size, mode, wall, peak, count, rmse, nmad, passes, factor in rows:
        print(f"{size:>6} {mode:<17} {wall:7.1f} {peak:9.0f} {count:>10d} {rmse:10.6f} "
              f"{nmad:10.6f} {passes!s:>6} {factor!s:>7}")
    if options.record:
        record(rows, options)


def record(rows: list[tuple], options: argparse.Namespace) -> None:
    """bench/results/51_scale_compare.json: one row per DEM size."""
    from bench.validation_page import write_result

    cells: dict[int, dict[str, str]] = {}
    for size, mode, wall, peak, _, rmse, _, passes, factor in rows:
        text = f"{wall:.1f} s, {peak:.0f} MiB"
        if mode != "in memory":
            text += f", {passes} passes, f = {factor} (RMSE {rmse:.5f} m)"
        cells.setdefault(size, {})[mode] = text
    modes = ["in memory", "windows 512", "windows, 600 MiB"]
    write_result(
        "51_scale_compare", title="`compare` in windows", section="Large images", order=51,
        command="python bench/compare_windowed.py --sizes "
                + " ".join(str(s) for s in options.sizes)
                + (" --windows-only" if options.windows_only else "")
                + " (fractal DEM displaced by (1.3, −0.7) px and 2 m, --align nuth-kaab "
                  "--no-plots, windows of 512)",
        date=time.strftime("%Y-%m-%d"), machine=options.record,
        columns=["DEM", "in memory: wall, peak", "windows 512: wall, peak, passes, "
                 "alignment on 1 in f²", "windows 512, --max-memory-mb 600"],
        rows=[[f"{size}²", *(cells[size].get(m, "—") for m in modes)] for size in cells],
        notes="The windowed run keeps the comparison grid and the differences between its "
              "passes while they fit in --max-memory-mb (default 4096 MiB): each raster is "
              "read once.  With a budget too small for them (600 MiB) every pass reads its "
              "windows again and the peak is the imports plus the alignment on the "
              "decimated grid (≤ 2 M cells) plus one window, flat in the DEM size.")


if __name__ == "__main__":
    main()
