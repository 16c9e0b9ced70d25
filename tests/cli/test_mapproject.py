"""`demtool mapproject` end to end: a synthetic lunar line-scan image projected onto the
truth DEM equals the scene seen from straight above; the sphere route; the real mission
ISDs (data-marked); every bad input."""

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from demtool.mapproject.core import ortho_grid
from demtool.maps import MapGrid, body_by_name, grid_lonlat, map_to_xyz, snap_grid, xyz_to_map
from tests.helpers.linescan import (
    MOON,
    isd_dict,
    linescan_sensor,
    texture,
    write_scene,
    write_truth_dem,
)

SHARED = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "sensors" / "ale"


def invoke(*args):
    return CliRunner().invoke(cli, ["mapproject", *map(str, args)])


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A rolled line-scan view of the analytic terrain, its ISD and the truth DEM."""
    folder = tmp_path_factory.mktemp("linescan")
    sensor = linescan_sensor(lines=260, samples=180, roll_deg=15.0)
    image, isd = write_scene(folder, sensor)
    grid = ortho_grid(sensor, MOON, height=0.0)
    grid = snap_grid(grid.crs, *grid.bounds(), 1.0)
    dem = write_truth_dem(folder / "truth_dem_map.tif", grid)
    return {"folder": folder, "sensor": sensor, "image": image, "isd": isd, "dem": dem,
            "grid": grid}


def shift_px(ortho, truth, gsd):
    """Least-squares shift (dx, dy) in map pixels that best explains ortho − truth by the
    truth's gradient (first-order image registration, Lucas & Kanade 1981)."""
    gy, gx = np.gradient(truth)
    ok = np.isfinite(ortho) & np.isfinite(gx) & np.isfinite(gy)
    design = np.column_stack([gx[ok], gy[ok]])
    delta, *_ = np.linalg.lstsq(design, (truth - ortho)[ok], rcond=None)
    return delta


