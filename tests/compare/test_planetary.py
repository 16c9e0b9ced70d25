"""Planetary CRS checks of compare: one body, reference surfaces, degree grids in metres."""

import numpy as np
import pytest
from affine import Affine
from rasterio.crs import CRS

from demtool import maps
from demtool.compare.grids import Grid, resample_to_grid
from demtool.compare.planetary import check_bodies, metric_grid
from demtool.errors import InputError, ProcessingError
from demtool.maps.bodies import body_label


def test_check_bodies_accepts_one_body_and_skips_rasters_without_crs():
    moon_eqc = CRS.from_user_input("IAU_2015:30110")
    moon_polar = CRS.from_wkt(maps.make_projection(maps.body_by_naif_id(301), "auto", 0,
                                                   -85).to_wkt())
    assert check_bodies([("a.tif", moon_eqc), ("b.tif", None), ("c.tif", moon_polar)]) == []


def test_check_bodies_refuses_two_bodies_naming_both_files():
    with pytest.raises(InputError) as info:
        check_bodies([("ref.tif", "IAU_2015:30100"), ("dem.tif", "IAU_2015:49910")])
    message = str(info.value)
    assert message.startswith("dem.tif: is on Mars (NAIF 499, sphere R=3396190 m)")
    assert "ref.tif is on Moon (NAIF 301, sphere R=1737400 m)" in message
    assert "\n" not in message


def test_check_bodies_warns_about_two_reference_surfaces_of_one_body():
    warnings = check_bodies([("sphere.tif", "IAU_2015:49900"),
                             ("ellipsoid.tif", "IAU_2015:49902")])
    assert len(warnings) == 1
    assert "ellipsoid a=3396190 m, c=3376200 m" in warnings[0]
    assert "different reference surfaces" in warnings[0]


def test_body_label_of_an_unknown_body():
    toy = maps.body_from_radii(2000.0, name="Toy")
    assert body_label(toy) == "Toy (sphere R=2000 m)"


def test_resampling_between_bodies_is_a_processing_error():
    transform = Affine(100.0, 0, 0, 0, -100.0, 0)
    src = Grid((10, 10), transform, CRS.from_user_input("IAU_2015:49910"))
    dst = Grid((10, 10), transform, CRS.from_user_input("IAU_2015:30110"))
    with pytest.raises(ProcessingError, match="different bodies"):
        resample_to_grid(np.zeros((10, 10)), src, dst)


def test_reprojection_is_exact_for_a_plane():
    # a plane in one CRS stays a plane under bilinear sampling at the exact positions
    moon = maps.body_by_naif_id(301)
    a = maps.make_projection(moon, "equirectangular", 10.0, 5.0)
    b = maps.make_projection(moon, "equirectangular", 10.2, 4.0)
    grid_b = maps.snap_grid(b, -12000, 1.1e5, 12000, 1.3e5, 40.0)
    x, y = grid_b.cell_centers()
    plane = 0.1 * x - 0.05 * y
    src = Grid(grid_b.shape, grid_b.transform, CRS.from_wkt(b.to_wkt()))
    grid_a = maps.snap_grid(a, -2000, 1.15e5, 2000, 1.25e5, 50.0)
    dst = Grid(grid_a.shape, grid_a.transform, CRS.from_wkt(a.to_wkt()))
    out = resample_to_grid(plane, src, dst)
    xa, ya = grid_a.cell_centers()
    lon, lat = maps.map_to_lonlat(a, xa, ya)
    xb, yb = maps.lonlat_to_map(b, lon, lat)
    np.testing.assert_allclose(out, 0.1 * xb - 0.05 * yb, atol=1e-6)


def test_metric_grid_only_for_degrees():
    projected = Grid((5, 5), Affine(10, 0, 0, 0, -10, 0), CRS.from_user_input("IAU_2015:30110"))
    assert metric_grid(projected) == (projected, None)
    local = Grid((5, 5), Affine(10, 0, 0, 0, -10, 0), None)
    assert metric_grid(local) == (local, None)
    degrees = Grid((90, 180), Affine(0.01, 0, 30, 0, -0.01, 0.45),
                   CRS.from_user_input("IAU_2015:30100"))
    metric, note = metric_grid(degrees)
    assert metric.crs.is_projected and not metric.is_geographic and degrees.is_geographic
    per_degree = 1737400.0 * np.pi / 180
    assert metric.spacing[0] == pytest.approx(0.01 * per_degree, rel=1e-4)  # ≈303 m
    assert note["spacing_deg"] == pytest.approx([0.01, 0.01])
    assert note["spacing_m"] == pytest.approx(list(metric.spacing))
    assert metric.shape[1] == pytest.approx(180, abs=2) and metric.shape[0] == pytest.approx(
        90, abs=2)


@pytest.mark.parametrize("tile_size", [0, 64])
def test_a_reference_of_radii_is_compared_as_heights(tmp_path, tile_size):
    """An ISIS shape model (LOLA ldem_*, MOLA) stores each post's distance from the Moon's
    centre: compare subtracts the radius (in memory and in windows) instead of reporting
    a 1737 km offset."""
    from demtool import io as dio
    from demtool.compare.params import CompareParams
    from demtool.compare.run import run_compare
    from demtool.maps import body_by_name, make_projection

    moon = body_by_name("Moon")
    crs = make_projection(moon, "equirectangular", 10.0, 5.0)
    rows, cols = np.mgrid[0:120, 0:120]
    heights = (40.0 * np.sin(rows / 9.0) * np.cos(cols / 13.0) + 0.5 * cols).astype(np.float32)
    transform = Affine(20.0, 0, -1200.0, 0, -20.0, 1200.0)
    dio.write_raster(tmp_path / "dem.tif", heights, transform=transform, crs=crs)
    dio.write_raster(tmp_path / "ldem.tif", (heights.astype(np.float64) + moon.radius)
                     .astype(np.float32), transform=transform, crs=crs)
    report = run_compare(tmp_path / "dem.tif", tmp_path / "ldem.tif", tmp_path / "out",
                         CompareParams(align="none", plots=False, tile_size=tile_size))
    # float32 radii near 1.7e6 m hold heights to 1/8 m
    assert abs(report["median"]) < 0.1 and report["rmse"] < 0.1
    assert report["completeness"] == pytest.approx(100.0)
