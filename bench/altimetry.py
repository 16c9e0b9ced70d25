"""Altimetry: a DEM against laser shots, synthetic and LOLA (issue 45).

1. Synthetic: a DEM on the Moon moved by a known (dx, dy, dz) and sampled along four
   tracks of shots with 0.5 m noise → ``compare DEM shots.csv`` recovers the shift
   (target: within 0.1 post and 0.1 m).
2. LOLA RDR (``../shared/data/altimetry/lola_nac_pair``, ISIS's lidar test data): all
   shots read; their UTC times converted to ephemeris seconds against the RDR's own ET
   column; for each of the two LRO NAC ISDs, the shots whose time falls inside the image
   projected into it, with the difference between the shot's time and the exposure time
   of the line it lands on (the NAC and LOLA look near nadir from one spacecraft, so the
   two should agree to the time of a few lines).
3. The LOLA shots against ISIS's reduced LOLA global DEM (``dems/ldem_4_reduced.cub``,
   0.75° posts): a coarse DEM and one track, so only the vertical shift is determined.

    python bench/altimetry.py [--record MACHINE]

Parts 2 and 3 need ``../shared/data`` (skipped when absent).  ``--record`` writes
``bench/results/77_altimetry.json``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT / ".." / "shared" / "data"
LOLA = SHARED / "altimetry" / "lola_nac_pair"
POST = 20.0
SHIFT = (37.0, -23.0, 4.0)


def terrain(x, y):
    return (60 * np.sin(x / 310.0) * np.cos(y / 420.0) + 25 * np.sin((x + 2 * y) / 190.0)
            + 0.01 * x)


def synthetic(folder: Path) -> dict:
    from pyproj import Transformer

    from demtool import io as dio
    from demtool.compare.run_altimetry import run_compare_shots
    from demtool.maps import body_by_name, grid_from_lonlat, grid_lonlat, lonlat_to_map

    moon = body_by_name("Moon")
    grid = grid_from_lonlat(moon, np.array([29.9, 30.1, 30.1, 29.9]),
                            np.array([-10.1, -10.1, -9.9, -9.9]), POST)
    gl, gt = grid_lonlat(grid)
    gx, gy = lonlat_to_map(grid.crs, gl, gt)
    dem = terrain(gx - SHIFT[0], gy - SHIFT[1]) + SHIFT[2]
    dio.write_raster(folder / "dem.tif", dem.astype(np.float32), transform=grid.transform,
                     crs=grid.crs, tags=moon.tags())
    to_lonlat = Transformer.from_crs(grid.crs, grid.crs.geodetic_crs, always_xy=True)
    rng = np.random.default_rng(8)
    rows = []
    for track, (dx, angle) in enumerate([(-1500, 80), (0, 95), (1500, 100), (-700, 88)]):
        s = np.linspace(-3000, 3000, 400)
        x = gx.mean() + dx + s * np.cos(np.radians(angle))
        y = gy.mean() + s * np.sin(np.radians(angle))
        h = terrain(x, y) + rng.normal(0, 0.5, len(s))
        lo, la = to_lonlat.transform(x, y)
        rows += [f"{lo[k]:.9f},{la[k]:.9f},{(moon.radius + h[k]) / 1e3:.7f},{track}"
                 for k in range(len(s))]
    (folder / "shots.csv").write_text("Pt_Long,Pt_Lat,Pt_Rad,orbit\n" + "\n".join(rows))
    return run_compare_shots(folder / "dem.tif", folder / "shots.csv", folder / "out")


def lola() -> list[list[str]]:
    from demtool.io.altimetry import read_shots, utc_to_et
    from demtool.maps import lonlat_height_to_xyz
    from demtool.sensors import read_sensor

    shots = read_shots(LOLA / "lidarPoints.csv")
    utc = [line.split(",")[0] for line in (LOLA / "lidarPoints.csv").read_text().splitlines()]
    et_error = float(np.max(np.abs(np.array([utc_to_et(u) for u in utc]) - shots.time)))
    rows = [["LOLA shots read", str(len(shots)), "105", "ok" if len(shots) == 105 else "NO"],
            ["UTC → ET vs the RDR's ET column (max, s)", f"{et_error:.1e}", "< 1e-3", ""]]
    for name in ("lidarObservationImage1.isd", "lidarObservationImage2.isd"):
        model = read_sensor(LOLA / name)
        start = model.center_time + float(model.line_time(0.0))
        end = model.center_time + float(model.line_time(model.lines))
        during = (shots.time >= start) & (shots.time <= end)
        text = "0 shots in its time span"
        if np.any(during):
            xyz = lonlat_height_to_xyz(shots.lon[during], shots.lat[during],
                                       shots.radius[during] - model.radii[0],
                                       radii=model.radii[0])
            line, sample = model.ground_to_image(xyz)
            inside = np.isfinite(line) & (line >= 0) & (line <= model.lines) & \
                (sample >= 0) & (sample <= model.samples)
            dt = model.center_time + model.line_time(line[inside]) - shots.time[during][inside]
            text = (f"{int(during.sum())} in its time span, {int(inside.sum())} project into "
                    f"it (samples {np.nanmin(sample):.0f}-{np.nanmax(sample):.0f}); shot − "
                    f"line time {np.median(dt) * 1e3:+.1f} ms median, "
                    f"{np.ptp(dt) * 1e3:.1f} ms spread")
        rows.append([f"NAC {name.split('.')[0][-6:]}", text, "shots timed inside project",
                     ""])
    return rows


def main(argv: list[str] | None = None) -> int:
    sys.path.insert(0, str(ROOT))
    from bench._table import add_record_option, report_table

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_record_option(parser, "77_altimetry")
    options = parser.parse_args(argv)

    rows = []
    with tempfile.TemporaryDirectory() as folder:
        started = time.perf_counter()
        report = synthetic(Path(folder))
        elapsed = time.perf_counter() - started
    shift = report["alignment"]["shift_m"]
    sigma = report["alignment"]["sigma_m"]
    errors = [shift["east"] + SHIFT[0], shift["north"] + SHIFT[1], shift["up"] + SHIFT[2]]
    met = abs(errors[0]) < 0.1 * POST and abs(errors[1]) < 0.1 * POST and abs(errors[2]) < 0.1
    rows.append(["synthetic shift recovered (E, N, U m)",
                 f"{-shift['east']:.2f}, {-shift['north']:.2f}, {-shift['up']:.3f} "
                 f"(σ {sigma['east']:.2f}, {sigma['north']:.2f}, {sigma['up']:.3f})",
                 f"{SHIFT[0]}, {SHIFT[1]}, {SHIFT[2]} ± 0.1 post / 0.1 m",
                 "met" if met else "NOT met"])
    rows.append(["synthetic NMAD before → after (m)",
                 f"{report['difference_before']['nmad_m']:.2f} → "
                 f"{report['difference_after']['nmad_m']:.2f}", "0.5 (noise)",
                 f"{elapsed:.1f} s"])
    if (LOLA / "lidarPoints.csv").exists():
        rows += lola()
        dem = SHARED / "dems" / "ldem_4_reduced.cub"
        if dem.exists():
            from demtool.compare.run_altimetry import run_compare_shots

            with tempfile.TemporaryDirectory() as folder:
                real = run_compare_shots(dem, LOLA / "lidarPoints.csv", Path(folder) / "o")
            before = real["difference_before"]
            rows.append(["LOLA shots vs ldem_4_reduced (0.75° posts)",
                         f"{real['shots_on_dem']} on the DEM; DEM − shots median "
                         f"{before['median_m']:.1f} m, NMAD {before['nmad_m']:.1f} m; "
                         f"{real['alignment'].get('note', 'shift solved')}",
                         "the DEM's posts are ~23 km", ""])
    else:
        rows.append(["LOLA data", "../shared/data absent: skipped", "", ""])
    columns = ["check", "demtool", "target / reference", "verdict"]
    report_table(
        "77_altimetry", columns, rows, record=options.record,
        title="Altimetry: DEM against laser shots (synthetic, LOLA)",
        section="Comparison", order=77, command="python bench/altimetry.py",
        notes=("`compare DEM shots.csv`. Synthetic: 20 m posts, four tracks of 400 shots "
               "(0.5 m noise); the shift the DEM was given is recovered as minus the shift "
               "moving it back (σ formal, shots taken as independent). LOLA: ISIS's "
               "`lidarObservationPair` test data (105 RDR shots, two LRO NAC ISDs of "
               "successive orbits: the shots are timed during the first). Differences are "
               "DEM minus shots."))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
