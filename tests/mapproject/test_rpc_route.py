"""The RPC route through mapproject: heights above WGS 84, the grid from the RPC's
footprint, --t-srs, a grid along the pair's parallax, and the inputs that cannot go
together refused in one line."""

import numpy as np
import pytest
from click.testing import CliRunner

from demtool.cli import cli
from tests.sensors.test_rpc import rpc_dict, write_tif

SIZE = (100, 80)


def small_rpc(height_sign=1.0, **changes):
    """rpc_dict's model on a 100 × 80 px image (~55 m pixels at 45° N, 5° E); the height
    term of the line (the parallax) scaled by ``height_sign``."""
    rpc = rpc_dict()
    rpc.update(line_off=50.0, samp_off=40.0, line_scale=50.0, samp_scale=40.0)
    rpc["line_num_coeff"] = rpc["line_num_coeff"].copy()
    rpc["line_num_coeff"][3] *= height_sign
    rpc.update(changes)
    return rpc


def ramp_image(path, rpc):
    """A GeoTIFF with the RPC in its tags whose pixel values are their line index."""
    import rasterio

    write_tif(path, rpc, size=SIZE)
    with rasterio.open(path, "r+") as ds:
        ds.write(np.repeat(np.arange(SIZE[0], dtype=np.uint8)[:, None], SIZE[1], 1)[None])
    return path


def invoke(*args):
    return CliRunner().invoke(cli, ["-q", *map(str, args)])


def test_mapproject_an_rpc_on_wgs84_heights(tmp_path):
    import rasterio

    from demtool.maps import map_to_xyz
    from demtool.sensors import read_sensor

    image = ramp_image(tmp_path / "left.tif", small_rpc())
    out = tmp_path / "ortho.tif"
    result = invoke("mapproject", image, "--sensor", image, "--height", 700, "--gsd", 60,
                    "--out", out)
    assert result.exit_code == 0, result.output
    model = read_sensor(image)
    with rasterio.open(out) as ds:
        values, transform, crs = ds.read(1), ds.transform, ds.crs
        assert ds.tags()["height_reference"] == "ellipsoid"
    assert 'SPHEROID["WGS 84"' in crs.to_wkt()
    # every seen cell holds the raw line its ground point (at 700 m above WGS 84) falls on
    rows, cols = np.nonzero(np.isfinite(values))
    pick = np.linspace(0, rows.size - 1, 25).astype(int)
    x = transform.a * (cols[pick] + 0.5) + transform.c
    y = transform.e * (rows[pick] + 0.5) + transform.f
    line, _ = model.ground_to_image(map_to_xyz(crs, np.array(x), np.array(y), 700.0))
    inside = (line > 2) & (line < SIZE[0] - 2)
    np.testing.assert_allclose(values[rows[pick], cols[pick]][inside], line[inside] - 0.5,
                               atol=0.02)
    assert np.isfinite(values).mean() > 0.6


def test_t_srs_and_its_refusals(tmp_path):
    import rasterio

    image = ramp_image(tmp_path / "left.tif", small_rpc())
    out = tmp_path / "utm.tif"
    result = invoke("mapproject", image, "--sensor", image, "--height", 700, "--gsd", 60,
                    "--t-srs", "EPSG:32631", "--out", out)
    assert result.exit_code == 0, result.output
    with rasterio.open(out) as ds:
        assert ds.crs.to_epsg() == 32631
        assert ds.transform.a == 60.0 and ds.transform.c % 60.0 == 0.0
    for value, message in (
            ("IAU_2015:49910", "is a CRS of Mars but the data are of Earth"),
            ("EPSG:4326", "'WGS 84' is not a projected CRS"),
            ("EPSG:999999", "PROJ does not know this CRS")):
        result = invoke("mapproject", image, "--sensor", image, "--height", 700, "--t-srs",
                        value, "--out", tmp_path / "no.tif")
        assert result.exit_code == 1, result.output
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and f"--t-srs {value}: " in lines[0] and message in lines[0]
    assert not (tmp_path / "no.tif").exists()


