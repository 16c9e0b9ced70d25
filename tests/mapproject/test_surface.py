"""The DEM surface held in memory (DemSurface.holding, issue 47): the footprint's second
pass and the map tiles slice the window read once instead of reading the file again,
with the same heights to the bit; windows outside it are read from the file."""

import numpy as np

from demtool.mapproject.core import ortho_grid
from demtool.mapproject.surface import read_dem_surface
from demtool.maps import grid_lonlat, snap_grid
from tests.helpers.linescan import MOON, linescan_sensor, write_truth_dem


def test_held_window_gives_the_files_heights_to_the_bit(tmp_path, monkeypatch):
    sensor = linescan_sensor(lines=120, samples=90)
    grid = ortho_grid(sensor, MOON, height=0.0)
    grid = snap_grid(grid.crs, *grid.bounds(), 2.0)
    dem_path = write_truth_dem(tmp_path / "dem.tif", grid)
    surface = read_dem_surface(dem_path, "sensor.json", MOON)
    lon, lat = grid_lonlat(grid)
    rows, cols = lon.shape
    centre = (slice(rows // 4, 3 * rows // 4), slice(cols // 4, 3 * cols // 4))
    held = surface.holding(lon[centre], lat[centre], margin=2)
    (r0, r1, c0, c1), values = held.held
    assert values.shape == (r1 - r0, c1 - c0) and 0 < r0 and r1 < rows  # a window only
    # inside the held window: no file read, heights equal to the file's to the bit
    from demtool import io as dio

    reads = []
    original = dio.read_window
    monkeypatch.setattr(dio, "read_window", lambda *a, **k: (reads.append(a[1]),
                                                             original(*a, **k))[1])
    inner = (slice(rows // 3, rows // 2), slice(cols // 3, cols // 2))
    x = grid.transform.c + (np.arange(cols)[inner[1]] + 0.37) * grid.transform.a
    y = grid.transform.f + (np.arange(rows)[inner[0]] + 0.61) * grid.transform.e
    xx, yy = np.meshgrid(x, y)
    found = held.heights_xy(xx, yy)
    assert reads == []
    expected = surface.heights_xy(xx, yy)
    assert len(reads) == 1
    assert np.isfinite(expected).all()
    np.testing.assert_array_equal(found.view(np.uint64), expected.view(np.uint64))
    # the whole grid reaches past the held window: read from the file, the same heights
    np.testing.assert_array_equal(held.heights_lonlat(lon, lat), surface.heights_lonlat(lon, lat))
    assert len(reads) == 3
    # a window over the cap stays on disk
    assert surface.holding(lon, lat, max_cells=10).held is None


def test_held_window_read_in_row_parts_equals_one_read(tmp_path, monkeypatch):
    """holding()'s read, split into row parts on threads, gives one read's values to the
    bit (NaN nodata included), and reads each part once."""
    from demtool import io as dio
    from demtool.mapproject import surface as surface_module
    from demtool.tiling import rows

    sensor = linescan_sensor(lines=120, samples=90)
    grid = ortho_grid(sensor, MOON, height=0.0)
    grid = snap_grid(grid.crs, *grid.bounds(), 2.0)
    lon, lat = grid_lonlat(grid)
    heights = (1000.0 * np.sin(lon * 7.0) + 37.25 * lat).astype(np.float32)
    heights[5:9, 3:40] = np.nan  # a hole: nodata stays NaN
    dem_path = tmp_path / "dem.tif"
    dio.write_raster(dem_path, heights, transform=grid.transform, crs=grid.crs,
                     tags=MOON.tags())
    surface = read_dem_surface(dem_path, "sensor.json", MOON)
    window = (1, grid.height - 2, 2, grid.width - 1)
    whole = dio.read_window(dem_path, window, what="DEM")
    monkeypatch.setattr(surface_module, "HOLD_MIN_ROWS_PER_PART", 4)
    monkeypatch.setattr(rows, "usable_threads", lambda: 3)
    monkeypatch.setattr(rows, "_numba_threads", lambda: 3)
    reads = []
    original = dio.read_window
    monkeypatch.setattr(dio, "read_window", lambda *a, **k: (reads.append(a[1]),
                                                             original(*a, **k))[1])
    parts = surface._read_rows_on_threads(window)
    assert len(reads) == 3 and sorted(r[0] for r in reads)[0] == window[0]
    assert np.isnan(parts).sum() == np.isnan(whole).sum() > 0
    np.testing.assert_array_equal(parts.view(np.uint32), whole.view(np.uint32))


def test_scattered_points_read_their_own_cells_with_the_windows_heights(tmp_path, monkeypatch):
    """A few points spread over a DEM not held in memory (the image's outer edge on a
    DEM over the hold cap) read each point's 4 x 4 cells, not the window spanning them:
    the same heights to the bit, at the DEM's edges, next to a hole and off the DEM."""
    from demtool import io as dio
    from demtool.mapproject import surface as surface_module

    sensor = linescan_sensor(lines=120, samples=90)
    grid = ortho_grid(sensor, MOON, height=0.0)
    grid = snap_grid(grid.crs, *grid.bounds(), 2.0)
    lon, lat = grid_lonlat(grid)
    heights = (1000.0 * np.sin(lon * 7.0) + 37.25 * lat).astype(np.float32)
    heights[20:24, 30:33] = np.nan
    dem_path = tmp_path / "dem.tif"
    dio.write_raster(dem_path, heights, transform=grid.transform, crs=grid.crs,
                     tags=MOON.tags())
    surface = read_dem_surface(dem_path, "sensor.json", MOON)
    rows, cols = heights.shape
    # fractional (row, col) centre positions: inside, on each edge (within and beyond
    # half a cell), beside the hole, far off the DEM, NaN
    positions = np.array([[3.3, 4.7], [rows / 2 + 0.25, cols / 3 + 0.5], [-0.3, 10.2],
                          [-0.7, 10.2], [rows - 0.6, cols - 0.6], [rows - 0.4, 5.5],
                          [12.1, -0.49], [7.5, cols - 0.51], [19.6, 31.2], [24.2, 29.9],
                          [-40.0, 8.0], [rows + 50.0, cols + 3.0], [np.nan, 3.0]])
    x = grid.transform.c + (positions[:, 1] + 0.5) * grid.transform.a
    y = grid.transform.f + (positions[:, 0] + 0.5) * grid.transform.e
    monkeypatch.setattr(surface_module, "SPARSE_MIN_CELLS", 10**12)
    expected = surface.heights_xy(x, y)
    monkeypatch.setattr(surface_module, "SPARSE_MIN_CELLS", 64)
    whole_reads, point_windows = [], []
    original_window, original_windows = dio.read_window, dio.read_windows
    monkeypatch.setattr(dio, "read_window", lambda *a, **k: (whole_reads.append(a[1]),
                                                             original_window(*a, **k))[1])
    monkeypatch.setattr(dio, "read_windows", lambda *a, **k: (point_windows.extend(a[1]),
                                                              original_windows(*a, **k))[1])
    found = surface.heights_xy(x, y)
    assert whole_reads == [] and 0 < len(point_windows) <= len(positions)
    assert all(r1 - r0 <= 4 and c1 - c0 <= 4 for r0, r1, c0, c1 in point_windows)
    assert np.isnan(expected[[3, 5, 8, 10, 11, 12]]).all() and np.isfinite(expected).sum() == 7
    np.testing.assert_array_equal(found.view(np.uint64), expected.view(np.uint64))
    # many points (a tile's lattice) keep the one window read (read_window reads its
    # window through read_windows)
    monkeypatch.setattr(surface_module, "SPARSE_MAX_POINTS", 4)
    point_windows.clear()
    np.testing.assert_array_equal(surface.heights_xy(x, y).view(np.uint64),
                                  expected.view(np.uint64))
    assert len(whole_reads) == 1 and point_windows == whole_reads
