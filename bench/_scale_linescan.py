"""Line-scan views of any size rendered from analytic truth, for bench/scale_out.py's
``mapproject`` and ``dem`` cases.

The camera is tests/helpers/linescan.py's synthetic lunar pushbroom (1 m pixels, 50 km
altitude, polar orbit); the ground is its analytic ``terrain`` (hills scaled to 10 m,
23–53 m wavelengths: slopes up to about 0.3) draped with a seeded random texture
(:class:`GroundTexture`: white noise on a 1 m lattice of local metres, Gaussian-smoothed
at σ = 1.5 m, sampled bicubically; the helper's periodic ``texture`` would give a
matcher ambiguous seeds).
Each view is rendered in blocks of lines (ray–surface intersection by fixed-point
iteration on the radial height), so the orthoimage and the DEM expected on any map
grid are known exactly.  A stereo pair is two views rolled ±12.5° about the flight
direction from tracks on either side of the site (B/H ≈ 0.44), both looking at it.
"""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import numpy as np

ALTITUDE = 50_000.0  # m
RELIEF = 10.0  # m, amplitude of the helper's hills (its 40 m default: slopes up to 1)
ROLL = 12.5  # degrees, each view of the pair
DEM_SPACING = 2.0  # m, the DEM mapproject projects onto


def track_offset_deg(roll_deg: float, lat_deg: float = 5.0) -> float:
    """Longitude offset (degrees) from the site to a track whose view rolled by
    ``roll_deg`` centres on the site: the central angle asin(r/R sin θ) − θ.  (A
    positive roll of tests/helpers/linescan.py's camera looks east, so that track lies
    west of the site: subtract the offset.)"""
    from tests.helpers.linescan import R

    theta = math.radians(roll_deg)
    phi = math.asin((R + ALTITUDE) / R * math.sin(theta)) - theta
    return math.degrees(phi) / math.cos(math.radians(lat_deg))


