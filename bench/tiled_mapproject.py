"""`demtool mapproject` on the tile engine against the in-process loop (issue 15).

The synthetic lunar pushbroom strip of bench/mapproject.py (1 m pixels, rolled 10°) is
map-projected onto its 4 m DEM at 1 m, as child processes (``demtool -q mapproject``):
the default in-process loop, the engine with ``--workers 1`` (tiles in this process,
cached in a work folder) and with ``--workers 2`` (a Dask ``LocalCluster``), map tiles of
1024 cells.  Printed: wall time, the largest resident set of one process (``ru_maxrss``
of the waited-for descendants: the command or a Dask worker, not their sum), and
whether each orthoimage equals the in-process one cell for cell (target: equal, Dask
overhead small beside the tiles' time).

Usage: ``.venv/bin/python bench/tiled_mapproject.py [--lines 8192] [--samples 2048]``
(timings depend on the machine's load: compare numbers from the same run only).
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

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DEMTOOL = str(Path(sys.executable).with_name("demtool"))


def _write_inputs():
    from bench.mapproject import write_inputs

    return write_inputs


def run(args: list[str]) -> tuple[float, float]:
    """Wall seconds and the largest resident set (MiB) of the command's process tree."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    start = time.perf_counter()
    subprocess.run(args, check=True, stdout=subprocess.DEVNULL,
                   env=dict(os.environ, PYTHONPATH=str(ROOT)))
    wall = time.perf_counter() - start
    return wall, max(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, before) / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=8192)
    parser.add_argument("--samples", type=int, default=2048)
    options = parser.parse_args()
    from demtool import io as dio

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        start = time.perf_counter()
        _, image, isd, dem = _write_inputs()(folder, options.lines, options.samples)
        print(f"inputs: {options.samples} x {options.lines} image, written in "
              f"{time.perf_counter() - start:.1f} s; load average {os.getloadavg()[0]:.1f}")
        rows = []
        reference = None
        for label, extra in (("in process (default)", []),
                             ("engine, --workers 1", ["--workers", "1"]),
                             ("engine, --workers 2", ["--workers", "2"])):
            out = folder / f"ortho_{len(rows)}.tif"
            wall, peak = run([DEMTOOL, "-q", "mapproject", str(image), "--sensor", str(isd),
                              "--dem", str(dem), "--gsd", "1", "--out", str(out),
                              "--tile-size", "1024", *extra])
            summary = json.loads(Path(f"{out}.json").read_text())["summary"]
            data = dio.read_raster(out).data
            if reference is None:
                reference = data
            equal = bool(np.array_equal(data, reference, equal_nan=True))
            rows.append((label, summary["width"] * summary["height"], wall, peak, equal,
                         summary.get("tiling", {}).get("tiles", summary.get("tiles"))))
    print(f"{'run':24s} {'map cells':>12s} {'tiles':>6s} {'wall s':>7s} {'peak MiB':>9s} "
          f"{'equal':>6s}")
    for label, cells, wall, peak, equal, tiles in rows:
        print(f"{label:24s} {cells:12,d} {tiles!s:>6s} {wall:7.1f} {peak:9.0f} {equal!s:>6s}")


if __name__ == "__main__":
    main()
