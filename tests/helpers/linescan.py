"""A synthetic lunar pushbroom camera, an analytic terrain and texture, and their rendering.

The camera flies a circular polar orbit northward over longitude ``lon0`` at
``altitude`` metres, its detector line across track (samples increase eastward, lines
northward in time), optionally rolled about the flight direction.  Ground truth is
analytic: ``terrain(lon, lat)`` (metres above the sphere) and ``texture(lon, lat)``, so a
rendering (ray-surface intersection per pixel) and the orthoimage expected on any map
grid are known exactly.
"""

from __future__ import annotations

import numpy as np

from demtool.maps import body_by_name, lonlat_height_to_xyz, xyz_to_lonlat_height
from demtool.sensors import Detector, LineScanSensor
from demtool.sensors.base import matrix_to_quaternion

MOON = body_by_name("Moon")
R = MOON.radius
GM_MOON = 4.9048695e12  # m^3/s^2


def linescan_sensor(lines: int = 300, samples: int = 200, *, gsd: float = 1.0,
                    altitude: float = 50_000.0, lon0: float = 10.0, lat0: float = 5.0,
                    roll_deg: float = 0.0, name: str = "synthetic_ls",
                    sun_azimuth_deg: float = 90.0, sun_elevation_deg: float = 30.0
                    ) -> LineScanSensor:
    """A LineScanSensor on the Moon whose image centre sees (lon0, lat0) (for zero roll).

    ``gsd`` is the nadir ground sample distance on the sphere (metres); ``roll_deg``
    turns the camera about the flight direction (positive: looks west).
    """
    radius = R + altitude
    omega = np.sqrt(GM_MOON / radius**3)  # rad/s
    # angular rate on the ground: one line per gsd
    dt_line = gsd / (omega * R)
    duration = lines * dt_line
    t_nodes = np.linspace(-0.6 * duration - 1.0, 0.6 * duration + 1.0, 41)
    lat_nodes = lat0 + np.degrees(omega * t_nodes)
    up = lonlat_height_to_xyz(np.full_like(lat_nodes, lon0), lat_nodes, 0.0, radii=1.0)
    positions = up * radius
    lam = np.radians(lon0)
    east = np.array([-np.sin(lam), np.cos(lam), 0.0])
    rotations = []
    roll = np.radians(roll_deg)
    for u in up:
        north = np.cross(u, east)
        west = -east
        # camera axes in body frame: x (detector +) = east-ish, z = up, y = z × x
        x_axis = np.cos(roll) * (-west) + np.sin(roll) * u
        z_axis = -np.sin(roll) * (-west) + np.cos(roll) * u
        y_axis = np.cross(z_axis, x_axis)
        rotations.append(np.column_stack([x_axis, y_axis, z_axis]))
        del north
    quaternions = matrix_to_quaternion(np.array(rotations))
    pitch = 0.007  # mm
    focal = altitude * pitch / gsd  # mm
    # look = R (−u, 0, −f): a sample with focal x = +p looks toward −x (west); flip the
    # sample axis so that samples increase eastward
    detector = Detector(itrans_sample=np.array([0.0, -1.0 / pitch, 0.0]),
                        itrans_line=np.array([0.0, 0.0, 1.0 / pitch]),
                        center_sample=0.5 * samples, center_line=0.0)
    az, el = np.radians(sun_azimuth_deg), np.radians(sun_elevation_deg)
    centre_up = lonlat_height_to_xyz(lon0, lat0, 0.0, radii=1.0)
    centre_north = np.cross(centre_up, east)
    sun_dir = (np.cos(el) * (np.sin(az) * east + np.cos(az) * centre_north)
               + np.sin(el) * centre_up)
    sun = sun_dir * 1.5e11
    return LineScanSensor(line_scan_rate=[[0.5, -0.5 * duration, dt_line]],
                          positions=positions, t0_ephem=t_nodes[0],
                          dt_ephem=t_nodes[1] - t_nodes[0], quaternions=quaternions,
                          t0_quat=t_nodes[0], dt_quat=t_nodes[1] - t_nodes[0],
                          focal_length=focal, detector=detector, lines=lines,
                          samples=samples, radii=(R, R), sun_positions=sun[None],
                          name=name)


def terrain(lon, lat, *, lon0: float = 10.0, lat0: float = 5.0, amplitude: float = 40.0):
    """Smooth hills, metres above the sphere."""
    x = np.radians(np.asarray(lon) - lon0) * R * np.cos(np.radians(lat0))
    y = np.radians(np.asarray(lat) - lat0) * R
    return amplitude * (np.sin(x / 37.0) * np.cos(y / 53.0) + 0.5 * np.sin((x + y) / 23.0))


