"""`demtool compare` on planetary CRSs: reprojection between CRSs of one body, degree grids
measured in metres with the body's radius, and DEMs of different bodies refused."""

import math

import numpy as np
import pytest
from affine import Affine
from click.testing import CliRunner

from demtool import io as dio
from demtool import maps
from demtool.cli import cli

GSD = 25.0  # metres


@pytest.fixture(scope="module")
def moon():
    return maps.body_by_naif_id(301)


def surface(lon, lat, lon0, lat0, radius, *, shift_east_m=0.0):
    """Smooth relief (two 4–5 km waves, 60 m) in local metres around (lon0, lat0)."""
    east = radius * math.cos(math.radians(lat0)) * np.radians(lon - lon0) - shift_east_m
    north = radius * np.radians(lat - lat0)
    return (40.0 * np.sin(2 * np.pi * (east + 0.5 * north) / 4000.0)
            + 25.0 * np.cos(2 * np.pi * (north - 0.3 * east) / 5000.0))


def write_projected(path, body, crs, lon0, lat0, half_m, **kwargs):
    """The surface on a projected CRS over ±half_m around (lon0, lat0)."""
    x0, y0 = maps.lonlat_to_map(crs, lon0, lat0)
    grid = maps.snap_grid(crs, x0 - half_m, y0 - half_m, x0 + half_m, y0 + half_m, GSD)
    lon, lat = maps.grid_lonlat(grid)
    heights = surface(lon, lat, lon0, lat0, body.radius, **kwargs)
    dio.write_raster(path, heights, transform=grid.transform, crs=grid.crs, tags=body.tags())
    return grid


def write_geographic(path, body, lon0, lat0, half_m, heights_of=None):
    """The surface on the body's geographic CRS (degrees), ≈GSD pixels at lat0."""
    per_degree = body.radius * math.pi / 180
    dlat = GSD / per_degree
    dlon = GSD / (per_degree * math.cos(math.radians(lat0)))
    n = int(round(2 * half_m / GSD))
    transform = Affine(dlon, 0, lon0 - n / 2 * dlon, 0, -dlat, lat0 + n / 2 * dlat)
    cols, rows = np.meshgrid(np.arange(n) + 0.5, np.arange(n) + 0.5)
    lon = transform.c + cols * dlon
    lat = transform.f - rows * dlat
    heights = (heights_of or (lambda lo, la: surface(lo, la, lon0, lat0, body.radius)))(lon, lat)
    dio.write_raster(path, heights, transform=transform, crs=body.geographic_crs(),
                     tags=body.tags())
    return transform


def _invoke(*args):
    return CliRunner().invoke(cli, ["compare", *map(str, args)])


@pytest.mark.parametrize("other", ["geographic", "south_polar", "polar_stereographic"])
def test_one_surface_in_two_crss_of_the_moon_agrees(moon, tmp_path, other):
    lon0, lat0 = (20.0, 10.0) if other == "geographic" else (60.0, -80.0)
    reference_crs = maps.make_projection(moon, "equirectangular", lon0, lat0)
    write_projected(tmp_path / "ref.tif", moon, reference_crs, lon0, lat0, 2000.0)
    if other == "geographic":
        write_geographic(tmp_path / "dem.tif", moon, lon0, lat0, 2600.0)
    else:
        crs = "IAU_2015:30135" if other == "south_polar" else \
            maps.make_projection(moon, "auto", lon0, lat0)
        write_projected(tmp_path / "dem.tif", moon, maps.to_pyproj_crs(crs), lon0, lat0,
                        2600.0)
    out = tmp_path / "report"
    result = _invoke(tmp_path / "dem.tif", tmp_path / "ref.tif", "--out", out, "--align",
                     "none", "--no-plots")
    assert result.exit_code == 0, result.output
    report = dio.read_json(out / "report.json")
    assert report["completeness"] > 99.0
    assert report["rmse"] < 0.05  # metres, of ±60 m relief: bilinear resampling only
    assert report["grid"]["spacing_m"] == pytest.approx([GSD, GSD])
    assert report["grid"]["from_geographic"] is None
    assert "Moon" in report["grid"]["crs"]
    assert maps.body_from_crs(dio.read_raster(out / "difference.tif").crs).naif_id == 301


