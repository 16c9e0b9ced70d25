"""`demtool refine` on the body's map: an orthoimage of a synthetic lunar line-scan view,
shaded with the sun and view of its sensor model in each point's local frame; the refined
DEM must come closer to the truth than the smoothed input, in one piece or per tile; and
the map route's bad inputs."""

import json

import numpy as np
import pytest
from affine import Affine
from click.testing import CliRunner
from scipy.ndimage import gaussian_filter

from demtool import io as dio
from demtool.cli import cli
from demtool.imaging.reflectance import get_model
from demtool.mapproject.core import ortho_grid
from demtool.maps import MapGrid, grid_lonlat, snap_grid
from demtool.refine.geometry import illumination_grid
from demtool.refine.shading import slopes
from tests.helpers.linescan import MOON, R, isd_dict, linescan_sensor

BORDER = 12


def relief(lon, lat):
    """Gentle hills (slopes under 15 deg), metres above the sphere."""
    x = np.radians(lon - 10.0) * R * np.cos(np.radians(5.0))
    y = np.radians(lat - 5.0) * R
    return (1.2 * np.sin(2 * np.pi * x / 29.0) * np.cos(2 * np.pi * y / 23.0)
            + 0.8 * np.cos(2 * np.pi * (0.6 * x + 0.8 * y) / 17.0))


@pytest.fixture(scope="module")
def map_scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("refine_map")
    sensor = linescan_sensor(lines=180, samples=180, roll_deg=8.0, sun_azimuth_deg=100.0,
                             sun_elevation_deg=35.0, name="ls_map")
    isd = folder / "ls_map.json"
    isd.write_text(json.dumps(isd_dict(sensor)))
    grid = ortho_grid(sensor, MOON, height=0.0)
    grid = snap_grid(grid.crs, *grid.bounds(), 1.0)
    # keep the cells well inside the footprint
    t = grid.transform
    grid = MapGrid(crs=grid.crs, transform=Affine(1.0, 0, t.c + 15, 0, -1.0, t.f - 15),
                   width=grid.width - 30, height=grid.height - 30)
    lon, lat = grid_lonlat(grid)
    truth = relief(lon, lat)
    x, y = grid.cell_centers()
    light = illumination_grid(sensor, grid.crs, x, y, truth)
    assert light.seen.all()
    p, q = slopes(truth, (1.0, 1.0))
    norm = np.sqrt(1 + p * p + q * q)

    def cos(v):
        return (v[..., 2] - p * v[..., 0] - q * v[..., 1]) / norm

    phase = np.degrees(np.arccos(np.sum(light.sun * light.view, axis=-1)))
    image = get_model("lunar-lambert")(cos(light.sun), cos(light.view), phase, 0.3)
    ortho = folder / "ortho.tif"
    dio.write_raster(ortho, image, transform=grid.transform, crs=grid.crs,
                     tags={**MOON.tags(), "mapproject_sensor": str(isd), "frame": "map"})
    coarse = gaussian_filter(truth, 4.0)
    dem = folder / "dem.tif"
    dio.write_raster(dem, coarse, transform=grid.transform, crs=grid.crs, tags=MOON.tags())
    return {"folder": folder, "ortho": ortho, "dem": dem, "truth": truth, "coarse": coarse,
            "grid": grid, "isd": isd, "image": image, "sensor": sensor}


def rmse(a, b):
    inner = (slice(BORDER, -BORDER),) * 2
    return float(np.sqrt(np.mean((a[inner] - b[inner]) ** 2)))


def invoke(*args):
    return CliRunner().invoke(cli, ["refine", *map(str, args)])


def test_sun_and_view_in_local_frame(map_scene):
    """East-azimuth sun (100 deg clockwise from north) at 35 deg: the grid-frame sun
    vector has x > 0 (east), slightly y < 0, elevation 35 deg; the rolled view leans west."""
    grid, sensor = map_scene["grid"], map_scene["sensor"]
    x, y = grid.cell_centers()
    light = illumination_grid(sensor, grid.crs, x[::40, ::40], y[::40, ::40], 0.0)
    sun = light.sun.reshape(-1, 3)
    elevation = np.degrees(np.arcsin(sun[:, 2]))
    azimuth = np.degrees(np.arctan2(sun[:, 0], sun[:, 1])) % 360
    # the footprint is ~7 km west of the sun's reference point: the local frame turns by
    # 7 km / R = 0.23 deg
    assert np.allclose(elevation, 35.0, atol=0.5) and np.allclose(azimuth, 100.0, atol=0.5)
    view = light.view.reshape(-1, 3)
    assert (view[:, 0] < 0).all()
    assert np.allclose(np.degrees(np.arccos(view[:, 2])), 8.0 * (1 + 50e3 / R), atol=0.8)