class GroundTexture:
    """A seeded random ground pattern (σ ≈ 0.1 around 0.5) over a square of local
    metres around the site (lon 10°, lat 5°: x east, y north, as tests/helpers/
    linescan.py's ``terrain``), stored as ``texture.npy`` in a folder."""

    SPACING = 1.0  # m

    def __init__(self, data: np.ndarray, half: float):
        self.data, self.half = data, half

    @classmethod
    def make(cls, folder: Path, half_extent_m: float, seed: int = 0) -> GroundTexture:
        from scipy import ndimage

        n = int(math.ceil(2 * half_extent_m / cls.SPACING)) + 1
        noise = np.random.default_rng(seed).normal(size=(n, n)).astype(np.float32)
        noise = ndimage.gaussian_filter(noise, 1.5 / cls.SPACING, mode="wrap")
        data = (0.5 + 0.1 * noise / noise.std()).astype(np.float32)
        np.save(folder / "texture.npy", data)
        return cls(data, 0.5 * (n - 1) * cls.SPACING)

    @classmethod
    def load(cls, folder: Path) -> GroundTexture:
        data = np.load(folder / "texture.npy")
        return cls(data, 0.5 * (len(data) - 1) * cls.SPACING)

    def __call__(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        from scipy import ndimage

        from tests.helpers.linescan import R

        x = np.radians(np.asarray(lon) - 10.0) * R * math.cos(math.radians(5.0))
        y = np.radians(np.asarray(lat) - 5.0) * R
        rows = (self.half - y) / self.SPACING
        cols = (x + self.half) / self.SPACING
        return ndimage.map_coordinates(self.data, [rows.ravel(), cols.ravel()], order=3,
                                       mode="nearest").reshape(np.shape(rows))


def ground_heights(lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """The analytic terrain, metres above the sphere (:data:`RELIEF`)."""
    from tests.helpers.linescan import terrain

    return terrain(lon, lat, amplitude=RELIEF)


def render_blocks(sensor, path: Path, texture, block: int = 256) -> None:
    """Render ``sensor``'s view of the analytic terrain draped with ``texture`` into
    ``path`` (float32 GeoTIFF in the image frame), ``block`` lines at a time."""
    from demtool import io as dio
    from demtool.maps import xyz_to_lonlat_height
    from demtool.sensors import ray_ellipsoid_intersection
    from tests.helpers.linescan import R

    with dio.raster_writer(path, height=sensor.lines, width=sensor.samples,
                           tags={"frame": f"image:{sensor.name}"}) as writer:
        for l0 in range(0, sensor.lines, block):
            l1 = min(sensor.lines, l0 + block)
            line, sample = np.meshgrid(np.arange(l0, l1) + 0.5,
                                       np.arange(sensor.samples) + 0.5, indexing="ij")
            ray = sensor.image_to_ray(line, sample)
            h = np.zeros(line.shape)
            for _ in range(30):
                xyz = ray_ellipsoid_intersection(ray.origin, ray.direction, R, R, h)
                lon, lat, _ = xyz_to_lonlat_height(xyz, radii=R)
                new = ground_heights(lon, lat)
                done = np.nanmax(np.abs(new - h)) < 1e-4
                h = new
                if done:
                    break
            xyz = ray_ellipsoid_intersection(ray.origin, ray.direction, R, R, h)
            lon, lat, _ = xyz_to_lonlat_height(xyz, radii=R)
            writer.write(texture(lon, lat).astype(np.float32), l0, 0)


def _view(folder: Path, size: int, roll_deg: float, name: str, texture
          ) -> tuple[Path, Path]:
    from tests.helpers.linescan import isd_dict, linescan_sensor

    sensor = linescan_sensor(lines=size, samples=size, gsd=1.0, altitude=ALTITUDE,
                             lon0=10.0 - track_offset_deg(roll_deg), roll_deg=roll_deg,
                             name=name)
    image, isd = folder / f"{name}.tif", folder / f"{name}.json"
    isd.write_text(json.dumps(isd_dict(sensor)))
    render_blocks(sensor, image, texture)
    return image, isd


def write_linescan_scene(folder: Path, size: int, *, views: int = 1) -> dict:
    """One view (rolled 12.5°, ``size`` lines × samples) and the terrain on a 2 m DEM
    over its footprint; returns ``images``, ``isds``, ``dem`` and ``gsd`` (the ortho's,
    1 m)."""
    from demtool.mapproject.core import ortho_grid
    from demtool.maps import snap_grid
    from demtool.sensors import read_sensor
    from tests.helpers.linescan import MOON, write_truth_dem

    folder.mkdir(parents=True, exist_ok=True)
    texture = GroundTexture.make(folder, 0.75 * size + 100.0)
    image, isd = _view(folder, size, ROLL, "view_a", texture)
    grid = ortho_grid(read_sensor(isd), MOON, height=0.0, gsd=DEM_SPACING)
    grid = snap_grid(grid.crs, *grid.bounds(), DEM_SPACING)
    dem = write_truth_dem(folder / "dem_2m.tif", grid, surface=ground_heights)
    return {"images": [image], "isds": [isd], "dem": dem, "gsd": 1.0}


def write_linescan_pair(folder: Path, size: int) -> dict:
    """Two views rolled ±12.5° (``size``² px), map-projected onto the sphere (the right
    on the left's grid), matched by ``sgm --cost census``; returns ``left``, ``right``
    (orthoimages) and ``disparity``."""
    from bench.scale import DEMTOOL

    folder.mkdir(parents=True, exist_ok=True)
    texture = GroundTexture.make(folder, 0.75 * size + 100.0)
    left_image, left_isd = _view(folder, size, ROLL, "view_a", texture)
    right_image, right_isd = _view(folder, size, -ROLL, "view_b", texture)
    left, right = folder / "left_ortho.tif", folder / "right_ortho.tif"
    disparity = folder / "disparity.tif"
    for args in (["mapproject", left_image, "--sensor", left_isd, "--height", 0, "--out",
                  left],
                 ["mapproject", right_image, "--sensor", right_isd, "--height", 0,
                  "--grid-like", left, "--out", right],
                 ["sgm", left, right, "--cost", "census", "--out", disparity]):
        subprocess.run([DEMTOOL, "-q", *map(str, args)], check=True)
    return {"left": left, "right": right, "disparity": disparity}


def _grid_lonlat(raster):
    from demtool.maps import MapGrid, grid_lonlat, to_pyproj_crs

    height, width = raster.data.shape[-2:]
    return grid_lonlat(MapGrid(crs=to_pyproj_crs(raster.crs), transform=raster.transform,
                               width=width, height=height))


def ortho_error(path: Path) -> tuple[float, float]:
    """RMS of an orthoimage against the ground texture at its cells' centres (texture
    units), and the fraction of cells seen."""
    from demtool import io as dio

    texture = GroundTexture.load(Path(path).parent)
    ortho = dio.read_raster(path)
    lon, lat = _grid_lonlat(ortho)
    seen = np.isfinite(ortho.data)
    diff = ortho.data[seen] - texture(lon[seen], lat[seen])
    return float(np.sqrt(np.mean(diff**2))), float(seen.mean())


def dem_error(path: Path, left: Path) -> tuple[float, float]:
    """RMSE of a DEM against the analytic terrain, in the orthoimages' GSD (no
    alignment), and its completeness: finite cells among those whose centres both
    orthoimages see."""
    from demtool import io as dio

    dem = dio.read_raster(path)
    lon, lat = _grid_lonlat(dem)
    ok = np.isfinite(dem.data)
    diff = dem.data[ok] - ground_heights(lon[ok], lat[ok])
    left_ortho = dio.read_raster(left)
    right_ortho = dio.read_raster(Path(left).with_name("right_ortho.tif"))
    both = np.isfinite(left_ortho.data) & np.isfinite(right_ortho.data)
    rows, cols = np.indices(dem.data.shape)
    x, y = dem.transform * (cols + 0.5, rows + 0.5)
    c, r = ~left_ortho.transform * (x, y)
    r, c = np.floor(r).astype(np.int64), np.floor(c).astype(np.int64)
    inside = (r >= 0) & (r < both.shape[0]) & (c >= 0) & (c < both.shape[1])
    expected = np.zeros(dem.data.shape, dtype=bool)
    expected[inside] = both[r[inside], c[inside]]
    gsd = abs(left_ortho.transform.a)
    completeness = float((ok & expected).sum() / max(expected.sum(), 1))
    return float(np.sqrt(np.mean(diff**2))) / gsd, completeness