def test_degree_reference_is_measured_in_metres(moon, tmp_path):
    lon0, lat0 = -45.0, 40.0
    write_geographic(tmp_path / "ref.tif", moon, lon0, lat0, 2000.0)
    crs = maps.make_projection(moon, "equirectangular", lon0, lat0)
    write_projected(tmp_path / "dem.tif", moon, crs, lon0, lat0, 2600.0, shift_east_m=75.0)
    out = tmp_path / "report"
    result = _invoke(tmp_path / "dem.tif", tmp_path / "ref.tif", "--out", out, "--no-plots")
    assert result.exit_code == 0, result.output
    report = dio.read_json(out / "report.json")
    grid = report["grid"]
    per_degree = moon.radius * math.pi / 180
    degrees = grid["from_geographic"]
    assert degrees["spacing_deg"] == pytest.approx(
        [GSD / (per_degree * math.cos(math.radians(lat0))), GSD / per_degree])
    # metres on the ground at the footprint centre, not degrees
    assert grid["spacing_m"] == pytest.approx([GSD, GSD], rel=0.01)
    assert "Equirectangular" in degrees["projection"]
    assert "Moon" in grid["crs"]
    # the DEM was moved 75 m east: alignment moves it back by 75 m (3 px)
    assert report["shift"]["dx_px"] * grid["spacing_m"][0] == pytest.approx(-75.0, abs=2.0)
    assert report["shift"]["dy_px"] * grid["spacing_m"][1] == pytest.approx(0.0, abs=2.0)
    assert report["rmse"] < 0.02
    assert report["before_alignment"]["rmse"] > 2.0  # the shift is measured, not absent


def test_degree_grid_slopes_are_in_degrees_of_the_ground(moon, tmp_path):
    lon0, lat0 = 100.0, -30.0
    tilt = math.tan(math.radians(15.0))  # a plane rising 15° to the north

    def plane(lon, lat):
        return tilt * moon.radius * np.radians(lat - lat0)

    write_geographic(tmp_path / "ref.tif", moon, lon0, lat0, 1500.0, heights_of=plane)
    write_geographic(tmp_path / "dem.tif", moon, lon0, lat0, 1500.0,
                     heights_of=lambda lon, lat: plane(lon, lat) + 3.0)
    out = tmp_path / "report"
    result = _invoke(tmp_path / "dem.tif", tmp_path / "ref.tif", "--out", out, "--align",
                     "offset", "--no-plots")
    assert result.exit_code == 0, result.output
    report = dio.read_json(out / "report.json")
    classes = {(c["slope_min_deg"], c["slope_max_deg"]): c["count"]
               for c in report["slope_classes"]}
    # every pixel with a slope (all but the rim of the valid area) is in the 10–20° class
    assert classes[(10.0, 20.0)] == sum(classes.values()) > 0.9 * report["count"] > 1000
    assert report["shift"]["dz"] == pytest.approx(-3.0, abs=0.01)


@pytest.mark.parametrize("case", ["mars_vs_moon", "earth_vs_moon", "also_on_mars"])
def test_dems_of_different_bodies_are_refused_in_one_line(moon, tmp_path, case):
    reference = tmp_path / "moon.tif"
    write_projected(reference, moon, maps.make_projection(moon, "auto", 0.0, 0.0), 0.0, 0.0,
                    500.0)
    mars = maps.body_by_naif_id(499)
    extra = []
    if case == "earth_vs_moon":
        dem = tmp_path / "earth.tif"
        dio.write_raster(dem, np.zeros((20, 20)), crs="EPSG:32633",
                         transform=Affine(GSD, 0, -250, 0, -GSD, 250))
        expected = ["Earth (NAIF 399", "Moon (NAIF 301"]
    else:
        dem = tmp_path / "mars.tif"
        write_projected(dem, mars, maps.make_projection(mars, "auto", 0.0, 0.0), 0.0, 0.0,
                        500.0)
        expected = ["Mars (NAIF 499, sphere R=3396190 m)", "Moon (NAIF 301"]
        if case == "also_on_mars":
            write_projected(tmp_path / "moon2.tif", moon,
                            maps.make_projection(moon, "auto", 0.0, 0.0), 0.0, 0.0, 500.0)
            extra, dem = ["--also", dem], tmp_path / "moon2.tif"
    out = tmp_path / "report"
    result = _invoke(dem, reference, "--out", out, *extra)
    assert result.exit_code == 1
    lines = result.output.strip().splitlines()
    assert len(lines) == 1, result.output
    for text in (*expected, str(reference), str(tmp_path / ("earth.tif" if case ==
                                                           "earth_vs_moon" else "mars.tif"))):
        assert text in lines[0]
    assert "one body" in lines[0]
    assert not out.exists() or not any(out.iterdir())