@pytest.mark.slow
def test_refine_on_map_improves_dem(map_scene, tmp_path):
    out = tmp_path / "refined.tif"
    result = invoke(map_scene["ortho"], map_scene["dem"], "--out", out, "--median", 0)
    assert result.exit_code == 0, result.output
    refined = dio.read_raster(out)
    assert refined.crs == dio.read_raster(map_scene["dem"]).crs
    before = rmse(map_scene["coarse"], map_scene["truth"])
    after = rmse(refined.data, map_scene["truth"])
    print(f"map route RMSE {before:.3f} -> {after:.3f} m")
    assert after < 0.6 * before, (before, after)
    sidecar = json.loads((tmp_path / "refined.tif.json").read_text())
    route = sidecar["summary"]["map_route"]
    assert route["illumination_spread_deg"] < 1.0 and "tiles" not in route
    assert "sensor model" in sidecar["summary"]["sun_source"]


@pytest.mark.slow
def test_refine_on_map_per_tile(map_scene, tmp_path):
    out = tmp_path / "refined_tiles.tif"
    result = invoke(map_scene["ortho"], map_scene["dem"], "--out", out, "--median", 0,
                    "--max-illumination-change", 0.01, "--illumination-tile", 96)
    assert result.exit_code == 0, result.output
    sidecar = json.loads((tmp_path / "refined_tiles.tif.json").read_text())
    assert sidecar["summary"]["map_route"]["tiles"] >= 4
    refined = dio.read_raster(out).data
    before = rmse(map_scene["coarse"], map_scene["truth"])
    assert rmse(refined, map_scene["truth"]) < 0.6 * before


def assert_refused(result, out, *words):
    assert result.exit_code == 1, result.output
    errors = [ln for ln in result.output.splitlines() if ln.startswith("Error")]
    assert len(errors) == 1, result.output
    for word in words:
        assert word in errors[0], errors[0]
    assert not out.exists()


def test_refuses_mosaic_without_sun(map_scene, tmp_path):
    mosaic = tmp_path / "mosaic.tif"
    grid = map_scene["grid"]
    dio.write_raster(mosaic, map_scene["image"], transform=grid.transform, crs=grid.crs,
                     tags=MOON.tags())
    out = tmp_path / "r.tif"
    assert_refused(invoke(mosaic, map_scene["dem"], "--out", out), out, str(mosaic),
                   "mosaic")


def test_refuses_degree_dem_of_unknown_body(map_scene, tmp_path):
    dem = tmp_path / "degrees.tif"
    dio.write_raster(dem, np.zeros((40, 40)), transform=Affine(0.01, 0, 10, 0, -0.01, 5),
                     crs="+proj=longlat +R=1000 +no_defs")
    out = tmp_path / "r.tif"
    assert_refused(invoke(map_scene["ortho"], dem, "--out", out), out, str(dem), "degrees",
                   "unknown body")


def test_refuses_sensor_with_image_frame_dem(map_scene, tmp_path):
    dem = tmp_path / "frame_dem.tif"
    dio.write_raster(dem, np.zeros((30, 30)))
    out = tmp_path / "r.tif"
    assert_refused(invoke(map_scene["ortho"], dem, "--out", out, "--sensor",
                          map_scene["isd"]), out, str(dem), "body's map")


@pytest.mark.slow
def test_refine_raw_image_with_sensor(map_scene, tmp_path):
    """The raw line-scan image (the shaded map sampled where each pixel's ray meets the
    relief) with --sensor is map-projected onto the DEM inside refine."""
    from scipy.interpolate import RegularGridInterpolator

    from demtool.maps import lonlat_to_map
    from tests.helpers.linescan import render

    grid, sensor = map_scene["grid"], map_scene["sensor"]
    x, y = grid.cell_centers()
    shade = RegularGridInterpolator((y[::-1, 0], x[0]), map_scene["image"][::-1],
                                    bounds_error=False, fill_value=np.nan)

    def pattern(lon, lat):
        mx, my = lonlat_to_map(grid.crs, lon, lat)
        return shade(np.stack([my, mx], axis=-1))

    raw = tmp_path / "raw.tif"
    dio.write_raster(raw, render(sensor, relief, pattern))
    out = tmp_path / "refined_raw.tif"
    result = invoke(raw, map_scene["dem"], "--out", out, "--median", 0, "--sensor",
                    map_scene["isd"])
    assert result.exit_code == 0, result.output
    refined = dio.read_raster(out).data
    before = rmse(map_scene["coarse"], map_scene["truth"])
    assert rmse(refined, map_scene["truth"]) < 0.6 * before


