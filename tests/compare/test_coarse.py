"""demtool.compare.coarse: a DEM judged at a much coarser reference's resolution."""

import numpy as np
import pytest
from affine import Affine

from demtool import io as dio
from demtool.compare import compare_dems
from demtool.compare.coarse import (
    block_average,
    block_mean,
    compare_at_reference_resolution,
)
from demtool.compare.grids import Grid, resample_to_grid
from tests.helpers.compare import fractal

X0, Y0 = 500_000.0, 4_000_000.0
FINE, FACTOR = 10.0, 20  # a 10 m DEM against a 200 m reference


@pytest.fixture(scope="module")
def dem_and_reference():
    """A fine DEM with 300 m of relief and the reference that is its own 20 x 20 cell
    mean (what a gridded altimetry product holds): truth known, no error at all."""
    fine = fractal(240, relief=300.0, seed=5) + 0.002 * np.arange(240)[None, :] * FINE
    coarse = fine.reshape(12, FACTOR, 12, FACTOR).mean(axis=(1, 3))
    fine_grid = Grid(fine.shape, Affine(FINE, 0, X0, 0, -FINE, Y0))
    coarse_grid = Grid(coarse.shape, Affine(FINE * FACTOR, 0, X0, 0, -FINE * FACTOR, Y0))
    return fine, fine_grid, coarse, coarse_grid


def test_block_average_of_a_dem_is_its_coarse_mean(dem_and_reference):
    fine, fine_grid, coarse, coarse_grid = dem_and_reference
    block = block_average(fine, fine_grid, coarse_grid, rows_per_block=7)
    np.testing.assert_allclose(block.mean, coarse, atol=1e-9)
    np.testing.assert_allclose(block.filled, 1.0, atol=1e-9)
    rows, cols = np.indices(coarse.shape, dtype=float)
    np.testing.assert_allclose(block.row, rows, atol=1e-9)  # full cells: their centres
    np.testing.assert_allclose(block.col, cols, atol=1e-9)


def test_a_dem_equal_to_its_reference_at_the_reference_posts_differs_only_at_fine_cells(
        dem_and_reference):
    """Judged at the reference's posts the DEM is perfect; sampled at its fine cells (the
    reference interpolated) or at the posts (the DEM point-sampled), the relief the
    reference cannot show is charged to the DEM."""
    fine, fine_grid, coarse, coarse_grid = dem_and_reference
    at_posts = compare_at_reference_resolution(fine, fine_grid, coarse, coarse_grid,
                                               align="none")
    assert at_posts["posts"] == at_posts["count"] == 144
    assert at_posts["dem_cells_per_post"] == pytest.approx(400.0)
    assert abs(at_posts["median"]) < 1e-9 and at_posts["nmad"] < 1e-9
    assert at_posts["rmse"] < 1e-9
    assert "averaged over each reference cell" in at_posts["what"]
    on_fine = compare_dems(fine, resample_to_grid(coarse, coarse_grid, fine_grid),
                           spacing=FINE, align="none").report
    sampled = compare_dems(resample_to_grid(fine, fine_grid, coarse_grid), coarse,
                           spacing=FINE * FACTOR, align="none").report
    assert on_fine["nmad"] > 3.0 and on_fine["rmse"] > 5.0
    assert sampled["rmse"] > 3.0


def test_a_cell_mostly_without_data_has_no_mean():
    values = np.arange(100.0).reshape(10, 10)
    rows, cols = np.indices((10, 10), dtype=float)
    # 5 x 5 fine cells per coarse cell: the coarse centre of cell [r, c] at fine (5r+2, 5c+2)
    values[:4, :5] = np.nan  # 20 of cell [0, 0]'s 25 values missing
    values[5:7, 5:10] = np.nan  # 10 of cell [1, 1]'s 25 missing
    mean, filled, centre_r, centre_c = block_mean(values, (rows - 2.0) / 5.0,
                                                  (cols - 2.0) / 5.0, (2, 2), 25.0)
    assert np.isnan(mean[0, 0]) and filled[0, 0] == pytest.approx(0.2)
    assert mean[1, 1] == pytest.approx(np.nanmean(values[5:, 5:]))
    assert filled[1, 1] == pytest.approx(0.6)
    assert mean[0, 1] == pytest.approx(values[:5, 5:].mean())
    # the measured part's centroid: cell [1, 1] lost its top two fine rows
    assert centre_r[1, 1] == pytest.approx((np.mean(rows[7:, 5:]) - 2.0) / 5.0)
    assert centre_c[1, 1] == pytest.approx(1.0) and np.isnan(centre_r[0, 0])


