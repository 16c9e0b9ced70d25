"""Planetary sensor models of the synthetic views: frame cameras and a line-scan pair.

The scene sits on a spherical body (:mod:`demtool.synth.body`); its views become
body-fixed sensor models of :mod:`demtool.sensors` that the renderer casts rays
through and that ``synth`` writes as ISDs.

Frame (``synth --sensor frame``)
    Each pinhole of :func:`demtool.synth.scene.make_cameras` as a CSM frame camera:
    pixel pitch ``p`` (mm), focal length ``f_px · p`` mm, ``focal2pixel_samples =
    (0, 1/p, 0)``, ``focal2pixel_lines = (0, 0, 1/p)``, detector centre at the
    principal point (``cx + 0.5``, ``cy + 0.5``: CSM's first pixel centre is 0.5), the
    sensor-to-body rotation ``Eᵀ Rᵀ`` (E the placement's east-north-up rows, R the
    pinhole's world-to-camera rotation), at time 0.  The rays are the pinhole's.
Line scan (``synth --sensor linescan``)
    Two pushbroom cameras with LRO NAC-like geometry (Robinson et al. 2010, Space
    Sci. Rev. 150:81; NAC stereo from off-nadir slews, 20–30° convergence): each on a
    circular orbit of radius R + altitude flying south over the scene (image line 0
    north, samples increasing east), ground speed ``ground_speed_m_s`` at the
    surface, rolled off nadir by ∓convergence/2 about its velocity and displaced
    across track so its boresight meets the scene centre at t = 0 (the centre line).
    Focal length so the cross-track pixel is ``gsd_m`` on flat ground at the centre
    (``f_px = ρ / (gsd cos e)``, ρ range, e emission), line time ``gsd_m / ground
    speed`` so pixels are square; position and attitude on 41 equally spaced nodes
    (usgscsm's Lagrange interpolation between them), the detector one line
    (usgscsm's look ``(−x, −y, −f)``).
"""

from __future__ import annotations

import numpy as np

from demtool.sensors import Detector, FrameSensor, LineScanSensor
from demtool.sensors.base import matrix_to_quaternion

PIXEL_PITCH_MM = 0.007  # 7 µm, the LRO NAC's
EPHEMERIS_NODES = 41  # ≥ 25 (usgscsm's minimum), so ISDs are not resampled


def _detector(pitch_mm: float, center_sample: float, center_line: float) -> Detector:
    return Detector(itrans_sample=np.array([0.0, 1.0 / pitch_mm, 0.0]),
                    itrans_line=np.array([0.0, 0.0, 1.0 / pitch_mm]),
                    center_sample=float(center_sample), center_line=float(center_line))


def frame_sensor(camera, placement, *, sun_position, name: str = "",
                 pitch_mm: float = PIXEL_PITCH_MM) -> FrameSensor:
    """The body-fixed CSM frame camera of a local-frame pinhole (module docstring).

    Parameters
    ----------
    camera : demtool.sensors.PinholeCamera
        Ideal pinhole (no distortion, fx = fy, no skew) in the local frame.
    placement : demtool.synth.body.Placement
    sun_position : (3,) float
        Body-fixed sun position, metres.
    name : str
    pitch_mm : float
        Detector pixel pitch, millimetres.

    Returns
    -------
    FrameSensor
        Same rays as ``camera`` (body-fixed), image ``camera.height × camera.width``.
    """
    K = camera.K
    if camera.distortion is not None or K[0, 1] != 0 or not np.isclose(K[0, 0], K[1, 1]):
        raise ValueError("frame_sensor: only ideal square-pixel pinholes are supported")
    rotation = placement.frame.T @ camera.R.T
    return FrameSensor(position=placement.to_body(camera.center), rotation=rotation,
                       focal_length=float(K[0, 0]) * pitch_mm,
                       detector=_detector(pitch_mm, K[0, 2] + 0.5, K[1, 2] + 0.5),
                       lines=camera.height, samples=camera.width,
                       radii=(placement.radius, placement.radius), sun=sun_position,
                       name=name, time=0.0)


def cross_track_offset(off_nadir_rad: float, orbit_radius: float, radius: float) -> float:
    """Angle at the body centre (radians) between the spacecraft and the ground point it
    sees ``off_nadir_rad`` off nadir: ``asin(r sin η / R) − η`` (law of sines in the
    triangle centre–spacecraft–ground point, near-side intersection)."""
    return float(np.arcsin(orbit_radius * np.sin(off_nadir_rad) / radius) - off_nadir_rad)