def texture(lon, lat, *, lon0: float = 10.0, lat0: float = 5.0):
    """A band-limited ground pattern (wavelengths 9-25 m), values in about [0, 1]."""
    x = np.radians(np.asarray(lon) - lon0) * R * np.cos(np.radians(lat0))
    y = np.radians(np.asarray(lat) - lat0) * R
    return (0.5 + 0.2 * np.sin(2 * np.pi * x / 11.0 + 0.3) * np.cos(2 * np.pi * y / 13.0)
            + 0.15 * np.sin(2 * np.pi * (0.6 * x - 0.8 * y) / 9.0)
            + 0.1 * np.cos(2 * np.pi * (x + 0.5 * y) / 25.0))


def render(sensor: LineScanSensor, surface=terrain, pattern=texture, iterations: int = 30
           ) -> np.ndarray:
    """The image the sensor sees of ``pattern`` draped on ``surface`` (ray marching on
    the radial height by fixed-point iteration; float32 (lines, samples))."""
    from demtool.sensors import ray_ellipsoid_intersection

    line, sample = np.meshgrid(np.arange(sensor.lines) + 0.5, np.arange(sensor.samples) + 0.5,
                               indexing="ij")
    ray = sensor.image_to_ray(line, sample)
    h = np.zeros(line.shape)
    for _ in range(iterations):
        xyz = ray_ellipsoid_intersection(ray.origin, ray.direction, R, R, h)
        lon, lat, _ = xyz_to_lonlat_height(xyz, radii=R)
        h = surface(lon, lat)
    xyz = ray_ellipsoid_intersection(ray.origin, ray.direction, R, R, h)
    lon, lat, _ = xyz_to_lonlat_height(xyz, radii=R)
    return pattern(lon, lat).astype(np.float32)


def isd_dict(sensor: LineScanSensor, center_time: float = 1000.0) -> dict:
    """An ALE-style ISD of a synthetic :func:`linescan_sensor` (body frame = J2000,
    metres), enough for :func:`demtool.sensors.sensor_from_isd` to rebuild it."""
    from demtool.sensors.base import quaternion_to_matrix

    n = len(sensor.positions)
    times = center_time + sensor.t0_ephem + sensor.dt_ephem * np.arange(n)
    qt = center_time + sensor.t0_quat + sensor.dt_quat * np.arange(len(sensor.quaternions))
    pointing = matrix_to_quaternion(np.swapaxes(quaternion_to_matrix(sensor.quaternions),
                                                -1, -2))
    det = sensor.detector
    identity = [[1.0, 0.0, 0.0, 0.0]] * len(qt)
    rate = np.column_stack([sensor.int_lines, sensor.int_start_times, sensor.int_times])
    return {
        "name_model": "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL",
        "image_identifier": sensor.name,
        "image_lines": sensor.lines, "image_samples": sensor.samples,
        "center_ephemeris_time": center_time,
        "starting_ephemeris_time": center_time + float(rate[0, 1]),
        "line_scan_rate": rate.tolist(),
        "radii": {"semimajor": sensor.radii[0], "semiminor": sensor.radii[1], "unit": "m"},
        "focal_length_model": {"focal_length": sensor.focal_length},
        "detector_center": {"line": det.center_line, "sample": det.center_sample},
        "focal2pixel_samples": list(det.itrans_sample),
        "focal2pixel_lines": list(det.itrans_line),
        "optical_distortion": {"radial": {"coefficients": [0.0, 0.0, 0.0]}},
        "body_rotation": {"ephemeris_times": qt.tolist(), "quaternions": identity},
        "instrument_pointing": {"ephemeris_times": qt.tolist(),
                                "quaternions": pointing[:, [3, 0, 1, 2]].tolist()},
        "instrument_position": {"ephemeris_times": times.tolist(),
                                "positions": sensor.positions.tolist(), "unit": "m"},
        "sun_position": {"ephemeris_times": [center_time],
                         "positions": sensor.sun_positions.tolist(), "unit": "m"},
    }


def write_scene(folder, sensor: LineScanSensor, *, surface=terrain, pattern=texture):
    """Write ``<name>.tif`` (the rendering) and ``<name>.json`` (its ISD) into ``folder``;
    return their paths."""
    import json
    from pathlib import Path

    from demtool import io as dio

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    image = folder / f"{sensor.name}.tif"
    isd = folder / f"{sensor.name}.json"
    dio.write_raster(image, render(sensor, surface, pattern))
    isd.write_text(json.dumps(isd_dict(sensor)))
    return image, isd


