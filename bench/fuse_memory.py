"""Memory of `demtool fuse` in tiles on Dask: two large DEMs, 2 workers (issue 29).

Two overlapping DEMs of ``--size``² cells (default 8192², float32, 256 MiB each on disk
uncompressed) on an equirectangular map of the Moon, the second offset by 1/16 of the
size both ways and 0.7 m higher, are written window by window; then
``demtool fuse A B --tile-size 1024 --workers 2`` runs as a child process and the peak
resident memory of its whole process tree (the command, the Dask scheduler, nannies and
workers: :func:`bench.scale.run_measured`, psutil every 50 ms, shared pages counted once
per process — an over-estimate) is printed beside the target (< 2 GB), with the wall
time, the co-registration shift found (dz −0.7 m expected) and the fused DEM's
difference to the known surface on a sample of rows.

Usage: ``.venv/bin/python bench/fuse_memory.py [--size 8192] [--workers 2] [--keep DIR]``
(the 8192² run writes ~1.5 GB of GeoTIFFs; about 3-5 minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.scale import run_measured  # noqa: E402

GSD = 5.0
STRIP = 512


def surface(rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Known relief (metres) at lattice cell centres."""
    x, y = (cols + 0.5) * GSD, (rows + 0.5) * GSD
    return (30 * np.sin(2 * np.pi * x / 3000) + 20 * np.cos(2 * np.pi * (y + 0.3 * x) / 2200)
            + 3 * np.sin(2 * np.pi * (x - y) / 170))


def write_big(path: Path, size: int, offset: int, dz: float) -> None:
    from affine import Affine
    from rasterio.crs import CRS

    from demtool import io as dio
    from demtool import maps

    body = maps.body_by_naif_id(301)
    crs = CRS.from_wkt(maps.make_projection(body, "equirectangular", 0.0, 0.0).to_wkt())
    transform = Affine(GSD, 0, offset * GSD, 0, -GSD, -offset * GSD)
    rng = np.random.default_rng(offset)
    with dio.raster_writer(path, height=size, width=size, transform=transform, crs=crs,
                           tags=body.tags()) as writer:
        for r0 in range(0, size, STRIP):
            rows, cols = np.mgrid[r0 + offset:min(size, r0 + STRIP) + offset,
                                  offset:size + offset].astype(np.float64)
            heights = surface(rows, cols) + dz + 0.2 * rng.standard_normal(rows.shape)
            writer.write(heights.astype(np.float32), r0, 0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=8192)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--tile-size", type=int, default=1024)
    parser.add_argument("--keep", type=Path)
    args = parser.parse_args(argv)
    work = args.keep or Path(tempfile.mkdtemp(prefix="fuse_memory_"))
    work.mkdir(parents=True, exist_ok=True)
    a, b = work / "a.tif", work / "b.tif"
    offset = args.size // 16
    if not a.is_file():
        write_big(a, args.size, 0, 0.0)
    if not b.is_file():
        write_big(b, args.size, offset, 0.7)
    out = work / "fused.tif"
    for path in (out, *(out.with_name(f"fused_{n}.tif") for n in ("count", "spread",
                                                                     "error"))):
        path.unlink(missing_ok=True)
    command = [sys.executable, "-m", "demtool", "fuse", str(a), str(b), "--out", str(out),
               "--tile-size", str(args.tile_size), "--workers", str(args.workers)]
    result = run_measured(command)
    if result["code"] != 0:
        print(result["stderr"])
        return 1
    summary = json.loads(Path(f"{out}.json").read_text())["summary"]
    shift = summary["dems"][1]["alignment"]["shift"]
    from demtool.tiling import read_window

    rows = [0, args.size // 2, args.size + offset - 1]
    errors = []
    for r in rows:
        line = read_window(out, (r, r + 1, 0, args.size + offset))[0]
        truth = surface(np.full(line.shape, float(r)), np.arange(line.size, dtype=float))
        errors.append(line - truth)
    diff = np.concatenate(errors)
    diff = diff[np.isfinite(diff)]
    grid = summary["grid"]["shape"]
    print(f"demtool fuse: two {args.size}² DEMs (offset {offset} cells), fused grid "
          f"{grid[1]}×{grid[0]}, tile {args.tile_size}, {args.workers} Dask workers")
    print(f"{'measure':<40}{'target':>12}{'measured':>12}")
    print(f"{'peak memory of the process tree, MB':<40}{'< 2000':>12}{result['peak_mb']:>12.0f}")
    print(f"{'wall time, s':<40}{'':>12}{result['wall_s']:>12.1f}")
    print(f"{'CPU time of the tree, s':<40}{'':>12}{result['cpu_s']:>12.1f}")
    print(f"{'shift found dz, m (B is +0.7 m)':<40}{'-0.700':>12}{shift['dz']:>12.3f}")
    found = f"{shift['dx_px']:.3f}, {shift['dy_px']:.3f}"
    print(f"{'shift found dx, dy, cells':<40}{'0, 0':>12}{found:>16}")
    rmse = math.sqrt(float(np.mean(diff**2)))
    print(f"{'RMSE vs the surface on 3 rows, m':<40}{'0.14-0.2':>12}{rmse:>12.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
