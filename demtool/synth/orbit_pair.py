"""A stereo partner for a real line-scan ISD: the same camera on a neighbouring orbit.

LROC NAC stereo is made from two orbits: on a later orbit the Moon has turned under
LRO, and the spacecraft rolls to look back at the site the first image saw (Henriksen
et al. 2017, *Icarus* 283, 122–137, §2.1: 15–30° convergence).  :func:`later_orbit_isd`
builds that second view from one real ALE/usgscsm ISD, in the ISD's own frames:

1. the *site* S is the ground point (on the reference ellipsoid) of one pixel of the
   first image (default its centre), taken into J2000 with the ISD's ``body_rotation``
   at that line's time;
2. the whole trajectory (``instrument_position`` positions and velocities) is rotated
   rigidly about the body's centre, about the along-track direction (the velocity's
   part perpendicular to the position at the site's time), by the angle φ that makes
   the rays from the old and the new position to S converge by ``convergence_deg``:
   the cross-track shift of a neighbouring orbit, at the same times;
3. the pointing turns with the trajectory (``instrument_pointing`` J2000 → sensor
   ``M`` becomes ``A · M · Gᵀ``, G the orbit rotation), and ``A`` rolls the camera
   back onto S: the least rotation in the sensor frame that brings S's direction
   from the new position onto the direction in which the first view saw it, so S
   lies at the same detector position of both images (A's axis is within a few
   degrees of the along-track axis: it is a roll).

Everything else (timing, interior orientation, body rotation, sun) is kept, so the
result is a valid usgscsm line-scan ISD read by :func:`demtool.sensors.read_sensor`
as by usgscsm.  The quaternions are written scalar-first (ALE's order) times the
ISD's unchanged ``constant_rotation``; ``angular_velocities`` (J2000) are rotated
by G.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from demtool.errors import InputError


class OrbitPair(NamedTuple):
    """What :func:`later_orbit_isd` did.

    isd : dict
        The second view's ISD (a new dict in ALE's current layout; the input is not
        modified).
    site_body_m : (3,) float64
        The site S, body-fixed metres, on the reference ellipsoid.
    orbit_rotation_deg : float
        φ, the rotation of the trajectory about the along-track axis, degrees.
    cross_track_shift_m : float
        Distance between the old and the new spacecraft position at the site's time.
    roll_deg : float
        Angle of the pointing rotation A (the roll back onto the site), degrees.
    roll_axis_from_along_track_deg : float
        Angle between A's axis and the along-track direction (degrees, 0–90).
    convergence_deg : float
        Angle at S between the rays from the two positions, degrees.
    """

    isd: dict
    site_body_m: np.ndarray
    orbit_rotation_deg: float
    cross_track_shift_m: float
    roll_deg: float
    roll_axis_from_along_track_deg: float
    convergence_deg: float


def axis_angle_matrix(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rotation matrix (3, 3) of ``angle_rad`` about the unit ``axis`` (Rodrigues)."""
    k = np.asarray(axis, dtype=np.float64)
    k = k / np.linalg.norm(k)
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle_rad) * cross + (1.0 - math.cos(angle_rad)) * cross @ cross


def _angle(u: np.ndarray, v: np.ndarray) -> float:
    c = float(u @ v / (np.linalg.norm(u) * np.linalg.norm(v)))
    return math.acos(max(-1.0, min(1.0, c)))