def _write_wrapped_projected(path, body, lon0, lat0, half_m):
    """The surface on an equirectangular map centred at lon0 (longitudes wrapped)."""
    crs = maps.make_projection(body, "equirectangular", lon0, lat0)
    x0, y0 = maps.lonlat_to_map(crs, lon0, lat0)
    grid = maps.snap_grid(crs, x0 - half_m, y0 - half_m, x0 + half_m, y0 + half_m, GSD)
    lon, lat = maps.grid_lonlat(grid)
    lon = maps.wrap_longitude(lon, lon0)
    dio.write_raster(path, surface(lon, lat, lon0, lat0, body.radius), transform=grid.transform,
                     crs=grid.crs, tags=body.tags())


def test_degree_dem_across_the_antimeridian_is_compared_whole(moon, tmp_path):
    """Issue 31, class 6: a degree reference on 179.93…180.07 °E (0…360 style) against a
    map DEM: every cell compared (was 49.9 %: PROJ's −180…180 missed half the grid)."""
    write_geographic(tmp_path / "ref.tif", moon, 180.0, 10.0, 2000.0)
    _write_wrapped_projected(tmp_path / "dem.tif", moon, 180.0, 10.0, 2600.0)
    out = tmp_path / "report"
    result = _invoke(tmp_path / "dem.tif", tmp_path / "ref.tif", "--out", out, "--no-plots",
                     "--align", "none")
    assert result.exit_code == 0, result.output
    report = dio.read_json(out / "report.json")
    assert report["completeness"] > 99.0
    assert report["rmse"] < 0.05


def test_same_ground_written_360_degrees_apart_overlaps(moon, tmp_path):
    """The same surface as a degree grid on −180.07…−179.93 and on 179.93…180.07."""
    write_geographic(tmp_path / "ref.tif", moon, 180.0, 10.0, 2000.0)

    def heights(lon, lat):
        return surface(lon + 360.0, lat, 180.0, 10.0, moon.radius)

    write_geographic(tmp_path / "dem.tif", moon, -180.0, 10.0, 2000.0, heights_of=heights)
    out = tmp_path / "report"
    result = _invoke(tmp_path / "dem.tif", tmp_path / "ref.tif", "--out", out, "--no-plots",
                     "--align", "none")
    assert result.exit_code == 0, result.output
    report = dio.read_json(out / "report.json")
    assert report["completeness"] > 99.0 and report["rmse"] < 0.05


def test_image_frame_dem_against_a_map_dem_is_refused(moon, tmp_path):
    write_geographic(tmp_path / "ref.tif", moon, 10.0, 10.0, 2000.0)
    dio.write_raster(tmp_path / "dem.tif", np.zeros((64, 64)),
                     transform=dio.image_frame_transform(25.0), tags={"frame": "image:left"})
    out = tmp_path / "report"
    result = _invoke(tmp_path / "dem.tif", tmp_path / "ref.tif", "--out", out)
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert result.exit_code == 1 and len(errors) == 1, result.output
    assert (f"{tmp_path / 'dem.tif'}: is in an image's pixel frame (image:left, no CRS) but "
            f"the reference {tmp_path / 'ref.tif'} is on a map") in errors[0]
    assert not out.exists()
