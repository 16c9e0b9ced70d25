"""Every form of an ISD the reference tools read, brought to ALE's current layout before
a model is built (:func:`normalise_isd`; the reader :mod:`demtool.sensors.isd` then reads
one layout).

- **usgscsm's older layout** (``UsgsAstroLsSensorModel`` / ``UsgsAstroFrameSensorModel``
  before ALE's ``instrument_position``; still parsed by usgscsm's ``Utilities.cpp``:
  ``getSensorPositions``, ``getSensorVelocities``, ``getSensorOrientations``,
  ``getSunPositions``): ``sensor_position`` (body-fixed positions and velocities with
  their ``unit``), ``sensor_orientation.quaternions`` (sensor-to-body rotations,
  scalar-last ``x, y, z, w``: usgscsm's state quaternions), ``t0_ephemeris`` /
  ``dt_ephemeris`` and ``t0_quaternion`` / ``dt_quaternion`` (seconds from
  ``center_ephemeris_time``), and no ``body_rotation``: the positions are already in the
  body frame, so the body rotation is the identity.  Written here as ALE's blocks (the
  positions at ``centre + t0 + i·dt``, the pointing as J2000 → sensor quaternions,
  scalar-first, with J2000 taken as the body frame) and a marker
  (:data:`EQUAL_STEP_KEY`) telling the reader to keep usgscsm's equally spaced nodes as
  they are (no resampling).  A frame ISD uses the first position and quaternion.  The
  sun's positions lie on the grid ``t0_ephemeris + i·dt_ephemeris·n_pos/n_sun``
  (``getSunPosition``).  A block without ``unit`` is taken in metres (ALE's older
  ``usgscsm`` formatter wrote metres; usgscsm requires the key).
- **Summing of 0** (``detector_line_summing`` / ``detector_sample_summing``): TGO CaSSIS
  labels carry a summing *mode* (0 = 1×1, 1 = 2×2, 2 = 4×4), which ISIS's
  ``TgoCassisCamera`` turns into a summing of 1 when it is 0, and ALE's CaSSIS driver
  likewise; read as 1.
- **``focal_length`` null** (ALE's ISDs made from ISIS labels): ALE's formatter writes
  the driver's ``focal_length``, which ISIS label drivers read from the instrument
  kernel's ``INS<ik>_FOCAL_LENGTH`` — the value is taken from ``naif_keywords`` where it is
  there; likewise a null ``detector_center`` from ``INS<ik>_BORESIGHT_LINE`` /
  ``_SAMPLE``.  Where the keywords do not carry it either (ALE ran without the
  instrument kernel), the ISD is refused saying so.
- **Lunar Orbiter radial terms**: ALE's ``LoHighCamera`` driver puts the perspective
  factors and the point of symmetry into ``optical_distortion.lunarorbiter`` and leaves
  the radial terms ``k0, k1`` in ``naif_keywords`` (``INS<ik>_OD_K``, e.g.
  ``INS-533001_OD_K``); they are read from there.

References: DOI-USGS/usgscsm ``src/Utilities.cpp`` (getters above, ``metric_conversion``)
and ``src/UsgsAstro*SensorModel.cpp`` (``constructStateFromIsd``); DOI-USGS/ale
``ale/formatters/formatter.py`` (``to_isd``) and ``ale/drivers/lo_drivers.py``; ISIS
``TgoCassisCamera.cpp``.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

import numpy as np

from demtool.errors import InputError

#: Set by :func:`normalise_isd` on an ISD of usgscsm's older layout: its nodes are
#: equally spaced already and are kept as they are.
EQUAL_STEP_KEY = "_demtool_equal_step_nodes"
_LEGACY = ("sensor_position", "sensor_orientation")


def normalise_isd(isd: Mapping, source: Any = "<ISD>") -> dict:
    """A copy of ``isd`` in ALE's current layout (see the module docstring); the input
    is not modified.  Idempotent."""
    isd = dict(isd)
    if any(k in isd for k in _LEGACY) and "instrument_position" not in isd:
        isd = _from_legacy(isd, source)
    for key in ("detector_line_summing", "detector_sample_summing"):
        value = isd.get(key)
        if isinstance(value, (int, float)) and not isinstance(value, bool) and value == 0:
            isd[key] = 1
    keywords = isd.get("naif_keywords") if isinstance(isd.get("naif_keywords"), Mapping) \
        else {}
    focal = isd.get("focal_length_model")
    if isinstance(focal, Mapping) and "focal_length" in focal and focal["focal_length"] is None:
        value = _instrument_keyword(isd, keywords, "FOCAL_LENGTH")
        if value is None:
            raise InputError(f"{source}: key 'focal_length_model.focal_length' = None: not a "
                             "number, and naif_keywords holds no INS<code>_FOCAL_LENGTH to "
                             "fill it: ALE wrote this "
                             "ISD without the instrument kernel (e.g. from an ISIS label "
                             "before spiceinit); make it again with the kernels "
                             "(isd_generate)")
        isd["focal_length_model"] = {**focal, "focal_length": value}
    center = isd.get("detector_center")
    if isinstance(center, Mapping) and any(center.get(k, 0) is None for k in ("line", "sample")):
        new = dict(center)
        for key in ("line", "sample"):
            if new.get(key) is None:
                value = _instrument_keyword(isd, keywords, f"BORESIGHT_{key.upper()}")
                if value is None:
                    raise InputError(
                        f"{source}: key 'detector_center.{key}' = None: not a number, and "
                        f"naif_keywords holds no INS<code>_BORESIGHT_{key.upper()} to fill "
                        "it: ALE wrote this ISD "
                        "without the instrument kernel; make it again with the kernels "
                        "(isd_generate)")
                new[key] = value
        isd["detector_center"] = new
    block = isd.get("optical_distortion")
    if isinstance(block, Mapping) and isinstance(block.get("lunarorbiter"), Mapping):
        params = block["lunarorbiter"]
        if not any(k in params for k in ("odk", "coefficients")):
            terms = _instrument_keyword(isd, keywords, "OD_K", scalar=False)
            if terms is not None:
                isd["optical_distortion"] = {"lunarorbiter": {**params, "odk": terms}}
    return isd


def _instrument_keyword(isd: Mapping, keywords: Mapping, name: str, *, scalar: bool = True):
    """``INS<ik>_<name>`` of ``naif_keywords``: the one instrument code that has it (the
    code whose ``ITRANSS`` equals ``focal2pixel_samples`` when several do), or None."""
    found = {}
    for key, value in keywords.items():
        m = re.fullmatch(r"INS(-?\d+)_" + re.escape(name), str(key))
        if m:
            found[m.group(1)] = value
    if len(found) > 1:
        samples = isd.get("focal2pixel_samples")
        same = [code for code in found
                if _close(keywords.get(f"INS{code}_ITRANSS"), samples)]
        found = {code: found[code] for code in same} if len(same) == 1 else {}
    if len(found) != 1:
        return None
    value = next(iter(found.values()))
    if scalar:
        if isinstance(value, (list, tuple)):
            value = value[0] if len(value) == 1 else None
        return value if isinstance(value, (int, float)) and not isinstance(value, bool) \
            else None
    return list(value) if isinstance(value, (list, tuple)) else [value]


def _close(a, b) -> bool:
    try:
        return bool(np.allclose(np.asarray(a, dtype=float), np.asarray(b, dtype=float)))
    except (TypeError, ValueError):
        return False


def _from_legacy(isd: dict, source) -> dict:
    """ALE's blocks from usgscsm's older ``sensor_position`` / ``sensor_orientation``."""
    for key in _LEGACY:
        if not isinstance(isd.get(key), Mapping):
            raise InputError(f"{source}: ISD of usgscsm's older layout lacks the key '{key}' "
                             "(it has the other of sensor_position / sensor_orientation)")
    center = isd.get("center_ephemeris_time", 0.0)
    if not isinstance(center, (int, float)) or isinstance(center, bool):
        raise InputError(f"{source}: ISD key 'center_ephemeris_time' is {center!r}, "
                         "expected a number")
    frame = isd.get("name_model") == "USGS_ASTRO_FRAME_SENSOR_MODEL"
    position = isd["sensor_position"]
    positions = position.get("positions")
    quaternions = isd["sensor_orientation"].get("quaternions")
    if not isinstance(positions, list) or not positions:
        raise InputError(f"{source}: ISD key 'sensor_position.positions' is missing or empty")
    if not isinstance(quaternions, list) or not quaternions:
        raise InputError(f"{source}: ISD key 'sensor_orientation.quaternions' is missing or "
                         "empty")
    n_pos, n_quat = len(positions), len(quaternions)

    def step(t0_key: str, dt_key: str, n: int) -> tuple[float, float]:
        if frame or n == 1:
            return 0.0, 1.0
        t0, dt = isd.get(t0_key), isd.get(dt_key)
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (t0, dt)):
            raise InputError(f"{source}: ISD of usgscsm's older layout lacks '{t0_key}' / "
                             f"'{dt_key}' (the times of its {n} samples)")
        return float(t0), float(dt)

    t0_pos, dt_pos = step("t0_ephemeris", "dt_ephemeris", n_pos)
    t0_quat, dt_quat = step("t0_quaternion", "dt_quaternion", n_quat)
    if frame:
        positions, quaternions = positions[:1], quaternions[:1]
        n_pos = n_quat = 1
    unit = position.get("unit", "m")
    pos_times = [center + t0_pos + i * dt_pos for i in range(n_pos)]
    quat_times = [center + t0_quat + i * dt_quat for i in range(n_quat)]
    out = {k: v for k, v in isd.items() if k not in _LEGACY}
    out["instrument_position"] = {"ephemeris_times": pos_times, "positions": positions,
                                  "unit": unit, "reference_frame": 1}
    velocities = position.get("velocities")
    if isinstance(velocities, list) and len(velocities) >= n_pos:
        out["instrument_position"]["velocities"] = velocities[:n_pos]
    pointing = []
    for q in quaternions:  # sensor → body (x, y, z, w)  →  J2000(=body) → sensor (w, x, y, z)
        try:
            x, y, z, w = (q[i] for i in range(4))
        except (TypeError, IndexError, KeyError):
            raise InputError(f"{source}: ISD key 'sensor_orientation.quaternions' has a row "
                             f"{q!r}, expected 4 numbers (x, y, z, w)") from None
        pointing.append([w, -x if _num(x) else x, -y if _num(y) else y,
                         -z if _num(z) else z])
    out["instrument_pointing"] = {"ephemeris_times": quat_times, "quaternions": pointing,
                                  "reference_frame": 1}
    body_times = sorted(set(quat_times) | {pos_times[0], pos_times[-1]})
    out["body_rotation"] = {"ephemeris_times": body_times,
                            "quaternions": [[1.0, 0.0, 0.0, 0.0]] * len(body_times),
                            "reference_frame": 1}
    sun = isd.get("sun_position")
    if isinstance(sun, Mapping) and isinstance(sun.get("positions"), list) \
            and "ephemeris_times" not in sun:
        n_sun = len(sun["positions"])
        dt_sun = dt_pos * n_pos / n_sun if n_sun else dt_pos
        times = ([center] if n_sun == 1 or frame
                 else [center + t0_pos + i * dt_sun for i in range(n_sun)])
        out["sun_position"] = {**sun, "ephemeris_times": times,
                               "positions": sun["positions"][:len(times)],
                               "unit": sun.get("unit", "m")}
        if isinstance(sun.get("velocities"), list):
            out["sun_position"]["velocities"] = sun["velocities"][:len(times)]
    if not frame and n_pos > 1:
        out[EQUAL_STEP_KEY] = True
    return out


def _num(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)
