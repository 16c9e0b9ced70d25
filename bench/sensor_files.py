"""Every real camera file in ``../shared/data/sensors``: does it load, and how well does
image → ground → image close (issue 24: ≤ 0.01 px), or what is the one-line refusal.

For each ISD and cube: the model kind, the image size, the lines the ephemeris covers,
and the largest round-trip error over a 9 × 9 grid of image points whose rays meet the
body (push frames: each point projected into the framelet it came from, since
overlapping framelets see a ground point twice).  Files that are refused print the
reason.  ``simpleFramerISD.json`` does not close: its "transverse" coefficients map both
distorted x and y to the undistorted x (singular; usgscsm's tests only run it forwards).
ISIS line-scan cubes (LRO NAC, CTX, HiRISE) are read from their own tables; for the
HiRISE ``cam2map`` cubes (refused as cameras: their pixels are on the map) a second row
reads the raw camera their tables keep (``read_linescan_cube(mapped=True)``), and every
line-scan cube's row says where the pointing table (its first record, and the label's
``CkTableStartTime``) starts against the start time derived from the clock, in lines of
the uncropped image (0: its first line), and where the cube's first line is.
Skips cleanly when ``../shared/data/sensors`` is absent.

    python bench/sensor_files.py
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT / ".." / "shared" / "data" / "sensors"


def round_trip(model, n: int = 9) -> tuple[float, int]:
    """Largest |ground_to_image(image_to_ground(p)) − p| (px) over a grid, and the number
    of grid points whose rays meet the body."""
    from demtool.sensors import ray_ellipsoid_intersection

    lines, samples = np.meshgrid(np.linspace(0.5, model.lines - 0.5, n),
                                 np.linspace(0.5, model.samples - 0.5, n), indexing="ij")
    ray = model.image_to_ray(lines, samples)
    ground, hit = ray_ellipsoid_intersection(ray.origin, ray.direction, *model.radii,
                                             return_hit=True)
    if getattr(model, "kind", "") == "pushframe":
        back = model.ground_to_image(ground, framelet=model.framelet(lines))
    else:
        back = model.ground_to_image(ground)
    err = np.hypot(back[0] - lines, back[1] - samples)[hit]
    return (float(np.max(err)) if len(err) else float("nan")), int(hit.sum())


def main() -> None:
    from demtool.errors import InputError
    from demtool.sensors import read_sensor
    from demtool.sensors.coverage import covered_lines

    if not SHARED.is_dir():
        print(f"skipped: {SHARED} is absent")
        return
    files = sorted(p for p in SHARED.glob("*/*") if p.suffix.lower() in (".json", ".cub"))
    print(f"{'file':58s} {'kind':10s} {'size':>12s} {'covered':>9s} {'hits':>5s} "
          f"{'max round trip px':>18s} {'s':>6s}")
    for path in files:
        name = f"{path.parent.name}/{path.name}"
        start = time.perf_counter()
        try:
            model = read_sensor(path)
        except InputError as exc:
            reason = str(exc).split(": ", 1)[1]
            print(f"{name[:58]:58s} refused: {reason[:150]}")
            raw = _raw_camera(path)
            if raw is None:
                continue
            model, name = raw, f"{name[:48]} (camera)"
            start = time.perf_counter()
        if model.lines == 0 or model.radii is None:
            print(f"{name[:58]:58s} {model.kind:10s} (no image size or body)")
            continue
        covered = "—"
        if model.coverage is not None:  # line scan / push frame: ephemeris coverage
            runs = covered_lines(model)
            covered = f"{100 * sum(b - a + 1 for a, b in runs) / model.lines:.1f}%"
        err, hits = round_trip(model)
        print(f"{name[:58]:58s} {model.kind:10s} {model.lines:>5d}x{model.samples:<6d} "
              f"{covered:>9s} {hits:>5d} {err:>18.2e} "
              f"{time.perf_counter() - start:>6.2f}{_table_span(path)}")


def _raw_camera(path: Path):
    """The raw line-scan camera an ISIS map-projected cube's tables keep, or None."""
    from demtool.errors import InputError
    from demtool.sensors.isis_linescan import read_linescan_cube

    if path.suffix.lower() != ".cub":
        return None
    try:
        return read_linescan_cube(path, mapped=True)
    except InputError:
        return None


def _table_span(path: Path) -> str:
    """For an ISIS line-scan cube: the pointing table's first and last times against the
    first and last image lines, in lines (negative: the table starts before the image)."""
    from demtool.errors import InputError
    from demtool.sensors.isis_label import read_label
    from demtool.sensors.isis_linescan import cube_isd, time_check

    if path.suffix.lower() != ".cub":
        return ""
    try:
        label, data = read_label(path)
        check = time_check(cube_isd(path, label, data, mapped=True), label)
    except InputError:
        return ""
    return (f"  pointing table {check['table_start_lines']:+.2f}, CkTableStartTime "
            f"{check['ck_start_lines']:+.2f}, cube {check['cube_start_lines']:+.2f} lines")


if __name__ == "__main__":
    main()