@pytest.mark.parametrize("args, message", [
    (("--height", 9000), "--height 9000: height 9000 m lies outside the RPC's validity "
                         "domain -300…1300 m"),
    (("--height", 700, "--grid-like", "ELSEWHERE"), "no map cell sees the image"),
    (("--dem", "DEM"), "DEM has no valid height under the image's footprint"),
    (("--dem", "GEOID_DEM"), "DEM heights are above 'EGM96 height'"),
])
def test_inputs_that_do_not_go_together_are_one_line(tmp_path, args, message):
    """A height outside the RPC's domain; an image of another place than the grid of its
    pair's ortho; a DEM of another place."""
    from affine import Affine

    from demtool import io as dio

    image = ramp_image(tmp_path / "left.tif", small_rpc())
    far = ramp_image(tmp_path / "far.tif", small_rpc(lat_off=47.0, long_off=9.0))
    elsewhere = tmp_path / "elsewhere.tif"
    assert invoke("mapproject", far, "--sensor", far, "--height", 700, "--gsd", 60, "--out",
                  elsewhere).exit_code == 0
    dem = tmp_path / "dem.tif"  # UTM 32 N near 9° E, 47° N: not under the image
    dio.write_raster(dem, np.full((50, 50), 600.0, np.float32), crs="EPSG:32632",
                     transform=Affine(60.0, 0.0, 500000.0, 0.0, -60.0, 5206000.0))
    geoid_dem = tmp_path / "geoid_dem.tif"  # heights above EGM96: refused as read
    dio.write_raster(geoid_dem, np.full((50, 50), 600.0, np.float32), crs="EPSG:32631+5773",
                     transform=Affine(200.0, 0.0, 690000.0, 0.0, -200.0, 4990000.0))
    args = [{"ELSEWHERE": elsewhere, "DEM": dem, "GEOID_DEM": geoid_dem}.get(a, a)
            for a in args]
    result = invoke("mapproject", image, "--sensor", image, *args, "--out",
                    tmp_path / "o.tif")
    assert result.exit_code in (1, 2), result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], result.output
    assert not (tmp_path / "o.tif").exists()


def test_pair_sensor_turns_the_grid_along_the_parallax(tmp_path):
    """A point above the projection surface lands in the two orthoimages at one map y:
    the parallax runs along the grid's x, where sgm searches."""
    from demtool.mapproject.core import sensor_body
    from demtool.mapproject.parallax import parallax_azimuth
    from demtool.maps import lonlat_height_to_xyz, xyz_to_map
    from demtool.sensors import read_sensor

    left_path = ramp_image(tmp_path / "left.tif", small_rpc())
    right_path = write_tif(tmp_path / "right.tif", small_rpc(height_sign=-1.0), size=SIZE)
    out = tmp_path / "left_ortho.tif"
    result = invoke("mapproject", left_path, "--sensor", left_path, "--pair-sensor",
                    right_path, "--height", 500, "--gsd", 60, "--out", out)
    assert result.exit_code == 0, result.output
    import rasterio

    with rasterio.open(out) as ds:
        crs = ds.crs
    assert "Oblique Mercator" in crs.to_wkt()
    left, right = read_sensor(left_path), read_sensor(right_path)
    body = sensor_body(left)
    lon, lat, azimuth = parallax_azimuth(left, right, body, 500.0)
    assert abs(abs(azimuth) - 180.0) < 30.0 or abs(azimuth) < 30.0  # line parallax: N-S
    above = lonlat_height_to_xyz(lon + 0.01, lat - 0.01, 900.0, radii=body.surface)
    ys = []
    for model in (left, right):
        line, sample = model.ground_to_image(above[None])
        on_surface = model.image_to_ground(line, sample, 500.0)
        x, y, _ = xyz_to_map(crs, on_surface)
        ys.append((float(x[0]), float(y[0])))
    (x0, y0), (x1, y1) = ys
    assert abs(x1 - x0) > 50.0  # 400 m above the surface: parallax of a pixel or more
    assert abs(y1 - y0) < 0.02 * abs(x1 - x0)


def test_bundle_refuses_rpc_models_in_one_line(tmp_path):
    """An RPC carries no camera position or attitude to adjust (issue 46: a LinAlgError
    traceback before)."""
    left = ramp_image(tmp_path / "left.tif", small_rpc())
    right = ramp_image(tmp_path / "right.tif", small_rpc(height_sign=-1.0))
    result = invoke("bundle", left, right, "--sensors", left, "--sensors", right, "--out",
                    tmp_path / "bundle.npz")
    assert result.exit_code == 1, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and "left.tif: is an RPC model, which has no camera position" \
        in lines[0]
    assert not (tmp_path / "bundle.npz").exists()


def test_camera_puts_an_rpc_where_mapproject_does(tmp_path):
    """camera's ground of an RPC is at its height offset above WGS 84, the centre's
    latitude geodetic: the model's own image_to_lonlat (issue 46: the sphere elsewhere)."""
    import json

    from demtool.sensors import read_sensor

    left = ramp_image(tmp_path / "left.tif", small_rpc())
    right = ramp_image(tmp_path / "right.tif", small_rpc(height_sign=-1.0))
    result = CliRunner().invoke(cli, ["-q", "camera", str(left), str(right), "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    model = read_sensor(left)
    lon, lat = model.image_to_lonlat(0.5 * SIZE[0], 0.5 * SIZE[1], 500.0)
    first = report["cameras"][0]
    assert first["center_lat_deg"] == pytest.approx(float(lat), abs=1e-9)
    assert first["center_lon_deg"] == pytest.approx(float(lon), abs=1e-9)
    pair = report["pairs"][0]
    assert pair["overlap_fraction_first"] > 0.5
