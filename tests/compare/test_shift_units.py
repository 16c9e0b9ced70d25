"""compare's shift in metres east/north/up and in each input DEM's own pixels."""

import numpy as np
import pytest
import rasterio
from affine import Affine
from rasterio.crs import CRS
from scipy import ndimage

from demtool import io as dio
from demtool.compare.grids import Grid
from demtool.compare.params import CompareParams
from demtool.compare.report import format_table
from demtool.compare.run import run_compare
from demtool.compare.shift_units import shift_in_units
from tests.helpers.compare import fractal

SHIFT = {"dx_px": 2.0, "dy_px": -3.0, "dz": 1.5}
SIGMA = {"dx_px": 0.1, "dy_px": 0.2, "dz": 0.05}


def test_projected_grid_near_its_centre_gives_pixels_times_spacing():
    # equirectangular Moon map centred on (0, 0): true scale at the grid's centre
    grid = Grid((100, 100), Affine(10.0, 0, -500.0, 0, -10.0, 500.0),
                CRS.from_user_input("IAU_2015:30110"))
    out = shift_in_units(SHIFT, SIGMA, grid, [("dem", grid)])
    metres = out["shift_m"]
    assert metres["east"] == pytest.approx(20.0, abs=1e-3)
    assert metres["north"] == pytest.approx(30.0, abs=1e-3)  # 3 px up = north
    assert metres["up"] == 1.5 and metres["axes"].startswith("east, north")
    sigma = out["shift_uncertainty_m"]
    assert sigma["east"] == pytest.approx(1.0, rel=1e-4)
    assert sigma["north"] == pytest.approx(2.0, rel=1e-4)
    own = out["shift_input_px"]["dem"]
    assert (own["dx_px"], own["dy_px"]) == pytest.approx((2.0, -3.0), abs=1e-9)
    assert own["pixel_units"] == "metres"


def test_a_coarser_input_sees_fewer_of_its_own_pixels_and_a_rotated_grid_rotates():
    moon = CRS.from_user_input("IAU_2015:30110")
    grid = Grid((100, 100), Affine(10.0, 0, -500.0, 0, -10.0, 500.0), moon)
    coarse = Grid((25, 25), Affine(40.0, 0, -500.0, 0, -40.0, 500.0), moon)
    own = shift_in_units(SHIFT, SIGMA, grid, [("reference", coarse)])["shift_input_px"]
    assert (own["reference"]["dx_px"], own["reference"]["dy_px"]) == \
        pytest.approx((0.5, -0.75), abs=1e-9)
    assert own["reference"]["sigma_dx_px"] == pytest.approx(0.025)
    # a grid whose columns run north: a shift along x is a shift north
    rotated = Grid((100, 100), Affine(0, -10.0, 500.0, 10.0, 0, -500.0), moon)
    metres = shift_in_units({"dx_px": 1.0, "dy_px": 0.0, "dz": 0.0}, SIGMA, rotated,
                            [])["shift_m"]
    assert (metres["east"], metres["north"]) == pytest.approx((0.0, 10.0), abs=1e-3)


def test_without_crs_the_metres_are_along_the_map_axes():
    grid = Grid((50, 50), Affine(2.0, 0, 0, 0, -2.0, 0), None)
    out = shift_in_units(SHIFT, {"dx_px": np.inf, "dy_px": 0.1, "dz": 0.1}, grid,
                         [("dem", grid)])
    assert out["shift_m"] == {"x": 4.0, "y": 6.0, "up": 1.5, "axes": out["shift_m"]["axes"]}
    assert "not east and north" in out["shift_m"]["axes"]
    assert out["shift_uncertainty_m"]["x"] == np.inf  # unconstrained stays unconstrained
    assert out["shift_input_px"]["dem"]["dx_px"] == pytest.approx(2.0)


def _radii_of_curvature(lat_deg: float) -> tuple[float, float]:
    """WGS84 meridional (M) and prime-vertical (N) radii of curvature, metres."""
    a, f = 6378137.0, 1 / 298.257223563
    e2 = f * (2 - f)
    s2 = np.sin(np.radians(lat_deg)) ** 2
    n = a / np.sqrt(1 - e2 * s2)
    return n * (1 - e2) / (1 - e2 * s2), n


@pytest.mark.slow
def test_demcompare_like_srtm_pair_reports_its_own_pixels_and_metres(tmp_path):
    # CNES demcompare's test pair: an SRTM DEM on a 3" grid, blurred and shifted by
    # (3, 5) of its own pixels; demcompare's reference answer dx = 3, dy = 5 px.
    # demtool compares a degree grid on a metric grid of other pixels (81 m here).
    step = 1.0 / 1200.0  # 3 arc-seconds
    lat0, lon0, size = 44.5, 5.0, 200
    field = fractal(size + 8, relief=900.0, seed=3) + 400.0
    transform = Affine(step, 0, lon0, 0, -step, lat0 + size * step / 2)
    crs = CRS.from_epsg(4326)
    reference = field[:size, :size]
    # dem[r, c] = reference[r + 5, c + 3], blurred: +3 px right and +5 px down aligns it
    dem = ndimage.gaussian_filter(field[5:size + 5, 3:size + 3], 1.0)
    for name, values in (("ref.tif", reference), ("dem.tif", dem)):
        dio.write_raster(tmp_path / name, values, transform=transform, crs=crs)
    report = run_compare(tmp_path / "dem.tif", tmp_path / "ref.tif", tmp_path / "out",
                         CompareParams(plots=False))
    own = report["shift_input_px"]["dem"]
    assert own["dx_px"] == pytest.approx(3.0, abs=0.1)
    assert own["dy_px"] == pytest.approx(5.0, abs=0.1)
    assert own["pixel_units"] == "degrees"
    assert report["shift_input_px"]["reference"]["dx_px"] == pytest.approx(own["dx_px"])
    # the comparison grid's pixels are not the DEM's (what the user saw)
    assert abs(report["shift"]["dx_px"] - own["dx_px"]) > 0.2
    m_radius, n_radius = _radii_of_curvature(lat0)
    east = own["dx_px"] * np.radians(step) * n_radius * np.cos(np.radians(lat0))
    north = -own["dy_px"] * np.radians(step) * m_radius
    assert report["shift_m"]["east"] == pytest.approx(east, rel=0.01)  # ≈ 198 m
    assert report["shift_m"]["north"] == pytest.approx(north, rel=0.01)  # ≈ -463 m
    assert report["shift_m"]["up"] == report["shift"]["dz"]
    written = dio.read_json(tmp_path / "out" / "report.json")
    assert written["shift_m"] == pytest.approx(report["shift_m"])
    assert written["provenance"]["summary"]["shift_input_px"]["dem"]["dx_px"] == \
        pytest.approx(own["dx_px"])
    table = format_table([("dem", report)])
    assert "dE m" in table and f"{own['dx_px']:7.3f}" in table
    with rasterio.open(tmp_path / "out" / "difference.tif") as src:
        assert src.crs is not None