def linescan_sensor(placement, *, off_nadir_deg: float, altitude_m: float, gsd_m: float,
                    ground_speed_m_s: float, lines: int, samples: int, sun_position,
                    name: str = "", pitch_mm: float = PIXEL_PITCH_MM) -> LineScanSensor:
    """One pushbroom camera of the synthetic pair (module docstring).

    Parameters
    ----------
    placement : demtool.synth.body.Placement
        The scene centre is ``placement.origin``.
    off_nadir_deg : float
        Roll off nadir at the centre line, degrees; positive looks east (the orbit
        passes west of the scene).
    altitude_m : float
        Orbit height above the reference sphere, metres.
    gsd_m : float
        Cross-track and along-track pixel size on flat ground at the centre, metres.
    ground_speed_m_s : float
        Speed of the sub-spacecraft point on the sphere, m/s.
    lines, samples : int
        Image size.
    sun_position : (3,) float
        Body-fixed sun position, metres.

    Returns
    -------
    LineScanSensor
        Centre time 0 at the centre line (``lines / 2``).
    """
    radius = placement.radius
    orbit = radius + altitude_m
    east, north, up = placement.frame
    eta = np.radians(off_nadir_deg)
    beta = -np.sign(eta) * cross_track_offset(abs(eta), orbit, radius)
    a = np.cos(beta) * up + np.sin(beta) * east  # spacecraft direction at t = 0
    b = -north  # flying south
    omega = ground_speed_m_s / radius  # rad/s about the body centre
    position0 = orbit * a
    look0 = placement.origin - position0
    rng = float(np.linalg.norm(look0))
    look0 /= rng
    cross0 = np.cross(b, a)  # orbit frame at t = 0: along b, up a, cross = b × a
    l_cross, l_up = float(look0 @ cross0), float(look0 @ a)
    emission = np.arccos(np.clip(-(look0 @ up), -1.0, 1.0))
    focal_px = rng / (gsd_m * np.cos(emission))
    line_time = gsd_m / ground_speed_m_s
    half = 0.5 * lines * line_time
    margin = 4.0 * line_time
    times = np.linspace(-half - margin, half + margin, EPHEMERIS_NODES)
    wt = omega * times[:, None]
    unit = np.cos(wt) * a + np.sin(wt) * b
    along = -np.sin(wt) * a + np.cos(wt) * b
    cross = np.cross(along, unit)
    z_axis = -(l_cross * cross + l_up * unit)
    x_axis = np.cross(along, z_axis)
    rotations = np.stack([x_axis, along, z_axis], axis=-1)  # columns: sensor axes
    velocities = orbit * omega * along
    return LineScanSensor(
        line_scan_rate=[[0.5, -half, line_time]], positions=orbit * unit,
        velocities=velocities, t0_ephem=float(times[0]), dt_ephem=float(times[1] - times[0]),
        quaternions=matrix_to_quaternion(rotations), t0_quat=float(times[0]),
        dt_quat=float(times[1] - times[0]), focal_length=focal_px * pitch_mm,
        detector=_detector(pitch_mm, 0.5 * samples, 0.0), lines=lines, samples=samples,
        radii=(radius, radius), sun_positions=np.asarray(sun_position, dtype=np.float64)[None],
        name=name, center_time=0.0)


def convergence_deg(first, second, placement) -> float:
    """Angle (degrees) between two sensors' rays to the scene centre at their centre
    lines: the pair's stereo convergence."""
    ground = placement.origin
    rays = []
    for model in (first, second):
        line, _ = model.ground_to_image(ground)
        rays.append(model.camera_center(line) - ground)
    cos = rays[0] @ rays[1] / (np.linalg.norm(rays[0]) * np.linalg.norm(rays[1]))
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def footprint_bounds(camera, z_min: float, z_max: float, *, placement=None,
                     border_step: int = 1) -> np.ndarray:
    """(x_min, x_max, y_min, y_max) (local metres) of the ground any pixel can see between
    the planes z_min and z_max.

    Rays along the image border (every ``border_step`` pixels, corners included) are
    cut by both planes; for a pinhole the frustum's extremes are its corner rays, for a
    line scanner each line's fan is planar, so the border bounds every hit.
    """
    lines, samples = camera.lines, camera.samples
    edge_l = np.arange(0, lines + 1, border_step, dtype=np.float64)
    edge_s = np.arange(0, samples + 1, border_step, dtype=np.float64)
    edge_l = np.union1d(edge_l, [lines])
    edge_s = np.union1d(edge_s, [samples])
    line = np.concatenate([edge_l, edge_l, np.zeros_like(edge_s), np.full_like(edge_s, lines)])
    sample = np.concatenate([np.zeros_like(edge_l), np.full_like(edge_l, samples), edge_s,
                             edge_s])
    ray = camera.image_to_ray(line, sample)  # CSM coordinates: 0 and lines are the edges
    origin, direction = ray.origin, ray.direction
    if placement is not None:
        origin = placement.to_local(origin)
        direction = placement.directions_to_local(direction)
    if np.any(direction[:, 2] >= 0):
        return np.array([-np.inf, np.inf, -np.inf, np.inf])
    points = []
    for z in (z_min, z_max):
        s = (z - origin[:, 2]) / direction[:, 2]
        points.append(origin[:, :2] + s[:, None] * direction[:, :2])
    xy = np.vstack(points)
    return np.array([xy[:, 0].min(), xy[:, 0].max(), xy[:, 1].min(), xy[:, 1].max()])
