"""usgscsm-style frame ISDs built in tests: a camera over a sphere with known geometry."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from demtool.maps import enu_frame, lonlat_height_to_xyz
from demtool.sensors.base import matrix_to_quaternion

MOON_RADIUS = 1737400.0


def frame_isd(position, rotation, *, focal_mm: float, pitch_mm: float, lines: int,
              samples: int, radius: float = MOON_RADIUS, sun=None, name: str = "cam") -> dict:
    """ALE ISD dict of an undistorted frame camera (body rotation = identity).

    rotation : (3, 3) sensor-to-body (columns: the sensor x, y, z axes; z = look axis).
    Pixel (line, sample) = y / pitch + lines / 2, x / pitch + samples / 2 (mm on the
    focal plane), so the image centre is on the look axis.
    """
    q = matrix_to_quaternion(np.asarray(rotation, dtype=np.float64).T)  # J2000 -> sensor
    q = q[[3, 0, 1, 2]]  # ALE quaternions are scalar-first
    state = {"unit": "m", "positions": [list(map(float, position))],
             "velocities": [[0.0, 0.0, 0.0]], "ephemeris_times": [0.0]}
    sun_state = {"unit": "m", "positions": [list(map(float, sun if sun is not None
                                                     else (0.0, 0.0, 0.0)))],
                 "velocities": [[0.0, 0.0, 0.0]], "ephemeris_times": [0.0]}
    return {
        "name_model": "USGS_ASTRO_FRAME_SENSOR_MODEL", "image_identifier": name,
        "center_ephemeris_time": 0.0, "starting_ephemeris_time": 0.0,
        "focal2pixel_lines": [0.0, 0.0, 1.0 / pitch_mm],
        "focal2pixel_samples": [0.0, 1.0 / pitch_mm, 0.0],
        "focal_length_model": {"focal_length": focal_mm},
        "image_lines": lines, "image_samples": samples,
        "detector_center": {"line": lines / 2.0, "sample": samples / 2.0},
        "optical_distortion": {"radial": {"coefficients": [0.0, 0.0, 0.0]}},
        "radii": {"semimajor": radius, "semiminor": radius, "unit": "m"},
        "instrument_position": state,
        "instrument_pointing": {"quaternions": [list(map(float, q))], "ephemeris_times": [0.0]},
        "body_rotation": {"quaternions": [[1.0, 0.0, 0.0, 0.0]], "ephemeris_times": [0.0]},
        "sun_position": sun_state,
    }


def look_at_rotation(position, target, east) -> np.ndarray:
    """Sensor-to-body rotation looking from ``position`` at ``target``, sensor x along
    the part of ``east`` across the look axis (so image lines run roughly south)."""
    z = np.asarray(target, dtype=np.float64) - np.asarray(position, dtype=np.float64)
    z /= np.linalg.norm(z)
    x = np.asarray(east, dtype=np.float64) - (np.asarray(east) @ z) * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def nadir_isd(lon: float, lat: float, altitude: float, *, sun_elevation: float | None = 30.0,
              sun_azimuth: float = 90.0, radius: float = MOON_RADIUS, **camera) -> dict:
    """A frame camera ``altitude`` metres straight above (lon, lat), the sun at a given
    azimuth (clockwise from north) and elevation seen from the nadir point (1.5e11 m)."""
    east, north, up = enu_frame(lon, lat)
    ground = lonlat_height_to_xyz(lon, lat, 0.0, radii=radius)
    position = ground + altitude * up
    sun = None
    if sun_elevation is not None:
        el, az = np.radians(sun_elevation), np.radians(sun_azimuth)
        direction = np.cos(el) * (np.sin(az) * east + np.cos(az) * north) + np.sin(el) * up
        sun = ground + 1.5e11 * direction
    return frame_isd(position, look_at_rotation(position, ground, east), radius=radius,
                     sun=sun, **camera)


def write_isd(path: str | Path, isd: dict) -> Path:
    path = Path(path)
    path.write_text(json.dumps(isd))
    return path