def _least_rotation(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The rotation (3, 3) of least angle taking direction ``u`` onto direction ``v``."""
    u, v = u / np.linalg.norm(u), v / np.linalg.norm(v)
    axis = np.cross(u, v)
    if np.linalg.norm(axis) < 1e-15:
        return np.eye(3)
    return axis_angle_matrix(axis, _angle(u, v))


def later_orbit_isd(isd: Mapping[str, Any], *, convergence_deg: float,
                    site_line: float | None = None, site_sample: float | None = None,
                    side: int = 1, source: str = "<ISD>") -> OrbitPair:
    """The ISD of the same line scanner on a neighbouring orbit, looking back at a site.

    See the module docstring for the construction.

    Parameters
    ----------
    isd : mapping
        A line-scan ISD (``USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL``) as parsed JSON.
    convergence_deg : float
        Angle between the two views' rays at the site, degrees (0 < value < 60).
    site_line, site_sample : float, optional
        The pixel of the first image whose ground point is the site (CSM pixel
        coordinates; default the image centre).
    side : {1, -1}
        Which neighbour: the trajectory is rotated by +φ or −φ about the along-track
        axis.
    source : str
        Name of the ISD for error messages.

    Returns
    -------
    OrbitPair

    Raises
    ------
    InputError
        Not a line-scan ISD, a convergence out of range, or a site pixel whose ray
        misses the body.
    """
    from demtool.sensors.base import matrix_to_quaternion, quaternion_to_matrix
    from demtool.sensors.isd import _UNITS, Orientations, resample_states, sensor_from_isd
    from demtool.sensors.isd_forms import normalise_isd

    isd = normalise_isd(isd, source)  # older usgscsm layouts → ALE's
    if isd.get("name_model") != "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL":
        raise InputError(f"{source}: a later orbit is made for line-scan ISDs, not "
                         f"{isd.get('name_model')!r}")
    if not 0.0 < convergence_deg < 60.0:
        raise InputError(f"{source}: convergence {convergence_deg}° is outside (0°, 60°)")
    if side not in (1, -1):
        raise ValueError("side must be 1 or -1")
    model = sensor_from_isd(isd, source)
    line = 0.5 * model.lines if site_line is None else float(site_line)
    sample = 0.5 * model.samples if site_sample is None else float(site_sample)
    site_body = np.asarray(model.image_to_ground(np.array([line]), np.array([sample])),
                           dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(site_body)):
        raise InputError(f"{source}: the ray of pixel (line {line}, sample {sample}) misses "
                         "the body")
    time = float(isd["center_ephemeris_time"]) + float(model.line_time(line))

    def orientations(block):
        quats = np.asarray(block["quaternions"], dtype=np.float64).reshape(-1, 4)
        constant = block.get("constant_rotation")
        return Orientations(block["ephemeris_times"], quats[:, [1, 2, 3, 0]],
                            None if constant is None else np.reshape(constant, (3, 3)))

    body = orientations(isd["body_rotation"])
    pointing_block = isd["instrument_pointing"]
    pointing = orientations(pointing_block)
    site = body.matrices_at([time])[0].T @ site_body  # J2000, metres
    position_block = isd["instrument_position"]
    scale = _UNITS.get(str(position_block.get("unit", "km")).lower())
    if scale is None:
        raise InputError(f"{source}: ISD key 'instrument_position.unit' is "
                         f"{position_block.get('unit')!r}, expected 'm' or 'km'")
    times = np.asarray(position_block["ephemeris_times"], dtype=np.float64).reshape(-1)
    positions = np.asarray(position_block["positions"], dtype=np.float64).reshape(-1, 3)
    velocities = position_block.get("velocities")
    velocities = None if velocities is None else \
        np.asarray(velocities, dtype=np.float64).reshape(-1, 3)
    if len(times) > 1:
        state = resample_states(times, positions * scale,
                                None if velocities is None else velocities * scale,
                                np.array([time]))
        p = np.asarray(state, dtype=np.float64).reshape(-1, 3)[0]
        i = int(np.clip(np.searchsorted(times, time) - 1, 0, len(times) - 2))
        v = (velocities[i] * scale if velocities is not None
             else (positions[i + 1] - positions[i]) * scale / (times[i + 1] - times[i]))
    else:
        p = positions[0] * scale
        if velocities is None:
            raise InputError(f"{source}: one instrument position without a velocity: no "
                             "along-track direction")
        v = velocities[0] * scale
    along = v - (v @ p) / (p @ p) * p
    along /= np.linalg.norm(along)

    target = math.radians(convergence_deg)

    def convergence(phi: float) -> float:
        return _angle(p - site, axis_angle_matrix(along, side * phi) @ p - site)

    lo, hi = 0.0, 0.5
    if convergence(hi) < target:
        raise InputError(f"{source}: no neighbouring orbit converges by {convergence_deg}°")
    for _ in range(200):  # the convergence grows with φ up to far beyond 60°
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if convergence(mid) < target else (lo, mid)
    phi = side * 0.5 * (lo + hi)
    g = axis_angle_matrix(along, phi)
    m = pointing.matrices_at([time])[0]
    first = m @ (site - p)  # sensor frame, first view
    moved = m @ g.T @ (site - g @ p)  # sensor frame, rigidly moved camera
    a = _least_rotation(moved, first)
    roll_axis = np.array([a[2, 1] - a[1, 2], a[0, 2] - a[2, 0], a[1, 0] - a[0, 1]])
    along_sensor = m @ along
    axis_off = math.degrees(_angle(roll_axis, along_sensor)) if np.linalg.norm(roll_axis) \
        else 0.0
    axis_off = min(axis_off, 180.0 - axis_off)

    out = copy.deepcopy(isd)
    new_position = out["instrument_position"]
    new_position["positions"] = (positions @ g.T).tolist()
    if velocities is not None:
        new_position["velocities"] = (velocities @ g.T).tolist()
    quats = np.asarray(pointing_block["quaternions"], dtype=np.float64).reshape(-1, 4)
    constant = pointing.constant
    rotations = quaternion_to_matrix(quats[:, [1, 2, 3, 0]])  # R(q), J2000 → (C ·) sensor
    new_rotations = constant.T @ a @ constant @ rotations @ g.T
    new_quats = matrix_to_quaternion(new_rotations)[:, [3, 0, 1, 2]]
    new_quats *= np.sign(np.sum(new_quats * quats, axis=1, keepdims=True) + 1e-300)
    new_pointing = out["instrument_pointing"]
    new_pointing["quaternions"] = new_quats.tolist()
    if pointing_block.get("angular_velocities") is not None:
        av = np.asarray(pointing_block["angular_velocities"], dtype=np.float64).reshape(-1, 3)
        new_pointing["angular_velocities"] = (av @ g.T).tolist()
    if "image_identifier" in out:
        out["image_identifier"] = f"{out['image_identifier']}_later_orbit"
    return OrbitPair(isd=out, site_body_m=site_body, orbit_rotation_deg=math.degrees(phi),
                     cross_track_shift_m=float(np.linalg.norm(g @ p - p)),
                     roll_deg=math.degrees(_angle(moved, first)),
                     roll_axis_from_along_track_deg=axis_off,
                     convergence_deg=math.degrees(convergence(abs(phi))))