def test_mapproject_onto_truth_dem_equals_view_from_above(scene, tmp_path):
    out = tmp_path / "ortho.tif"
    angles = tmp_path / "angles.tif"
    result = invoke(scene["image"], "--sensor", scene["isd"], "--dem", scene["dem"],
                    "--out", out, "--angles-out", angles, "--tile-size", "96")
    assert result.exit_code == 0, result.output
    ortho = dio.read_raster(out)
    grid = MapGrid(crs=scene["grid"].crs, transform=ortho.transform,
                   width=ortho.data.shape[1], height=ortho.data.shape[0])
    assert grid.gsd == (1.0, 1.0)
    lon, lat = grid_lonlat(grid)
    truth = texture(lon, lat)  # the ground pattern seen from straight above
    seen = np.isfinite(ortho.data)
    assert seen.mean() > 0.9
    diff = ortho.data - truth
    assert np.sqrt(np.nanmean(diff**2)) < 0.02 * np.std(truth)
    # geometric error: overall and in each quarter
    assert np.hypot(*shift_px(ortho.data, truth, 1.0)) < 0.05
    h, w = truth.shape
    for rows in (slice(0, h // 2), slice(h // 2, h)):
        for cols in (slice(0, w // 2), slice(w // 2, w)):
            assert np.hypot(*shift_px(ortho.data[rows, cols], truth[rows, cols], 1.0)) < 0.1
    # the tags that let later stages undo the projection
    tags = ortho.tags
    assert Path(tags["mapproject_sensor"]) == scene["isd"].resolve()
    assert tags["mapproject_surface"] == "dem"
    assert Path(tags["mapproject_dem"]) == scene["dem"].resolve()
    assert tags["body"] == "Moon" and tags["frame"] == "map"
    sidecar = json.loads(Path(f"{out}.json").read_text())
    assert sidecar["summary"]["max_interpolation_error_px"] <= 0.01
    # angles: at the image centre's ground point (13 km west of the sun's reference
    # point, since the view is rolled 15 deg), from the sun and sensor positions
    sensor = scene["sensor"]
    centre = sensor.image_to_ground(0.5 * sensor.lines, 0.5 * sensor.samples)
    normal = centre / np.linalg.norm(centre)
    sun = sensor.sun_position(0.5 * sensor.lines) - centre
    view = sensor.camera_center(0.5 * sensor.lines) - centre
    want_i = np.degrees(np.arccos(normal @ sun / np.linalg.norm(sun)))
    want_e = np.degrees(np.arccos(normal @ view / np.linalg.norm(view)))
    assert 59.0 < want_i < 60.0 and 15.0 < want_e < 16.0
    incidence = dio.read_raster(angles, band=1).data
    emission = dio.read_raster(angles, band=2).data
    assert np.nanmedian(incidence) == pytest.approx(want_i, abs=0.05)
    assert np.nanmedian(emission) == pytest.approx(want_e, abs=0.05)
    assert np.array_equal(np.isfinite(incidence), seen)


def ramp_images(folder, sensor):
    """Two images whose values are their own line and sample (CSM coordinates)."""
    line, sample = np.meshgrid(np.arange(sensor.lines) + 0.5, np.arange(sensor.samples) + 0.5,
                               indexing="ij")
    paths = folder / "lines.tif", folder / "samples.tif"
    dio.write_raster(paths[0], line)
    dio.write_raster(paths[1], sample)
    return paths


def check_corners(sensor, isd, folder, height, *, gsd=None, tolerance=0.1, args=()):
    """Mapproject line and sample ramps; at the cells under the image's corners the
    resampled (line, sample) equal the model's projection of the cells' ground points."""
    outs = []
    for ramp in ramp_images(folder, sensor):
        out = folder / f"{ramp.stem}_ortho.tif"
        extra = (["--gsd", gsd] if gsd else []) + list(args)
        result = invoke(ramp, "--sensor", isd, "--height", height, "--out", out, *extra)
        assert result.exit_code == 0, result.output
        outs.append(dio.read_raster(out))
    grid = MapGrid(crs=outs[0].crs, transform=outs[0].transform,
                   width=outs[0].data.shape[1], height=outs[0].data.shape[0])
    inset = 2.0
    corners_line = np.array([inset, inset, sensor.lines - inset, sensor.lines - inset])
    corners_sample = np.array([inset, sensor.samples - inset, inset, sensor.samples - inset])
    ray = sensor.image_to_ray(corners_line, corners_sample)
    from demtool.sensors import ray_ellipsoid_intersection

    radius = float(outs[0].tags["reference_sphere_radius_m"])
    xyz = ray_ellipsoid_intersection(ray.origin, ray.direction, radius, radius, height)
    x, y, _ = xyz_to_map(grid.crs, xyz)
    t = grid.transform
    inv = ~t
    col0 = np.floor(inv.a * x + inv.b * y + inv.c).astype(int)
    row0 = np.floor(inv.d * x + inv.e * y + inv.f).astype(int)
    for k in range(4):
        # the cells around the corner's ground point (a map cell can span many image
        # lines of a narrow line scanner: take those whose centre the image sees)
        rows, cols = np.meshgrid(row0[k] + np.arange(-2, 3), col0[k] + np.arange(-2, 3),
                                 indexing="ij")
        inside = (rows >= 0) & (rows < grid.height) & (cols >= 0) & (cols < grid.width)
        rows, cols = rows[inside], cols[inside]
        got_line = outs[0].data[rows, cols]
        got_sample = outs[1].data[rows, cols]
        seen = np.isfinite(got_line) & np.isfinite(got_sample)
        assert seen.any(), f"corner {k}: no orthoimage cell near it"
        rows, cols = rows[seen], cols[seen]
        cx, cy = t.a * (cols + 0.5) + t.c, t.e * (rows + 0.5) + t.f
        want_line, want_sample = sensor.ground_to_image(map_to_xyz(grid.crs, cx, cy, height))
        # cells whose 4 x 4 bicubic support lies on the image (nearer the edge the edge
        # pixels are repeated, so a ramp is not reproduced)
        full = ((want_line >= 1.5) & (want_line <= sensor.lines - 1.5) & (want_sample >= 1.5)
                & (want_sample <= sensor.samples - 1.5))
        assert full.any(), f"corner {k}: no cell well inside the image"
        err = np.hypot(got_line[seen] - want_line, got_sample[seen] - want_sample)[full]
        assert err.max() < tolerance, (k, err)
        # the nearest seen cell is within 1.5 cells of the corner's ground point
        near = np.hypot(cx - x[k], cy - y[k]).min() / grid.gsd[0]
        assert near < 1.5, (k, near)
    return grid


def test_mapproject_on_sphere_corners_land_back(tmp_path):
    sensor = linescan_sensor(lines=150, samples=120, roll_deg=-20.0)
    isd = tmp_path / "ls.json"
    isd.write_text(json.dumps(isd_dict(sensor)))
    grid = check_corners(sensor, isd, tmp_path, 250.0)
    assert grid.gsd[0] == pytest.approx(1.0 / np.cos(np.radians(20.0)), rel=0.03)


@pytest.mark.data
@pytest.mark.slow
@pytest.mark.parametrize("name, gsd", [("hirise", None), ("lrolroc", None), ("ctx", None)])
def test_mapproject_real_isd_corners_land_back(tmp_path, name, gsd):
    """On the real mission ISDs.  (MOC's fixture is refused: its pointing samples start
    1.15 s after its last line, tests/sensors/test_coverage.py.)"""
    path = SHARED / f"{name}_isd.json"
    if not path.exists():
        pytest.skip("../shared/data is absent")
    from demtool.sensors import read_sensor

    sensor = read_sensor(path)
    check_corners(sensor, path, tmp_path, 0.0, gsd=gsd)


# ---------------------------------------------------------------------------------------
# Bad input: one line naming the file or option, exit 1 (2 for usage), nothing written
# ---------------------------------------------------------------------------------------


def assert_refused(result, out, *words, code=1):
    assert result.exit_code == code, result.output
    if code == 1:
        lines = [ln for ln in result.output.strip().splitlines() if ln.startswith("Error")]
        assert len(lines) == 1, result.output
        for word in words:
            assert word in lines[0], lines[0]
    assert not Path(out).exists()
    assert not list(Path(out).parent.glob(Path(out).name + "*"))


def test_refuses_dem_of_another_body(scene, tmp_path):
    mars = body_by_name("Mars")
    grid = scene["grid"]
    from demtool.maps import make_projection

    crs = make_projection(mars, "equirectangular", 10.0, 5.0)
    dem = tmp_path / "mars_dem.tif"
    dio.write_raster(dem, np.zeros(grid.shape), transform=grid.transform, crs=crs,
                     tags=mars.tags())
    out = tmp_path / "o.tif"
    result = invoke(scene["image"], "--sensor", scene["isd"], "--dem", dem, "--out", out)
    assert_refused(result, out, str(dem), "Mars", "Moon")


def test_ortho_on_the_sphere_covers_the_camera_footprint(scene, tmp_path):
    """Issue 12: without a DEM, the orthoimage's footprint is `demtool camera`'s."""
    from demtool.camera.info import footprint
    from demtool.sensors.polygons import point_in_polygon, polygon_area

    out = tmp_path / "sphere.tif"
    result = invoke(scene["image"], "--sensor", scene["isd"], "--height", 0, "--out", out)
    assert result.exit_code == 0, result.output
    ortho = dio.read_raster(out)
    outline = footprint(scene["sensor"], MOON, points_per_edge=64)
    x, y, _ = xyz_to_map(ortho.crs, outline.xyz)
    rows, cols = np.nonzero(np.isfinite(ortho.data))
    t = ortho.transform
    cx = t.c + t.a * (cols + 0.5) + t.b * (rows + 0.5)
    cy = t.f + t.d * (cols + 0.5) + t.e * (rows + 0.5)
    inside = point_in_polygon(cx, cy, x, y)
    assert inside.mean() > 0.999  # every seen cell is inside the camera's footprint
    gsd = abs(t.a)
    seen_area, outline_area = rows.size * gsd * abs(t.e), abs(polygon_area(x, y))
    # the ortho loses the bicubic kernel's half-width (~1.5 px) along the image border
    border = 1.5 * gsd * 2 * (np.ptp(x) + np.ptp(y))
    assert outline_area - border < seen_area <= outline_area * 1.001


def test_refine_refuses_a_dem_of_another_body_than_its_sensor(scene, tmp_path):
    """refine on the map: a Mars DEM with a lunar image and sensor, raw and ortho routes."""
    from demtool.maps import make_projection

    mars = body_by_name("Mars")
    grid = scene["grid"]
    dem = tmp_path / "mars_dem.tif"
    dio.write_raster(dem, np.zeros(grid.shape), transform=grid.transform,
                     crs=make_projection(mars, "equirectangular", 10.0, 5.0), tags=mars.tags())
    out = tmp_path / "refined.tif"
    raw = CliRunner().invoke(cli, ["refine", str(scene["image"]), str(dem), "--sensor",
                                   str(scene["isd"]), "--out", str(out)])
    assert_refused(raw, out, str(dem), "Mars", "Moon", str(scene["isd"]))
    ortho = tmp_path / "ortho.tif"
    made = invoke(scene["image"], "--sensor", scene["isd"], "--dem", scene["dem"], "--out",
                  ortho)
    assert made.exit_code == 0, made.output
    tagged = CliRunner().invoke(cli, ["refine", str(ortho), str(dem), "--out", str(out)])
    assert_refused(tagged, out, str(dem), "Mars", "Moon")


def test_refuses_dem_without_crs(scene, tmp_path):
    dem = tmp_path / "frame_dem.tif"
    dio.write_raster(dem, np.zeros((20, 20)))
    out = tmp_path / "o.tif"
    result = invoke(scene["image"], "--sensor", scene["isd"], "--dem", dem, "--out", out)
    assert_refused(result, out, str(dem), "no CRS")


def test_refuses_image_of_another_size(scene, tmp_path):
    image = tmp_path / "small.tif"
    dio.write_raster(image, np.ones((50, 40)))
    out = tmp_path / "o.tif"
    result = invoke(image, "--sensor", scene["isd"], "--height", 0, "--out", out)
    assert_refused(result, out, str(image), "40 x 50", "180 x 260")


def test_refuses_missing_sensor_and_non_sensor(scene, tmp_path):
    out = tmp_path / "o.tif"
    missing = tmp_path / "nope.json"
    result = invoke(scene["image"], "--sensor", missing, "--height", 0, "--out", out)
    assert_refused(result, out, str(missing))
    result = invoke(scene["image"], "--sensor", scene["dem"], "--height", 0, "--out", out)
    assert_refused(result, out, str(scene["dem"]), "sensor model")


def test_needs_exactly_one_surface(scene, tmp_path):
    out = tmp_path / "o.tif"
    both = invoke(scene["image"], "--sensor", scene["isd"], "--dem", scene["dem"], "--height",
                  0, "--out", out)
    assert_refused(both, out, code=2)
    assert "--dem" in both.output and "--height" in both.output
    neither = invoke(scene["image"], "--sensor", scene["isd"], "--out", out)
    assert_refused(neither, out, code=2)


def test_refuses_bad_bounds_and_area_off_the_image(scene, tmp_path):
    out = tmp_path / "o.tif"
    result = invoke(scene["image"], "--sensor", scene["isd"], "--height", 0, "--out", out,
                    "--bounds", 11, 5, 10, 6)
    assert_refused(result, out, code=2)  # a usage error (issue 31)
    assert "'--bounds'" in result.output and "MIN < MAX" in result.output
    result = invoke(scene["image"], "--sensor", scene["isd"], "--height", 0, "--out", out,
                    "--bounds", 40, 5, 40.01, 5.01)
    assert_refused(result, out, "--bounds: lon 40…40.01, lat 5…5.01 does not overlap the "
                   "image's footprint")


@pytest.mark.slow
def test_orthos_of_a_synth_linescan_pair_coincide(tmp_path):
    """`synth --sensor linescan` (its own renderer and ISD writer): both views
    map-projected onto truth_dem_map.tif land on one another (registration < 0.05 px)."""
    scene = tmp_path / "scene"
    result = CliRunner().invoke(cli, ["synth", "--sensor", "linescan", "--size", "128",
                                      "--image-size", "128", "--out", str(scene)])
    assert result.exit_code == 0, result.output
    meta = json.loads((scene / "scene.json").read_text())
    orthos = []
    for name in (meta["target"], meta["partner"]):
        out = tmp_path / f"{name}_ortho.tif"
        result = invoke(scene / f"{name}.tif", "--sensor", scene / f"{name}.json", "--dem",
                        scene / "truth_dem_map.tif", "--out", out)
        assert result.exit_code == 0, result.output
        orthos.append(dio.read_raster(out))
    a, b = (o.data.astype(np.float64) for o in orthos)
    assert orthos[0].transform == orthos[1].transform
    both = np.isfinite(a) & np.isfinite(b)
    assert both.mean() > 0.9
    inner = np.zeros_like(both)
    inner[4:-4, 4:-4] = True
    assert np.hypot(*shift_px(np.where(inner, b, np.nan), a, 1.0)) < 0.05


def test_grid_like_puts_the_ortho_on_that_grid(scene, tmp_path):
    """--grid-like: the output takes the given raster's grid (here the truth DEM's, so
    the ortho on the sphere covers exactly its cells)."""
    out = tmp_path / "ortho.tif"
    result = invoke(scene["image"], "--sensor", scene["isd"], "--height", 0, "--grid-like",
                    scene["dem"], "--out", out)
    assert result.exit_code == 0, result.output
    ortho, dem = dio.read_raster(out), dio.read_raster(scene["dem"])
    assert ortho.transform == dem.transform and ortho.data.shape == dem.data.shape
    assert ortho.crs == dem.crs
    assert np.isfinite(ortho.data).mean() > 0.5


def test_grid_like_refusals(scene, tmp_path):
    out = tmp_path / "ortho.tif"
    result = invoke(scene["image"], "--sensor", scene["isd"], "--height", 0, "--grid-like",
                    scene["dem"], "--gsd", 2, "--out", out)
    assert_refused(result, out, "--grid-like")
    frame = tmp_path / "frame.tif"
    dio.write_raster(frame, np.zeros((8, 8), np.float32), tags={"frame": "image:x"})
    result = invoke(scene["image"], "--sensor", scene["isd"], "--height", 0, "--grid-like",
                    frame, "--out", out)
    assert_refused(result, out, str(frame), "projected map")


def test_a_dem_of_radii_projects_like_its_heights(scene, tmp_path):
    """ISIS shape models (LOLA ldem_*, MOLA) store each post's distance from the body's
    centre: mapproject reads them as heights (radius subtracted), the same ortho."""
    heights = dio.read_raster(scene["dem"])
    radii = tmp_path / "ldem.tif"
    dio.write_raster(radii, heights.data.astype(np.float64) + MOON.radius,
                     transform=heights.transform, crs=heights.crs, tags=heights.tags)
    orthos = []
    for name, dem in (("heights", scene["dem"]), ("radii", radii)):
        out = tmp_path / f"{name}.tif"
        result = invoke(scene["image"], "--sensor", scene["isd"], "--dem", dem, "--out", out)
        assert result.exit_code == 0, result.output
        orthos.append(dio.read_raster(out).data)
    # float32 radii near 1.7e6 m hold heights to 1/8 m: edge cells may differ
    seen = np.isfinite(orthos[0])
    assert seen.mean() > 0.9 and (seen == np.isfinite(orthos[1])).mean() > 0.995
    difference = (orthos[0] - orthos[1])[seen & np.isfinite(orthos[1])]
    assert np.sqrt(np.mean(difference**2)) < 0.01 * np.nanstd(orthos[0])