def test_dem_far_from_the_footprint_is_blamed_on_the_dem(map_scene, tmp_path):
    """Issue 31, class 7: a DEM 100 km east of what the raw image sees is refused naming
    the DEM and the footprint (was: 'the sun is below the horizon')."""
    grid = map_scene["grid"]
    raw = tmp_path / "raw.tif"
    rng = np.random.default_rng(0)
    dio.write_raster(raw, rng.uniform(0.2, 0.4, (180, 180)))
    t = grid.transform
    far = tmp_path / "far_dem.tif"
    dio.write_raster(far, map_scene["coarse"], crs=grid.crs, tags=MOON.tags(),
                     transform=Affine(t.a, 0, t.c + 100e3, 0, t.e, t.f))
    out = tmp_path / "r.tif"
    result = invoke(raw, far, "--sensor", map_scene["isd"], "--out", out)
    assert_refused(result, out, f"{far}: the DEM lies outside the footprint of {raw}")
    assert "horizon" not in result.output


def _hashed_ortho(map_scene, folder, sensor_path):
    """The scene's orthoimage tagged, as ``mapproject`` tags it, with the SHA-256 of the
    sensor model it was made through."""
    from demtool.mapproject.hashes import SENSOR_HASH_TAG
    from demtool.provenance import file_sha256

    grid = map_scene["grid"]
    ortho = folder / "hashed_ortho.tif"
    dio.write_raster(ortho, map_scene["image"], transform=grid.transform, crs=grid.crs,
                     tags={**MOON.tags(), "frame": "map", "mapproject_sensor": str(sensor_path),
                           SENSOR_HASH_TAG: file_sha256(sensor_path)})
    return ortho


@pytest.mark.parametrize("tile_size", [0, 64])
def test_refuses_ortho_whose_sensor_changed_since(map_scene, tmp_path, tile_size):
    """Issue 31, class 4 (the sun turned after mapproject made refine 6× worse): the
    orthoimage's sensor model edited afterwards is refused, untiled and in tiles."""
    isd = tmp_path / "own.json"
    isd.write_text(map_scene["isd"].read_text())
    ortho = _hashed_ortho(map_scene, tmp_path, isd)
    isd.write_text(json.dumps(json.loads(isd.read_text()), indent=1))
    out = tmp_path / "r.tif"
    result = invoke(ortho, map_scene["dem"], "--out", out, "--tile-size", tile_size)
    assert_refused(result, out, f"{ortho}: its sensor model {isd} has changed since it was "
                   "map-projected")


def test_refuses_ortho_with_another_images_sensor(map_scene, tmp_path):
    """An orthoimage given with ``--sensor`` of another image (a swapped pair of models):
    refused naming both, not shaded with the other image's sun and view."""
    ortho = _hashed_ortho(map_scene, tmp_path, map_scene["isd"])
    other = linescan_sensor(lines=180, samples=180, roll_deg=-8.0, sun_azimuth_deg=250.0,
                            sun_elevation_deg=20.0, name="ls_other")
    other_isd = tmp_path / "other.json"
    other_isd.write_text(json.dumps(isd_dict(other)))
    out = tmp_path / "r.tif"
    result = invoke(ortho, map_scene["dem"], "--out", out, "--sensor", other_isd)
    assert_refused(result, out, f"{ortho}: is an orthoimage map-projected through "
                   f"{map_scene['isd']}, not through --sensor {other_isd}")


def test_ortho_with_its_own_sensor_given_is_used_as_is(map_scene, tmp_path):
    """The orthoimage's own model given as ``--sensor``: taken as an orthoimage (not
    map-projected a second time), the sun from that model."""
    ortho = _hashed_ortho(map_scene, tmp_path, map_scene["isd"])
    out = tmp_path / "r.tif"
    result = invoke(ortho, map_scene["dem"], "--out", out, "--sensor", map_scene["isd"],
                    "--iterations", 3, "--median", 0)
    assert result.exit_code == 0, result.output
    sidecar = json.loads((tmp_path / "r.tif.json").read_text())
    assert str(map_scene["isd"]) in sidecar["summary"]["sun_source"]
    refined = dio.read_raster(out).data
    assert rmse(refined, map_scene["truth"]) < rmse(map_scene["coarse"], map_scene["truth"])