def test_a_cell_the_dem_covers_in_part_is_compared_at_the_parts_centroid(
        dem_and_reference):
    """A planar DEM covering 60 % of the cells on its edge: its mean there is the plane
    at the covered part's centroid, not at the post, and that is where the reference is
    read."""
    _, fine_grid, _, coarse_grid = dem_and_reference
    rows, cols = np.indices(fine_grid.shape, dtype=float)
    plane = 3.0 * cols - 1.0 * rows  # metres per 10 m cell: 300 m across a post
    coarse = plane.reshape(12, FACTOR, 12, FACTOR).mean(axis=(1, 3))
    cut = plane.copy()
    cut[:, :8] = np.nan  # the first column of posts 60 % measured, on its east side
    report = compare_at_reference_resolution(cut, fine_grid, coarse, coarse_grid,
                                             align="none")
    assert report["posts"] == 144 and report["rmse"] < 1e-6
    block = block_average(cut, fine_grid, coarse_grid)
    assert block.filled[:, 0] == pytest.approx(0.6)
    assert block.mean[:, 0] - coarse[:, 0] == pytest.approx(np.full(12, 3.0 * 4.0))


def test_a_reference_at_the_dems_resolution_gets_no_second_comparison(dem_and_reference):
    fine, fine_grid, _, _ = dem_and_reference
    half = Grid((120, 120), Affine(1.5 * FINE, 0, X0, 0, -1.5 * FINE, Y0))
    assert compare_at_reference_resolution(fine, fine_grid, fine[:120, :120], half) is None


def test_block_average_across_crs_counts_the_cells_per_post():
    """A DEM on a transverse Mercator 1 km east of the reference's UTM grid: a plane
    averaged over each 100 m cell is the plane at the cell's centre, every cell full."""
    utm = "EPSG:32633"
    shifted = ("+proj=tmerc +lat_0=0 +lon_0=15 +k=0.9996 +x_0=501000 +y_0=0 +datum=WGS84 "
               "+units=m +no_defs")
    from rasterio.crs import CRS

    rows, cols = np.indices((100, 100), dtype=float)
    east = X0 + 1000.0 + 5.0 * (cols + 0.5) - 1000.0  # the tmerc x minus its 1 km
    north = Y0 - 5.0 * (rows + 0.5)
    plane = 0.01 * (east - X0) + 0.02 * (north - Y0)
    fine_grid = Grid(plane.shape, Affine(5.0, 0, X0 + 1000.0, 0, -5.0, Y0),
                     CRS.from_string(shifted))
    coarse_grid = Grid((5, 5), Affine(100.0, 0, X0, 0, -100.0, Y0), CRS.from_string(utm))
    block = block_average(plane, fine_grid, coarse_grid)
    r, c = np.indices((5, 5), dtype=float)
    expected = 0.01 * 100.0 * (c + 0.5) - 0.02 * 100.0 * (r + 0.5)
    np.testing.assert_allclose(block.filled, 1.0, atol=0.01)
    np.testing.assert_allclose(block.mean, expected, atol=0.01)


