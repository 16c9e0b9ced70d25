"""A small frame-camera stereo scene on the Moon's sphere, with exact truth.

Terrain: heights (metres above the 1 737 400 m sphere) given as a smooth function of the
east/north coordinates of the point's direction in the tangent plane at (lon0, lat0):
two Gaussian hills, a crater bowl and a gentle tilt.  Albedo: band-limited noise on a
1 m lattice over the same plane (bilinear).  Images are rendered through
:class:`demtool.sensors.frame.FrameSensor` models with radial lens distortion by
intersecting every pixel's ray with the terrain (fixed-point iteration on the radius).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter, map_coordinates

from demtool.maps.frames import enu_frame, lonlat_height_to_xyz, xyz_to_lonlat_height
from demtool.sensors.base import Detector
from demtool.sensors.distortion import Distortion
from demtool.sensors.frame import FrameSensor

MOON_RADIUS = 1737400.0
PIXEL_MM = 0.01


@dataclass
class FrameScene:
    """The scene's truth: ``height(xyz)`` (metres above the sphere of points' directions),
    the cameras and images."""

    lon0: float
    lat0: float
    albedo: np.ndarray
    extent_m: float
    left: FrameSensor
    right: FrameSensor
    left_image: np.ndarray
    right_image: np.ndarray
    gsd_m: float

    def _en(self, xyz):
        xyz = np.asarray(xyz, dtype=np.float64)
        unit = xyz / np.linalg.norm(xyz, axis=-1, keepdims=True)
        frame = enu_frame(self.lon0, self.lat0)
        center = lonlat_height_to_xyz(self.lon0, self.lat0, 0.0, radii=MOON_RADIUS)
        rel = unit * MOON_RADIUS - center
        return rel @ frame[0], rel @ frame[1]

    def height_en(self, e, n):
        """Terrain height (m above the sphere) at tangent-plane east/north (m)."""
        h = 25.0 * np.exp(-((e - 150) ** 2 + (n + 100) ** 2) / (2 * 160.0 ** 2))
        h += 15.0 * np.exp(-((e + 200) ** 2 + (n - 180) ** 2) / (2 * 110.0 ** 2))
        r = np.hypot(e + 120, n + 150)
        h -= 12.0 * np.exp(-(r / 90.0) ** 4)
        return h + 0.01 * e - 0.005 * n

    def height(self, xyz):
        """Terrain height of body-fixed points' directions, metres."""
        return self.height_en(*self._en(xyz))

    def albedo_at(self, e, n):
        half = 0.5 * self.extent_m
        cols = (np.asarray(e) + half)
        rows = (half - np.asarray(n))
        return map_coordinates(self.albedo, [rows.ravel(), cols.ravel()], order=1,
                               mode="reflect").reshape(np.shape(e))

    def render(self, model: FrameSensor, rng=None, noise: float = 0.002) -> np.ndarray:
        """Image of the terrain through ``model`` (float32, 0 … 1)."""
        rows, cols = np.mgrid[0:model.lines, 0:model.samples].astype(np.float64)
        ray = model.image_to_ray(rows + 0.5, cols + 0.5)
        h = np.zeros(rows.shape)
        for _ in range(40):
            xyz = _sphere_hit(ray.origin, ray.direction, MOON_RADIUS + h)
            h = self.height(xyz)
        xyz = _sphere_hit(ray.origin, ray.direction, MOON_RADIUS + h)
        e, n = self._en(xyz)
        image = self.albedo_at(e, n)
        if rng is not None:
            image = image + rng.normal(0.0, noise, image.shape)
        return image.astype(np.float32)


def _sphere_hit(origin, direction, radius):
    b = np.einsum("...i,...i->...", origin, direction)
    c = np.einsum("...i,...i->...", origin, origin) - radius ** 2
    s = -b - np.sqrt(np.maximum(b * b - c, 0.0))
    return origin + s[..., None] * direction


def frame_camera(position, target, *, size: int, focal_mm: float, k1: float = 0.0,
                 name: str = "") -> FrameSensor:
    """A CSM frame camera at ``position`` looking at ``target`` (body-fixed metres), x axis
    towards east of the view, radial distortion ``k1`` (per mm²)."""
    position = np.asarray(position, float)
    z = np.asarray(target, float) - position
    z /= np.linalg.norm(z)
    up = position / np.linalg.norm(position)
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    x = east - (east @ z) * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    rotation = np.stack([x, y, z], axis=1)
    detector = Detector(np.array([0.0, 1 / PIXEL_MM, 0.0]), np.array([0.0, 0.0, 1 / PIXEL_MM]),
                        size / 2.0, size / 2.0)
    return FrameSensor(position=position, rotation=rotation, focal_length=focal_mm,
                       detector=detector, distortion=Distortion("radial", [0.0, k1, 0.0]),
                       lines=size, samples=size, radii=(MOON_RADIUS, MOON_RADIUS),
                       sun=(1.5e11, 0.0, 0.0), name=name)


