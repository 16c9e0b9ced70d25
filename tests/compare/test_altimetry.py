"""``compare DEM shots.csv``: a DEM against laser altimetry shots (LOLA, MOLA)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from demtool.errors import InputError
from demtool.io.altimetry import read_shots, utc_to_et
from demtool.maps import body_by_name, grid_from_lonlat, grid_lonlat, lonlat_to_map

SHARED = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "altimetry"
MOON = body_by_name("Moon")
POST = 20.0
SHIFT = (37.0, -23.0, 4.0)  # the DEM is the truth moved by this (east, north m; up m)


def terrain(x, y):
    """Hills (metres) of 0.6-2 km wavelengths in map metres."""
    return (60 * np.sin(x / 310.0) * np.cos(y / 420.0) + 25 * np.sin((x + 2 * y) / 190.0)
            + 0.01 * x)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("shots")
    lon = np.array([29.9, 30.1, 30.1, 29.9])
    lat = np.array([-10.1, -10.1, -9.9, -9.9])
    grid = grid_from_lonlat(MOON, lon, lat, POST)
    gl, gt = grid_lonlat(grid)
    gx, gy = lonlat_to_map(grid.crs, gl, gt)
    dem = terrain(gx - SHIFT[0], gy - SHIFT[1]) + SHIFT[2]
    h, w = dem.shape
    dem[h // 2 - 6:h // 2 + 6, w // 2 - 6:w // 2 + 6] = np.nan  # no data under a track
    dem_path = dio.write_raster(folder / "dem.tif", dem.astype(np.float32),
                                transform=grid.transform, crs=grid.crs, tags=MOON.tags())
    rng = np.random.default_rng(8)
    rows = []
    from pyproj import Transformer

    to_lonlat = Transformer.from_crs(grid.crs, grid.crs.geodetic_crs, always_xy=True)
    x0, y0 = gx.mean(), gy.mean()
    for track, (dx, angle) in enumerate([(-1500, 80), (0, 95), (1500, 100), (-700, 88)]):
        s = np.linspace(-3000, 3000, 400)
        x = x0 + dx + s * np.cos(np.radians(angle))
        y = y0 + s * np.sin(np.radians(angle))
        h = terrain(x, y) + rng.normal(0, 0.5, len(s))
        lo, la = to_lonlat.transform(x, y)
        for k in range(len(s)):
            t = 1000.0 * track + 0.1 * k
            rows.append(f"{lo[k]:.9f},{la[k]:.9f},{(MOON.radius + h[k]) / 1e3:.7f},{t:.3f},"
                        f"{track}")
    rows += ["31.5,-10.0,1737.4,9999.0,9"]  # outside the DEM
    shots = folder / "shots.csv"
    shots.write_text("Pt_Long,Pt_Lat,Pt_Rad,EphemerisTime,orbit\n" + "\n".join(rows) + "\n")
    return dem_path, shots, folder


def test_known_shift_is_recovered_within_a_tenth_of_a_post_and_a_decimetre(scene, tmp_path):
    from demtool.compare.params import CompareParams
    from demtool.compare.run_altimetry import run_compare_shots

    dem, shots, _ = scene
    run_compare_shots(dem, shots, tmp_path / "out", CompareParams(plots=False))
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    shift = report["alignment"]["shift_m"]
    # moving the DEM back onto the truth: minus the shift it was given
    assert abs(shift["east"] + SHIFT[0]) < 0.1 * POST
    assert abs(shift["north"] + SHIFT[1]) < 0.1 * POST
    assert abs(shift["up"] + SHIFT[2]) < 0.1
    assert report["shots_read"] == 1601 and report["shots_outside"] == 1
    assert report["shots_on_no_data"] > 0 and report["tracks"] == 5
    assert report["difference_after"]["nmad_m"] < 1.0 < report["difference_before"]["nmad_m"]
    sigma = report["alignment"]["sigma_m"]
    assert 0 < sigma["up"] < 0.1 and 0 < sigma["east"] < 0.1 * POST
    table = (tmp_path / "out" / "shots.csv").read_text().splitlines()
    assert len(table) == 1602 and table[-1].endswith("outside")


def test_shots_of_another_body_are_one_line_exit_1(scene, tmp_path):
    dem, _, folder = scene
    mars = folder / "mars.csv"
    mars.write_text("longitude,latitude,radius_km\n30.0,-10.0,3396.1\n30.01,-10.0,3396.2\n")
    result = CliRunner().invoke(cli, ["-q", "compare", str(dem), str(mars), "--out",
                                      str(tmp_path / "o")])
    assert result.exit_code == 1
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and "another body" in lines[0]
    assert not (tmp_path / "o" / "report.json").exists()


def test_table_without_usable_columns_is_refused(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b,c\n1,2,3\n")
    with pytest.raises(InputError, match="cannot tell the longitude"):
        read_shots(bad)


def test_utc_to_ephemeris_seconds():
    # LOLA RDR: 2010-01-27T06:19:47.01382601 UTC is 317845253.197826 s TDB past J2000
    assert utc_to_et("2010-01-27T06:19:47.01382601") == pytest.approx(317845253.197826,
                                                                       abs=1e-5)


@pytest.mark.skipif(not (SHARED / "lola_nac_pair").exists(), reason="needs ../shared/data")
def test_lola_rdr_shots_read_and_fall_in_the_first_nac_image():
    from demtool.sensors import read_sensor

    shots = read_shots(SHARED / "lola_nac_pair" / "lidarPoints.csv")
    assert len(shots) == 105 and shots.radius.min() > 1.73e6
    model = read_sensor(SHARED / "lola_nac_pair" / "lidarObservationImage1.isd")
    start = model.center_time + float(model.line_time(0.0))
    end = model.center_time + float(model.line_time(model.lines))
    during = (shots.time >= start) & (shots.time <= end)
    assert 0 < np.count_nonzero(during) < 105
    from demtool.maps import lonlat_height_to_xyz

    xyz = lonlat_height_to_xyz(shots.lon[during], shots.lat[during],
                               shots.radius[during] - model.radii[0], radii=model.radii[0])
    line, sample = model.ground_to_image(xyz)
    assert np.all(np.isfinite(line))