def test_compare_reports_both_resolutions(dem_and_reference, tmp_path):
    """``compare`` keeps its comparison grid's figures and adds the reference-resolution
    ones beside them, saying which is which."""
    from demtool.compare.params import CompareParams
    from demtool.compare.run import run_compare

    fine, fine_grid, coarse, coarse_grid = dem_and_reference
    crs = "EPSG:32633"
    dio.write_raster(tmp_path / "dem.tif", fine, transform=fine_grid.transform, crs=crs)
    dio.write_raster(tmp_path / "ref.tif", coarse, transform=coarse_grid.transform, crs=crs)
    report = run_compare(tmp_path / "dem.tif", tmp_path / "ref.tif", tmp_path / "out",
                         CompareParams(grid="dem", align="none", plots=False))
    assert report["nmad"] > 3.0  # the fine grid's figures, unchanged
    assert report["at_reference_resolution"]["nmad"] < 1e-6
    assert report["at_reference_resolution"]["posts"] == 144
    assert "grid.on" in report["at_reference_resolution"]["what"]
    assert dio.read_json(tmp_path / "out" / "report.json")["at_reference_resolution"][
        "count"] == 144
    same = run_compare(tmp_path / "dem.tif", tmp_path / "dem.tif", tmp_path / "same",
                       CompareParams(align="none", plots=False))
    assert "at_reference_resolution" not in same


def test_a_reference_in_degrees_is_compared_at_its_posts_in_metres(tmp_path):
    """A LOLA-like reference on the Moon's geographic grid (250 m posts) against a 25 m
    DEM on an equirectangular map, both the same smooth plane: at the reference's posts
    the DEM's cell means equal the reference."""
    import math

    from demtool import maps
    from demtool.compare.params import CompareParams
    from demtool.compare.run import run_compare

    moon = maps.body_by_naif_id(301)
    lon0, lat0, half = 23.5, 26.1, 3000.0

    def plane(lon, lat):
        east = moon.radius * math.cos(math.radians(lat0)) * np.radians(lon - lon0)
        north = moon.radius * np.radians(lat - lat0)
        return 0.05 * east - 0.02 * north + 300.0

    crs = maps.make_projection(moon, "equirectangular", lon0, lat0)
    x0, y0 = maps.lonlat_to_map(crs, lon0, lat0)
    grid = maps.snap_grid(crs, x0 - half, y0 - half, x0 + half, y0 + half, 25.0)
    lon, lat = maps.grid_lonlat(grid)
    dio.write_raster(tmp_path / "dem.tif", plane(lon, lat), transform=grid.transform,
                     crs=grid.crs, tags=moon.tags())
    per_degree = moon.radius * math.pi / 180
    dlat, n = 250.0 / per_degree, 40
    dlon = 250.0 / (per_degree * math.cos(math.radians(lat0)))
    transform = Affine(dlon, 0, lon0 - n / 2 * dlon, 0, -dlat, lat0 + n / 2 * dlat)
    cols, rows = np.meshgrid(np.arange(n) + 0.5, np.arange(n) + 0.5)
    reference = plane(transform.c + cols * dlon, transform.f - rows * dlat)
    dio.write_raster(tmp_path / "ref.tif", reference, transform=transform,
                     crs=moon.geographic_crs(), tags=moon.tags())
    report = run_compare(tmp_path / "dem.tif", tmp_path / "ref.tif", tmp_path / "out",
                         CompareParams(align="none", plots=False))
    coarse = report["at_reference_resolution"]
    assert coarse["post_spacing_m"] == pytest.approx(250.0, rel=0.01)
    assert coarse["dem_cells_per_post"] == pytest.approx(100.0, rel=0.02)
    assert coarse["posts"] >= 400  # the 6 km DEM covers about 24 x 24 posts
    assert abs(coarse["median"]) < 0.1 and coarse["rmse"] < 0.5


def test_the_windowed_compare_says_it_leaves_the_reference_resolution_out(
        dem_and_reference, tmp_path):
    from demtool.compare.params import CompareParams
    from demtool.compare.run import run_compare

    fine, fine_grid, coarse, coarse_grid = dem_and_reference
    dio.write_raster(tmp_path / "dem.tif", fine, transform=fine_grid.transform,
                     crs="EPSG:32633")
    dio.write_raster(tmp_path / "ref.tif", coarse, transform=coarse_grid.transform,
                     crs="EPSG:32633")
    report = run_compare(tmp_path / "dem.tif", tmp_path / "ref.tif", tmp_path / "out",
                         CompareParams(grid="dem", align="offset", plots=False,
                                       tile_size=64))
    assert "--max-memory-mb" in report["at_reference_resolution"]["error"]
    assert any("--max-memory-mb" in w for w in report["warnings"])