def make_frame_scene(*, size: int = 192, altitude_m: float = 20000.0, gsd_m: float = 5.0,
                     base_to_height: float = 0.3, lon0: float = 10.0, lat0: float = 5.0,
                     k1: float = 0.01, seed: int = 0) -> FrameScene:
    """A seeded stereo pair: left and right cameras ``base_to_height × altitude`` apart
    east–west, both aimed at (lon0, lat0)."""
    rng = np.random.default_rng(seed)
    extent = int(size * gsd_m * 2.2)
    noise = rng.normal(size=(extent, extent))
    albedo = 0.5 + 0.6 * (gaussian_filter(noise, 2.0) * 4 + gaussian_filter(noise, 6.0) * 6)
    albedo = np.clip(albedo, 0.02, 1.5)
    center = lonlat_height_to_xyz(lon0, lat0, 0.0, radii=MOON_RADIUS)
    frame = enu_frame(lon0, lat0)
    focal_mm = altitude_m / gsd_m * PIXEL_MM
    half_base = 0.5 * base_to_height * altitude_m
    cams = []
    for sign, name in ((-1, "left"), (1, "right")):
        position = center + frame[2] * altitude_m + sign * half_base * frame[0]
        cams.append(frame_camera(position, center, size=size, focal_mm=focal_mm, k1=k1,
                                 name=name))
    scene = FrameScene(lon0, lat0, albedo, float(extent), cams[0], cams[1],
                       np.zeros(0), np.zeros(0), gsd_m)
    scene.left_image = scene.render(cams[0], rng)
    scene.right_image = scene.render(cams[1], rng)
    return scene


def height_on_grid(scene: FrameScene, grid) -> np.ndarray:
    """Truth heights at the cell centres of a map grid (metres above the sphere)."""
    from demtool.maps.grids import grid_xyz

    xyz = grid_xyz(grid, 0.0)
    return scene.height(xyz)


__all__ = ["FrameScene", "frame_camera", "height_on_grid", "make_frame_scene",
           "xyz_to_lonlat_height"]


def frame_isd(model: FrameSensor) -> dict:
    """A minimal ALE frame ISD (``USGS_ASTRO_FRAME_SENSOR_MODEL``) of a FrameSensor with
    identity body rotation, so that ``read_sensor`` gives the same model back."""
    from demtool.sensors.base import matrix_to_quaternion

    d = model.detector
    quat = matrix_to_quaternion(model.rotation.T)[[3, 0, 1, 2]]  # ALE: scalar first
    dist = model.distortion
    state = {"unit": "m", "velocities": [[0.0, 0.0, 0.0]], "ephemeris_times": [0.0],
             "reference_frame": 1}
    return {
        "name_model": "USGS_ASTRO_FRAME_SENSOR_MODEL", "image_identifier": model.name,
        "center_ephemeris_time": 0.0,
        "focal2pixel_lines": list(map(float, d.itrans_line)),
        "focal2pixel_samples": list(map(float, d.itrans_sample)),
        "focal_length_model": {"focal_length": model.focal_length},
        "image_lines": model.lines, "image_samples": model.samples,
        "detector_center": {"line": d.center_line, "sample": d.center_sample},
        "optical_distortion": {dist.model: {"coefficients": list(map(float,
                                                                     dist.coefficients))}},
        "radii": {"semimajor": model.radii[0], "semiminor": model.radii[1], "unit": "m"},
        "instrument_position": {**state, "positions": [list(map(float, model.position))]},
        "sun_position": {**state, "positions": [list(map(float, model.sun))]},
        "instrument_pointing": {"quaternions": [list(map(float, quat))],
                                "angular_velocities": [[0.0, 0.0, 0.0]],
                                "ephemeris_times": [0.0], "reference_frame": 1},
        "body_rotation": {"quaternions": [[1.0, 0.0, 0.0, 0.0]],
                          "angular_velocities": [[0.0, 0.0, 0.0]], "ephemeris_times": [0.0],
                          "reference_frame": 1},
        "starting_detector_line": 0, "starting_detector_sample": 0,
    }


def write_frame_scene(scene: FrameScene, folder) -> dict:
    """Write left.tif, right.tif, left.json, right.json (ISDs) into ``folder``; returns the
    paths by name."""
    import json
    from pathlib import Path

    from demtool import io as dio

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {}
    for name, model, image in (("left", scene.left, scene.left_image),
                               ("right", scene.right, scene.right_image)):
        dio.write_raster(folder / f"{name}.tif", image)
        (folder / f"{name}.json").write_text(json.dumps(frame_isd(model)))
        paths[name] = folder / f"{name}.tif"
        paths[f"{name}_isd"] = folder / f"{name}.json"
    return paths
