"""Reader of ALE image support data (ISD JSON) into frame and line-scan models.

ALE (DOI-USGS/ale, ``isd_generate``) writes, for any mission ISIS supports, the
interior orientation (``focal2pixel_lines/samples``, ``detector_center``,
``focal_length_model``, ``optical_distortion``), the ephemerides in J2000
(``instrument_position``, ``sun_position``; km), the attitude
(``instrument_pointing``: J2000 → sensor, ``body_rotation``: J2000 → body, each as
scalar-first quaternions times a ``constant_rotation``) and the line timing
(``line_scan_rate``).  usgscsm's ``constructStateFromIsd`` turns them into the state
reproduced here (usgscsm @ ba32d13bc560b0a22395b07419c494190715288f):

- frame: position and sun linearly interpolated at the centre time, rotated into the
  body frame;
- line scan: the J2000 ephemeris resampled on ``max(n, 25)`` equally spaced nodes over
  its time span with ALE's ``States::getState(t, SPLINE)`` (cubic Hermite through the
  positions and velocities, or a natural cubic spline without velocities), each node
  rotated into the body frame at its time (SLERP of the body rotation); the sun
  sampled the same way on the same nodes; sensor-to-body quaternions ``body ·
  sensorᵀ`` resampled at equal steps over the union of both attitude time lists;
  everything in metres.

The resampling matters when the ISD's velocities disagree with its positions: for
usgscsm's ``orbitalLineScan`` fixture it moves the centre pixel's ground point by
0.445 m, from usgscsm 1.x's published value to today's.  The resampled line-scan
model keeps no velocities (no geometry here uses them).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from demtool.errors import InputError
from demtool.sensors.base import (
    Detector,
    lagrange_interp,
    matrix_to_quaternion,
    quaternion_to_matrix,
    slerp,
)
from demtool.sensors.distortion import Distortion
from demtool.sensors.frame import FrameSensor
from demtool.sensors.isd_distortion import distortion_block, distortion_from_isd
from demtool.sensors.linescan import LineScanSensor

FRAME_MODEL = "USGS_ASTRO_FRAME_SENSOR_MODEL"
LINESCAN_MODEL = "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL"
PUSHFRAME_MODEL = "USGS_ASTRO_PUSH_FRAME_SENSOR_MODEL"
_UNITS = {"m": 1.0, "km": 1000.0}


class _Keys:
    """Key lookups that fail with one line naming the file and the key."""

    def __init__(self, source: str):
        self.source = source

    def get(self, mapping: Mapping, key: str, where: str = "") -> Any:
        if not isinstance(mapping, Mapping) or key not in mapping:
            raise InputError(f"{self.source}: ISD lacks the key '{where}{key}'")
        return mapping[key]

    def array(self, mapping: Mapping, key: str, where: str = "", shape=None) -> np.ndarray:
        value = self.get(mapping, key, where)
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"{self.source}: ISD key '{where}{key}' is not numeric") from None
        if shape is not None:
            want = tuple(arr.shape[i] if s == -1 else s for i, s in enumerate(shape))
            if arr.ndim != len(shape) or arr.shape != want or arr.size == 0:
                raise InputError(f"{self.source}: ISD key '{where}{key}' has shape {arr.shape}, "
                                 f"expected {tuple('n' if s == -1 else s for s in shape)}")
        if not np.all(np.isfinite(arr)):
            raise InputError(f"{self.source}: ISD key '{where}{key}' has non-finite values")
        return arr

    def rows(self, block: Mapping, key: str, name: str, width: int,
             times: np.ndarray) -> np.ndarray:
        """``{name}.{key}``, (len(times), width): one row per ``{name}.ephemeris_times``."""
        arr = self.array(block, key, f"{name}.", (-1, width))
        if len(arr) != len(times):
            raise InputError(f"{self.source}: ISD key '{name}.{key}' has {len(arr)} rows "
                             f"but '{name}.ephemeris_times' has {len(times)}")
        return arr

    def unit(self, mapping: Mapping, where: str, default: str = "km") -> float:
        unit = str(mapping.get("unit", default)).lower()
        if unit not in _UNITS:
            raise InputError(f"{self.source}: ISD key '{where}unit' is {unit!r}, "
                             "expected 'm' or 'km'")
        return _UNITS[unit]


class Orientations:
    """Time-dependent rotations ``constant · R(q(t))`` (ALE's ``Orientations``).

    times : (n,) seconds; quaternions : (n, 4) scalar-last; constant : (3, 3).
    Interpolation is SLERP between neighbours, extrapolating from the end pairs.
    """

    def __init__(self, times, quaternions, constant=None):
        self.times = np.asarray(times, dtype=np.float64).reshape(-1)
        self.quaternions = np.asarray(quaternions, dtype=np.float64).reshape(-1, 4)
        self.constant = np.eye(3) if constant is None else np.asarray(constant).reshape(3, 3)

    def quaternions_at(self, times) -> np.ndarray:
        times = np.asarray(times, dtype=np.float64).reshape(-1)
        if len(self.times) == 1:
            return np.broadcast_to(self.quaternions[0], (len(times), 4)).copy()
        i = np.clip(np.searchsorted(self.times, times, side="right") - 1, 0, len(self.times) - 2)
        frac = (times - self.times[i]) / (self.times[i + 1] - self.times[i])
        return slerp(self.quaternions[i], self.quaternions[i + 1], frac)

    def matrices_at(self, times) -> np.ndarray:
        """Rotation matrices (N, 3, 3) at ``times``."""
        return self.constant @ quaternion_to_matrix(self.quaternions_at(times))


def _orientations(keys: _Keys, isd: Mapping, name: str) -> Orientations:
    block = keys.get(isd, name)
    times = keys.array(block, "ephemeris_times", f"{name}.", (-1,))
    quats = keys.rows(block, "quaternions", name, 4, times)
    constant = None
    if "constant_rotation" in block:
        constant = keys.array(block, "constant_rotation", f"{name}.", (9,)).reshape(3, 3)
    return Orientations(times, quats[:, [1, 2, 3, 0]], constant)  # ALE is scalar-first


def _states(keys: _Keys, isd: Mapping, name: str):
    """Times, J2000 positions and velocities (metres, m/s; velocities None when
    absent) of an ALE ``States`` block."""
    block = keys.get(isd, name)
    times = keys.array(block, "ephemeris_times", f"{name}.", (-1,))
    positions = keys.rows(block, "positions", name, 3, times)
    if len(times) > 1 and np.any(np.diff(times) <= 0):
        raise InputError(f"{keys.source}: ISD key '{name}.ephemeris_times' is not increasing")
    scale = keys.unit(block, f"{name}.")
    velocities = None
    if "velocities" in block:
        velocities = keys.array(block, "velocities", f"{name}.", (len(times), 3)) * scale
    return times, positions * scale, velocities


def _to_body(body: Orientations, times, vectors):
    """Rotate J2000 vectors (N, 3) into the body frame at their times."""
    if vectors is None:
        return None
    return np.einsum("nij,nj->ni", body.matrices_at(times), vectors)


def resample_states(times, positions, velocities, grid) -> np.ndarray:
    """Positions (N, 3) at the times ``grid`` as ALE's ``States::getState(t, SPLINE)``.

    With velocities (not all zero) each coordinate is a cubic Hermite spline through
    the neighbouring samples and their velocities; without, a natural cubic spline
    through all samples (GSL's ``cspline``, as ALE calls it).  Beyond the ends the
    end interval's cubic is extrapolated.

    Reference: DOI-USGS/ale ``src/States.cpp`` (``getState``, ``evaluateCubicHermite``).
    """
    times = np.asarray(times, dtype=np.float64)
    grid = np.asarray(grid, dtype=np.float64)
    if velocities is not None and np.any(velocities != 0):
        i = np.clip(np.searchsorted(times, grid, side="right") - 1, 0, len(times) - 2)
        h = times[i + 1] - times[i]
        t = ((grid - times[i]) / h)[:, None]
        t2, t3 = t * t, t * t * t
        return ((2 * t3 - 3 * t2 + 1) * positions[i] + (t3 - 2 * t2 + t) * h[:, None]
                * velocities[i] + (-2 * t3 + 3 * t2) * positions[i + 1]
                + (t3 - t2) * h[:, None] * velocities[i + 1])
    if len(times) == 2:  # a natural spline through two points is the line
        frac = ((grid - times[0]) / (times[1] - times[0]))[:, None]
        return positions[0] + frac * (positions[1] - positions[0])
    from demtool.sensors.natural_spline import natural_cubic_spline

    # SciPy's CubicSpline(bc_type="natural") to the bit, without importing
    # scipy.interpolate (~0.8 CPU s: more than the rest of the ISD read)
    return natural_cubic_spline(times, positions, grid)


#: usgscsm resamples the sensor ephemeris on at least this many equally spaced nodes
#: (``constructStateFromIsd``: "Force at least 25 nodes to help with lagrange
#: interpolation").
MIN_EPHEMERIS_NODES = 25


def _detector(keys: _Keys, isd: Mapping) -> Detector:
    center = keys.get(isd, "detector_center")
    return Detector(
        itrans_sample=keys.array(isd, "focal2pixel_samples", shape=(3,)),
        itrans_line=keys.array(isd, "focal2pixel_lines", shape=(3,)),
        center_sample=float(keys.get(center, "sample", "detector_center.")),
        center_line=float(keys.get(center, "line", "detector_center.")),
        start_sample=float(isd.get("starting_detector_sample", 0.0)),
        start_line=float(isd.get("starting_detector_line", 0.0)),
        sample_summing=float(isd.get("detector_sample_summing", 1.0)),
        line_summing=float(isd.get("detector_line_summing", 1.0)))


def sensor_from_isd(isd: Mapping, source: str = "<ISD>"):
    """Build a :class:`FrameSensor` or :class:`LineScanSensor` from a parsed ISD dict.

    Raises
    ------
    InputError
        Missing or inconsistent keys, or an unknown ``name_model``; one line naming
        ``source`` and the key.
    """
    from demtool.sensors.isd_forms import EQUAL_STEP_KEY, normalise_isd

    isd = normalise_isd(isd, source)
    keys = _Keys(source)
    model = keys.get(isd, "name_model")
    if model == "USGS_ASTRO_SAR_SENSOR_MODEL":
        raise InputError(f"{source}: ISD key 'name_model' is {model!r}: a SAR (radar) "
                         "sensor model; demtool reads optical cameras only (frame, line "
                         "scan, push frame)")
    if model not in (FRAME_MODEL, LINESCAN_MODEL, PUSHFRAME_MODEL):
        raise InputError(f"{source}: ISD key 'name_model' is {model!r}; demtool reads "
                         f"{FRAME_MODEL}, {LINESCAN_MODEL} and {PUSHFRAME_MODEL}")
    lines = int(keys.get(isd, "image_lines"))
    samples = int(keys.get(isd, "image_samples"))
    if lines <= 0 or samples <= 0:
        raise InputError(f"{source}: ISD image size {lines}x{samples} is empty")
    focal = float(keys.get(keys.get(isd, "focal_length_model"), "focal_length",
                           "focal_length_model."))
    radii_block = keys.get(isd, "radii")
    scale = keys.unit(radii_block, "radii.")
    radii = (float(keys.get(radii_block, "semimajor", "radii.")) * scale,
             float(keys.get(radii_block, "semiminor", "radii.")) * scale)
    detector = _detector(keys, isd)
    distortion = distortion_from_isd(keys, isd, focal)
    center_time = float(keys.get(isd, "center_ephemeris_time"))
    body = _orientations(keys, isd, "body_rotation")
    pointing = _orientations(keys, isd, "instrument_pointing")
    pos_times, pos_j2000, vel_j2000 = _states(keys, isd, "instrument_position")
    sun_times, sun_j2000, sun_vel_j2000 = _states(keys, isd, "sun_position")
    name = str(isd.get("image_identifier", Path(source).stem))

    if model == FRAME_MODEL:
        t = np.array([center_time])
        rotation = body.matrices_at(t)[0] @ pointing.matrices_at(t)[0].T
        positions = _to_body(body, pos_times, pos_j2000)
        sun = _to_body(body, sun_times, sun_j2000)
        return FrameSensor(position=_linear(pos_times, positions, center_time),
                           rotation=rotation, focal_length=focal, detector=detector,
                           distortion=distortion, lines=lines, samples=samples, radii=radii,
                           sun=_linear(sun_times, sun, center_time), name=name,
                           time=center_time)

    if model == PUSHFRAME_MODEL:
        from demtool.sensors.pushframe import framelet_keys

        rate, framelets = None, framelet_keys(keys, isd, center_time)
    else:
        rate, framelets = keys.array(isd, "line_scan_rate", shape=(-1, 3)), None
    if rate is not None and np.any(rate[:, 2] == 0):
        raise InputError(f"{source}: ISD key 'line_scan_rate' has a zero line time")
    # usgscsm (constructStateFromIsd): the ephemeris is resampled on at least 25 equally
    # spaced nodes over the ISD's time span (ALE's Hermite / natural spline), rotated
    # into the body frame at each node; the sun is sampled on the same nodes.
    if len(pos_times) > 1 and isd.get(EQUAL_STEP_KEY):
        # usgscsm's older layout: equally spaced body-fixed nodes, used as they are
        dt_ephem = (pos_times[-1] - pos_times[0]) / (len(pos_times) - 1)
        grid = pos_times
        positions = _to_body(body, pos_times, pos_j2000)
        velocities = _to_body(body, pos_times, vel_j2000)
    elif len(pos_times) > 1:
        n_nodes = max(len(pos_times), MIN_EPHEMERIS_NODES)
        dt_ephem = (pos_times[-1] - pos_times[0]) / (n_nodes - 1)
        grid = pos_times[0] + dt_ephem * np.arange(n_nodes)
        positions = _to_body(body, grid, resample_states(pos_times, pos_j2000, vel_j2000, grid))
        velocities = None
    else:
        dt_ephem = 1.0
        grid = pos_times
        positions = _to_body(body, pos_times, pos_j2000)
        velocities = _to_body(body, pos_times, vel_j2000)
    if len(sun_times) > 1 and len(grid) > 1:
        sun = _to_body(body, grid, resample_states(sun_times, sun_j2000, sun_vel_j2000, grid))
        sun_velocities = None
    else:  # one sun position: kept, with its velocity for linear extrapolation
        sun = _to_body(body, sun_times, sun_j2000)
        sun_velocities = _to_body(body, sun_times, sun_vel_j2000)
    quat_times = pointing.times if isd.get(EQUAL_STEP_KEY) else np.union1d(body.times,
                                                                            pointing.times)
    if len(quat_times) > 1:
        dt_quat = (quat_times[-1] - quat_times[0]) / (len(quat_times) - 1)
        quat_times = quat_times[0] + dt_quat * np.arange(len(quat_times))
    else:
        dt_quat = 1.0
    sensor_to_body = body.matrices_at(quat_times) @ np.swapaxes(
        pointing.matrices_at(quat_times), -1, -2)
    pose = dict(
        positions=positions, velocities=velocities,
        t0_ephem=pos_times[0] - center_time, dt_ephem=dt_ephem,
        quaternions=matrix_to_quaternion(sensor_to_body), t0_quat=quat_times[0] - center_time,
        dt_quat=dt_quat, focal_length=focal, detector=detector, distortion=distortion,
        lines=lines, samples=samples, radii=radii, sun_positions=sun,
        sun_velocities=sun_velocities, name=name, center_time=center_time)
    if framelets is not None:
        from demtool.sensors.pushframe import PushFrameSensor

        try:
            sensor = PushFrameSensor(**framelets, **pose)
        except ValueError as exc:
            raise InputError(f"{source}: {exc}") from None
    else:
        sensor = LineScanSensor(line_scan_rate=rate, **pose)
    from demtool.sensors.coverage import attach_coverage, attitude_end_margins

    pitch = 1.0 / max(float(np.hypot(detector.itrans_sample[1], detector.itrans_sample[2])),
                      1e-300)  # mm per pixel
    ifov = pitch * float(detector.sample_summing) / abs(focal)
    margins = {name: attitude_end_margins(block.times - center_time, block.quaternions, ifov)
               for name, block in (("instrument_pointing", pointing), ("body_rotation", body))}
    attach_coverage(sensor, source, {"instrument_position": pos_times - center_time,
                                     "instrument_pointing": pointing.times - center_time,
                                     "body_rotation": body.times - center_time}, margins)
    return sensor


def _linear(times: np.ndarray, values: np.ndarray, t: float) -> np.ndarray:
    """Linear interpolation (extrapolation at the ends) of rows of ``values`` at ``t``."""
    if len(times) == 1:
        return values[0].copy()
    i = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2))
    frac = (t - times[i]) / (times[i + 1] - times[i])
    return values[i] + frac * (values[i + 1] - values[i])


def read_isd(path: str | Path):
    """Read an ALE ISD JSON file into a sensor model (see :func:`sensor_from_isd`)."""
    p = Path(path)
    isd = load_isd(p)
    return sensor_from_isd(isd, str(p))


# ---------------------------------------------------------------------------------------
# Writer: a model → the ISD ALE would write for it (J2000 taken as the body frame)
# ---------------------------------------------------------------------------------------

#: Quaternion of the identity rotation, ALE's scalar-first order.
_IDENTITY_QUATERNION = [1.0, 0.0, 0.0, 0.0]


def _ale_quaternions(sensor_to_body: np.ndarray) -> list:
    """ALE ``instrument_pointing`` quaternions (scalar-first, J2000 → sensor) of
    sensor-to-body rotations (..., 3, 3), with the body frame taken as J2000."""
    q = matrix_to_quaternion(np.swapaxes(np.asarray(sensor_to_body).reshape(-1, 3, 3), -1, -2))
    return q[:, [3, 0, 1, 2]].tolist()


def _common_keys(model, detector: Detector, distortion: Distortion, focal: float) -> dict:
    a, b = model.radii
    return {
        "image_identifier": model.name or "synthetic",
        "name_platform": "DEMTOOL_SYNTH", "name_sensor": model.kind.upper(),
        "image_lines": int(model.lines), "image_samples": int(model.samples),
        "radii": {"semimajor": a / 1000.0, "semiminor": b / 1000.0, "unit": "km"},
        "focal_length_model": {"focal_length": focal},
        "focal2pixel_samples": [float(v) for v in detector.itrans_sample],
        "focal2pixel_lines": [float(v) for v in detector.itrans_line],
        "detector_center": {"line": float(detector.center_line),
                            "sample": float(detector.center_sample)},
        "starting_detector_line": float(detector.start_line),
        "starting_detector_sample": float(detector.start_sample),
        "detector_line_summing": float(detector.line_summing),
        "detector_sample_summing": float(detector.sample_summing),
        "optical_distortion": distortion_block(distortion),
    }


def _states_block(times, positions, velocities=None) -> dict:
    """An ALE ``States`` block in km (positions (n, 3) metres, velocities m/s)."""
    block = {"ephemeris_times": [float(t) for t in np.atleast_1d(times)],
             "positions": (np.asarray(positions).reshape(-1, 3) / 1000.0).tolist(),
             "reference_frame": 1, "unit": "km"}
    if velocities is not None:
        block["velocities"] = (np.asarray(velocities).reshape(-1, 3) / 1000.0).tolist()
    return block


def _rotations_block(times, quaternions) -> dict:
    return {"ephemeris_times": [float(t) for t in np.atleast_1d(times)],
            "quaternions": quaternions, "time_dependent_frames": [1],
            "constant_frames": [1], "constant_rotation": np.eye(3).ravel().tolist(),
            "reference_frame": 1}


def isd_from_sensor(model) -> dict:
    """The ALE image support data (ISD) of a frame or line-scan model, as a dict.

    The model's body-fixed frame is written as J2000 (``body_rotation`` is the
    identity at every time), the positions in km, quaternions scalar-first (ALE's
    order), so :func:`sensor_from_isd` rebuilds the same geometry and usgscsm reads the
    file as any ALE ISD.

    - :class:`FrameSensor`: one position, one attitude and one sun position at
      ``model.time`` (a ``z_direction`` of −1 is folded into the attitude: the frame
      ``(−x, −y, z)`` of the focal plane gives the same rays with usgscsm's +z look).
    - :class:`PushFrameSensor`: as a line-scan model, with usgscsm's framelet keys
      (``framelet_height``, ``exposure_duration``, ``interframe_delay``, the two flags,
      ``starting_ephemeris_time``) instead of ``line_scan_rate``.
    - :class:`LineScanSensor`: positions on ``max(n, 25)`` equally spaced nodes over
      the model's ephemeris span (usgscsm's minimum, so reading does not resample;
      a model with fewer nodes is sampled by its own Lagrange interpolation), with
      velocities when the model has them on those nodes; the sun on the same nodes
      (or the one sun position and its velocity); attitude on the model's quaternion
      nodes; ``line_scan_rate`` as given.

    Parameters
    ----------
    model : FrameSensor or LineScanSensor
        Its ``radii`` must be set (a body-fixed model).

    Returns
    -------
    dict
        JSON-serialisable ISD with ``name_model`` ``USGS_ASTRO_FRAME_SENSOR_MODEL`` or
        ``USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL``.

    Raises
    ------
    ValueError
        Another kind of model, or a model without radii.
    """
    if getattr(model, "radii", None) is None:
        raise ValueError("isd_from_sensor: the model has no body radii (a local-frame model)")
    if isinstance(model, FrameSensor):
        rotation = model.rotation
        if model.z_direction < 0:
            rotation = rotation @ np.diag([-1.0, -1.0, 1.0])
        t = float(model.time)
        isd = _common_keys(model, model.detector, model.distortion, model.focal_length)
        isd.update({
            "name_model": FRAME_MODEL, "center_ephemeris_time": t,
            "starting_ephemeris_time": t,
            "instrument_position": _states_block([t], model.position, np.zeros(3)),
            "sun_position": _states_block([t], model.sun, np.zeros(3)),
            "instrument_pointing": _rotations_block([t], _ale_quaternions(rotation)),
            "body_rotation": _rotations_block([t], [_IDENTITY_QUATERNION]),
        })
        return isd
    if not isinstance(model, LineScanSensor):
        raise ValueError(f"isd_from_sensor: cannot write a {type(model).__name__} as an ISD "
                         "(frame, line-scan and push-frame models only)")
    centre = model.center_time
    n_pos = len(model.positions)
    if n_pos >= MIN_EPHEMERIS_NODES or n_pos == 1:
        rel = model.t0_ephem + model.dt_ephem * np.arange(n_pos)
        positions, velocities = model.positions, model.velocities
        if velocities is not None and len(velocities) != n_pos:
            velocities = None
    else:
        span = model.dt_ephem * (n_pos - 1)
        rel = model.t0_ephem + span * np.arange(MIN_EPHEMERIS_NODES) / (MIN_EPHEMERIS_NODES - 1)
        positions, velocities = model.position_at(rel), None
    n_sun = len(model.sun_positions)
    if n_sun > 1:
        dt_sun = model.dt_ephem * n_pos / n_sun
        sun = _states_block(centre + rel, lagrange_interp(model.sun_positions, model.t0_ephem,
                                                          dt_sun, rel, 8))
    else:
        sun_velocity = (np.zeros(3) if model.sun_velocities is None
                        or not len(model.sun_velocities) else model.sun_velocities[0])
        sun = _states_block([centre], model.sun_positions[0], sun_velocity)
    quat_rel = model.t0_quat + model.dt_quat * np.arange(len(model.quaternions))
    rotations = quaternion_to_matrix(model.quaternions)
    quat_times = centre + quat_rel
    isd = _common_keys(model, model.detector, model.distortion, model.focal_length)
    isd.update({
        "name_model": LINESCAN_MODEL, "center_ephemeris_time": centre,
        "starting_ephemeris_time": centre + float(model.line_time(0.5)),
        "line_scan_rate": np.column_stack([model.int_lines, model.int_start_times,
                                           model.int_times]).tolist(),
        "instrument_position": _states_block(centre + rel, positions, velocities),
        "sun_position": sun,
        "instrument_pointing": _rotations_block(quat_times, _ale_quaternions(rotations)),
        "body_rotation": _rotations_block(quat_times,
                                          [_IDENTITY_QUATERNION] * len(quat_times)),
    })
    if getattr(model, "kind", "") == "pushframe":  # usgscsm's framelet keys instead
        del isd["line_scan_rate"]
        isd.update({"name_model": PUSHFRAME_MODEL,
                    "starting_ephemeris_time": centre + model.starting_time,
                    "framelet_height": int(model.framelet_height),
                    "exposure_duration": float(model.exposure_duration),
                    "interframe_delay": float(model.interframe_delay),
                    "framelets_flipped": bool(model.framelets_flipped),
                    "framelet_order_reversed": bool(model.framelet_order_reversed)})
    return isd


def write_isd(path: str | Path, model) -> Path:
    """Write :func:`isd_from_sensor` of ``model`` as JSON, atomically; returns the path."""
    from demtool import io

    return io.write_json(path, isd_from_sensor(model))


def load_isd(path: str | Path) -> dict:
    """Parse an ISD JSON file (one line naming the file when it cannot be read)."""

    p = Path(path)
    try:
        with open(p, encoding="utf-8") as handle:
            isd = json.load(handle)
    except OSError as exc:
        raise InputError(f"{p}: cannot read ISD ({exc.strerror or exc})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: not valid JSON ({exc})") from None
    except (ValueError, RecursionError) as exc:
        raise InputError(f"{p}: not a readable ISD ({exc})") from None
    if not isinstance(isd, Mapping):
        raise InputError(f"{p}: ISD is not a JSON object")
    return isd