def write_truth_dem(path, grid, surface=terrain):
    """The analytic terrain on a map grid (demtool's map raster contract)."""
    from demtool import io as dio
    from demtool.maps import grid_lonlat

    lon, lat = grid_lonlat(grid)
    dio.write_raster(path, surface(lon, lat), transform=grid.transform, crs=grid.crs,
                     tags=MOON.tags())
    return path


def synth_ortho_pair(work, size: int):
    """``synth --sensor linescan`` in ``work/scene`` and both views map-projected onto the
    sphere (the right on the left's grid), as `make demo`'s line-scan route does.

    Returns ``(scene, meta, left_ortho, right_ortho)``: the scene folder, its
    ``scene.json`` (``meta["target"]`` is the left view) and the two orthoimage paths.
    """
    import json
    from pathlib import Path

    from click.testing import CliRunner

    from demtool.cli import cli

    def invoke(*args):
        result = CliRunner().invoke(cli, [*map(str, args)])
        assert result.exit_code == 0, result.output

    work = Path(work)
    scene = work / "scene"
    invoke("synth", "--sensor", "linescan", "--size", size, "--image-size", size,
           "--out", scene)
    meta = json.loads((scene / "scene.json").read_text())
    names = (meta["target"], meta["partner"])
    left, right = work / "left_ortho.tif", work / "right_ortho.tif"
    invoke("mapproject", scene / f"{names[0]}.tif", "--sensor", scene / f"{names[0]}.json",
           "--height", 0, "--out", left)
    invoke("mapproject", scene / f"{names[1]}.tif", "--sensor", scene / f"{names[1]}.json",
           "--height", 0, "--grid-like", left, "--out", right)
    return scene, meta, left, right


def on_truth(path, truth):
    """The DEM at ``path`` resampled onto the map grid of ``truth`` (a demtool.io Raster),
    without alignment: (H, W) float64, NaN where the DEM has no value."""
    from demtool import io as dio
    from demtool.compare.grids import Grid, resample_to_grid

    dem = dio.read_raster(path)
    return resample_to_grid(dem.data.astype(np.float64),
                            Grid(dem.data.shape, dem.transform, dem.crs),
                            Grid(truth.data.shape, truth.transform, truth.crs))


def copy_raster(src, dst, *, data=None, tags=None, transform=None):
    """Write ``src`` again at ``dst`` with its data, tags or transform replaced (a way to
    make a bad input from a good one); returns ``dst``."""
    from demtool import io as dio

    raster = dio.read_raster(src)
    dio.write_raster(dst, raster.data if data is None else data,
                     transform=transform or raster.transform, crs=raster.crs,
                     tags=raster.tags if tags is None else tags)
    return dst


def ortho_ray_case(lines: int, samples: int):
    """A ±8° line-scan pair over :func:`terrain` on a 1 m map grid, as ``dem --mapprojected``
    sees it: ``(left, right, grid, orthos, heights, rows, cols, r_cols)``, with ``orthos``
    the two orthoimage stand-ins ``dem.ortho_rays.ortho_rays`` reads (transform, sensor,
    heights), every grid cell's row and column, and right columns offset by a random
    disparity of -2..6 px (float64, cells)."""
    from types import SimpleNamespace

    from demtool.maps import map_to_lonlat
    from demtool.maps.grids import grid_from_xyz

    left = linescan_sensor(lines=lines, samples=samples, roll_deg=-8.0, lon0=10.2324)
    right = linescan_sensor(lines=lines, samples=samples, roll_deg=8.0, lon0=9.7676)
    corners_line = np.array([0.5, lines - 0.5, 0.5, lines - 0.5])
    corners_sample = np.array([0.5, 0.5, samples - 0.5, samples - 0.5])
    grid = grid_from_xyz(MOON, left.image_to_ground(corners_line, corners_sample), 1.0)

    def heights(x, y):
        return terrain(*map_to_lonlat(grid.crs, x, y))

    orthos = [SimpleNamespace(info=SimpleNamespace(transform=grid.transform), sensor=s,
                              heights=heights) for s in (left, right)]
    rows, cols = np.nonzero(np.ones(grid.shape, bool))
    rows, cols = rows.astype(np.float64), cols.astype(np.float64)
    r_cols = cols - np.random.default_rng(1).uniform(-2.0, 6.0, cols.size)
    return left, right, grid, orthos, heights, rows, cols, r_cols
