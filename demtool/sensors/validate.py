"""One validation of every sensor model as it is read: is it a camera that can image the body?

Readers check keys and shapes; the checks here check *values*, once, for every kind
(ALE ISD frame and line scan, ISIS cubes, ASP ``.tsai``, pinholes of ``cameras.npz`` /
``bundle.npz``), called from the one entry point :func:`demtool.sensors.read_sensors`.
Every failure raises :class:`~demtool.errors.InputError` with one line naming the file,
the key and the value.

Two stages:

- **raw** (:mod:`demtool.sensors.validate_raw`: ``check_isd``, ``check_cube_label``): the
  file's own values before a
  model is built from them, where building would crash (a string for ``image_lines``, a
  ``BetaSamples`` of 0) or silently repair them (a zero quaternion normalised to NaN, a
  sheared ``constant_rotation`` multiplied in);
- **model** (:func:`check_model`): the built model's geometry — finite positive focal
  length and pixel pitch, an invertible focal-plane map (``focal2pixel``), rotations
  that are rotations (orthonormal, determinant +1), finite positions and sun, the body's
  radii positive, the camera not deeper than the body's lowest surface (positions
  labelled metres but written in km put it 1000× too close to the centre; a rover below
  the datum is a *surface camera*, read and named so in a note), and what it sees of
  the body on a dense ray grid (a limb image passes with the fraction in a note; a camera
  that sees no surface is refused only where the caller needs ground,
  ``require_surface``).  These checks refuse only the impossible:
  :mod:`demtool.sensors.body_view` gives the relief of each body and the rules.

The body named by the file (an ISD's ``naif_keywords``, a cube's ``BODY<id>_RADII``)
must have the radii the file gives (:func:`check_radii_of_body`), and a body named on
the command line must match the model's radii (:func:`check_named_body`).

A line-scan ISD with one ephemeris state is extended over its image time with the
state's velocity (usgscsm extrapolates one state the same way only for the sun); with
no velocity it is refused (a stationary pushbroom images one line).

References: usgscsm ``UsgsAstroLsSensorModel`` / ``UsgsAstroFrameSensorModel``
(``constructStateFromIsd``: the same keys); ISIS ``AlphaCube`` (``BetaSamples`` divides);
VisionWorkbench ``PinholeModel`` (``fu fv pitch R C``).
"""

from __future__ import annotations

import math
from numbers import Real
from typing import Any

import numpy as np

from demtool.errors import InputError

#: |‖q‖ − 1| beyond this and a quaternion is not an attitude (ALE writes ≤ 1e-8).
QUATERNION_NORM_TOL = 1e-3
#: max |M Mᵀ − I| of a matrix accepted as a rotation (SPICE frame kernels: ~1e-15).
ORTHONORMAL_TOL = 1e-5
#: relative difference of a file's radii from its named body's accepted (IAU radii
#: differ between kernel generations by far less: Moon 1737.4 vs 1737.15 km, 0.015 %).
BODY_RADIUS_RTOL = 0.02

FRAME_MODEL = "USGS_ASTRO_FRAME_SENSOR_MODEL"
LINESCAN_MODEL = "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL"


def _fmt(value: Any) -> str:
    """A value as it appears in a message: short, repr for strings."""
    if isinstance(value, str):
        return repr(value if len(value) <= 40 else value[:37] + "...")
    if isinstance(value, np.ndarray):
        return np.array2string(value.ravel()[:9], precision=6, separator=", ")
    if isinstance(value, float):
        return f"{value:.10g}"
    return repr(value)


def _fail(source: Any, key: str, value: Any, problem: str) -> InputError:
    return InputError(f"{source}: key '{key}' = {_fmt(value)}: {problem}")


# ---------------------------------------------------------------------------------------
# numbers
# ---------------------------------------------------------------------------------------


def _number(source, key: str, value, *, positive: bool = False, integer: bool = False
            ) -> float:
    """A finite number from a parsed file (bools, strings and nulls refused)."""
    if isinstance(value, bool) or not isinstance(value, Real):
        raise _fail(source, key, value, "not a number")
    number = float(value)
    if not math.isfinite(number):
        raise _fail(source, key, value, "not a finite number")
    if integer and number != int(number):
        raise _fail(source, key, value, "not a whole number")
    if positive and number <= 0:
        raise _fail(source, key, value, "must be positive")
    return number


def _numbers(source, key: str, value, size: int | None = None) -> np.ndarray:
    try:
        flat = [] if not isinstance(value, (list, tuple)) else list(_flatten(value))
        ok = isinstance(value, (list, tuple)) and all(
            isinstance(v, Real) and not isinstance(v, bool) for v in flat)
        arr = np.asarray(value, dtype=np.float64) if ok else None
    except (TypeError, ValueError):
        arr = None
    if arr is None:
        raise _fail(source, key, str(value)[:40] if isinstance(value, (list, tuple)) else value,
                    "not a list of numbers")
    if size is not None and arr.size != size:
        raise _fail(source, key, arr, f"has {arr.size} values, expected {size}")
    if not np.all(np.isfinite(arr)):
        raise _fail(source, key, arr, "has non-finite values")
    return arr


def _flatten(value):
    for item in value:
        if isinstance(item, (list, tuple)):
            yield from _flatten(item)
        else:
            yield item


def check_rotation(matrix, source, key: str) -> np.ndarray:
    """Refuse a 3×3 matrix that is not a proper rotation (orthonormal, det +1)."""
    m = np.asarray(matrix, dtype=np.float64).reshape(3, 3)
    if not np.all(np.isfinite(m)):
        raise _fail(source, key, m, "has non-finite values")
    error = float(np.max(np.abs(m @ m.T - np.eye(3))))
    if error > ORTHONORMAL_TOL:
        raise _fail(source, key, m, f"is not a rotation (|M Mᵀ − I| = {error:.3g}: "
                    "sheared or scaled)")
    det = float(np.linalg.det(m))
    if det < 0:
        raise _fail(source, key, m, f"is a reflection (determinant {det:.6g}), not a "
                    "rotation: the image would be mirrored")
    return m


def check_quaternions(q, source, key: str) -> None:
    """Refuse quaternions (n, 4) of zero or non-unit norm (any component order)."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, 4)
    norms = np.linalg.norm(q, axis=1)
    if not np.all(np.isfinite(norms)):
        raise _fail(source, key, q[~np.isfinite(norms)][0], "has non-finite values")
    worst = int(np.argmax(np.abs(norms - 1.0)))
    if norms[worst] == 0:
        raise _fail(source, key, q[worst], f"row {worst} is all zero: not an attitude")
    if abs(norms[worst] - 1.0) > QUATERNION_NORM_TOL:
        raise _fail(source, key, q[worst], f"row {worst} has norm {norms[worst]:.6g}, not 1 "
                    f"(tolerance {QUATERNION_NORM_TOL:g}): not an attitude")


def check_focal_plane_map(samples, lines, source, key: str) -> None:
    """Refuse a focal-plane → pixel affine (``focal2pixel``) that cannot be inverted."""
    s = np.asarray(samples, dtype=np.float64)
    ln = np.asarray(lines, dtype=np.float64)
    det = ln[1] * s[2] - ln[2] * s[1]
    scale = max(np.hypot(ln[1], ln[2]) * np.hypot(s[1], s[2]), np.finfo(float).tiny)
    if not np.isfinite(det) or abs(det) <= 1e-9 * scale or scale <= np.finfo(float).tiny:
        raise InputError(f"{source}: keys '{key}' (samples {_fmt(s)}, lines {_fmt(ln)}) are "
                         f"not invertible (determinant {det:.3g}): pixels cannot be mapped "
                         "to the focal plane")


def _increasing(times, source, key: str) -> None:
    t = np.asarray(times, dtype=np.float64)
    if len(t) > 1 and np.any(np.diff(t) <= 0):
        i = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise _fail(source, key, t[i:i + 2], f"not strictly increasing (entry {i + 1} of "
                    f"{len(t)})")


# ---------------------------------------------------------------------------------------
# ALE ISD (raw)
# ---------------------------------------------------------------------------------------


def check_radii_of_body(radii_m, named, source, key: str) -> None:
    """Refuse radii (metres) that are not those of the body the file names.

    ``named`` is ``(naif_id, radii_km or None)``: radii the file's keywords give for that
    body are compared first, else PROJ's radii of a known body; unknown bodies pass.
    """
    if radii_m is None or named is None:
        return
    naif, keyword_radii = named
    a = radii_m[0]
    if keyword_radii:
        expected = float(keyword_radii[0]) * 1000.0
        what = f"BODY{naif}_RADII"
    else:
        from demtool.maps import body_by_naif_id

        try:
            body = body_by_naif_id(naif)
        except KeyError:
            return
        expected = body.a
        what = f"{body.name} (NAIF {naif})"
    if expected > 0 and abs(a - expected) > BODY_RADIUS_RTOL * expected:
        raise InputError(f"{source}: key '{key}' gives a semi-major axis of {a / 1e3:.6g} km, "
                         f"but the file is of {what}, {expected / 1e3:.6g} km: radii of "
                         "another body")


# ---------------------------------------------------------------------------------------
# ISIS cube label (raw)
# ---------------------------------------------------------------------------------------


# ---------------------------------------------------------------------------------------
# The built model
# ---------------------------------------------------------------------------------------

#: per reader, the file keys behind the model's quantities (for the messages).
KEYS = {
    "isd": {"focal": "focal_length_model.focal_length",
            "detector": "focal2pixel_samples/focal2pixel_lines",
            "rotation": "instrument_pointing (with body_rotation)",
            "position": "instrument_position.positions", "radii": "radii",
            "sun": "sun_position.positions"},
    "cube": {"focal": "NaifKeywords/INS<code>_FOCAL_LENGTH",
             "detector": "NaifKeywords/INS<code>_ITRANSS/_ITRANSL",
             "rotation": "table InstrumentPointing (with BodyRotation)",
             "position": "table InstrumentPosition", "radii": "NaifKeywords/BODY<id>_RADII",
             "sun": "table SunPosition"},
    "tsai": {"focal": "fu/fv", "detector": "pitch", "rotation": "R", "position": "C",
             "radii": "--body", "sun": "sun"},
    "npz": {"focal": "K", "detector": "K", "rotation": "R", "position": "t", "radii": "radii",
            "sun": "sun"},
}
for _side in ("left", "right"):  # the models a calibrated rectify.npz stores
    _p = f"sensor_{_side}_"
    KEYS[f"rectify_{_side}"] = {
        "focal": _p + "focal_length", "detector": _p + "itrans_sample/" + _p + "itrans_line",
        "rotation": _p + "rotation", "position": _p + "position", "radii": _p + "radii",
        "sun": _p + "sun"}


def check_model(model, source: Any, reader: str = "isd", *, require_surface: bool = True):
    """Check a built sensor model's geometry; returns the model (with ``notes`` added).

    Parameters
    ----------
    model : SensorModel
        Frame, line-scan, pinhole or ``.tsai`` model (other kinds get the generic checks:
        radii, camera outside the body, boresight).
    source : path-like or str
        The file, for the messages.
    reader : {"isd", "cube", "tsai", "npz", "rectify_left", "rectify_right"}
        Which file keys to name (:data:`KEYS`).
    require_surface : bool
        Refuse a camera that sees no surface of its body (stages that need ground);
        False keeps it with a note (``demtool camera`` reports it).

    Raises
    ------
    InputError
        One line naming the file, the key and the value.
    """
    from demtool.sensors.frame import FrameSensor
    from demtool.sensors.linescan import LineScanSensor
    from demtool.sensors.pinhole import PinholeCamera

    keys = KEYS.get(reader, KEYS["isd"])
    if isinstance(model, PinholeCamera):
        _check_pinhole(model, source, keys)
    if isinstance(model, (FrameSensor, LineScanSensor)):
        _number(source, keys["focal"], model.focal_length, positive=True)
        d = model.detector
        check_focal_plane_map(d.itrans_sample, d.itrans_line, source, keys["detector"])
        for label, value in (("detector centre", (d.center_line, d.center_sample)),
                             ("detector start", (d.start_line, d.start_sample))):
            if not np.all(np.isfinite(value)):
                raise _fail(source, keys["detector"], np.asarray(value),
                            f"{label} is not finite")
        if not (d.line_summing > 0 and d.sample_summing > 0):
            raise _fail(source, keys["detector"], np.array([d.line_summing, d.sample_summing]),
                        "summing (or AlphaCube scale) must be positive")
        _check_distortion_inverts(model, source)
    if isinstance(model, FrameSensor):
        check_rotation(model.rotation, source, keys["rotation"])
        _finite(model.position, source, keys["position"])
        _finite(model.sun, source, keys["sun"])
    if isinstance(model, LineScanSensor):
        check_quaternions(model.quaternions, source, keys["rotation"])
        _finite(model.positions, source, keys["position"])
        _finite(model.sun_positions, source, keys["sun"])
        if not np.all(np.isfinite(model.int_times) & (model.int_times != 0)):
            raise _fail(source, "line_scan_rate", model.int_times,
                        "seconds per line must be finite and not zero")
        if len(model.positions) == 1 and model.lines > 1:
            raise _fail(source, keys["position"], model.positions[0],
                        "one position state for a line scan: its motion over the lines is "
                        "unknown")
    if getattr(model, "radii", None) is not None:
        _check_on_body(model, source, keys, require_surface)
    return model


#: distorted → undistorted → distorted → undistorted must come back within this many
#: pixels: a lens model that cannot be inverted over the image gives rays that ground →
#: image does not return to.
DISTORTION_CLOSURE_PX = 0.01


def _check_distortion_inverts(model, source) -> None:
    """Refuse a lens distortion that its own inverse does not undo over the image (e.g. a
    ``transverse`` polynomial mapping distorted x and y both to undistorted x: singular;
    usgscsm gives up on it and returns the point unchanged)."""
    dist = model.distortion
    if dist is None or dist.is_identity:
        return
    lines, samples = int(model.lines), int(model.samples)
    ll, ss = np.meshgrid(np.linspace(0.5, max(lines - 0.5, 0.5), 9),
                         np.linspace(0.5, max(samples - 0.5, 0.5), 9), indexing="ij")
    detector_line = model._detector_line(ll) if hasattr(model, "_detector_line") else ll
    with np.errstate(all="ignore"):
        x, y = model.detector.to_focal_plane(detector_line, ss)
        u, v = dist.remove(x, y)
        u2, v2 = dist.remove(*dist.apply(u, v))
    d = model.detector
    pitch = 1.0 / max(float(np.hypot(d.itrans_sample[1], d.itrans_sample[2])), 1e-300)
    miss = np.hypot(u2 - u, v2 - v) / pitch
    miss = np.where(np.isfinite(u) & np.isfinite(v), miss, 0.0)  # off the lens: not judged
    worst = float(np.nanmax(np.where(np.isfinite(miss), miss, np.inf)))
    if worst > DISTORTION_CLOSURE_PX:
        i = np.unravel_index(int(np.nanargmax(np.where(np.isfinite(miss), miss, np.inf))),
                             miss.shape)
        raise _fail(source, f"optical_distortion.{dist.model}", dist.coefficients,
                    f"cannot be inverted over the image: undistorting what it distorts misses "
                    f"by {worst:.3g} px at line {ll[i]:.1f}, sample {ss[i]:.1f} (a singular "
                    "or folded lens model)")


def _finite(values, source, key: str) -> None:
    values = np.asarray(values, dtype=np.float64)
    if not np.all(np.isfinite(values)):
        bad = values.reshape(-1, values.shape[-1]) if values.ndim else values.reshape(1, 1)
        row = bad[~np.all(np.isfinite(bad), axis=-1)][0]
        raise _fail(source, key, row, "has non-finite values")


def _check_pinhole(model, source, keys) -> None:
    K = np.asarray(model.K, dtype=np.float64)
    _finite(K, source, keys["focal"])
    for value, what in ((K[0, 0], "fx"), (K[1, 1], "fy")):
        if not value > 0:
            raise _fail(source, keys["focal"], K, f"focal length {what} = {value:.6g} px "
                        "must be positive")
    pitch = getattr(model, "pitch", 1.0)
    _number(source, keys["detector"], pitch, positive=True)
    check_rotation(model.R, source, keys["rotation"])
    _finite(model.t, source, keys["position"])


def _note(model, text: str) -> None:
    notes = list(getattr(model, "notes", []) or [])
    notes.append(text)
    try:
        model.notes = notes
    except (AttributeError, TypeError):  # frozen dataclass pinholes
        object.__setattr__(model, "notes", notes)


def _check_on_body(model, source, keys, require_surface: bool = True) -> None:
    """Radii, the camera not inside the body (against the body's relief: a surface
    camera is named in a note), and what it sees (:mod:`demtool.sensors.body_view`)."""
    from demtool.sensors.body_view import (
        body_view,
        height_above_ellipsoid,
        reference_height,
        relief_band,
    )

    a, b = (float(v) for v in model.radii)
    for value, name in ((a, "semi-major"), (b, "semi-minor")):
        if not (math.isfinite(value) and value > 0):
            raise _fail(source, keys["radii"], np.array([a, b]),
                        f"the {name} axis must be a positive finite length (metres)")
    lines, samples = int(getattr(model, "lines", 0) or 0), int(getattr(model, "samples", 0) or 0)
    if lines <= 0 or samples <= 0:  # a .tsai pinhole without an image size: its centre only
        origin = np.asarray(model.camera_center(np.zeros(1)), dtype=np.float64)
        ray = None
        _finite(origin, source, keys["position"])
    else:
        line_edge = np.array([0.5, 0.5 * lines, lines - 0.5])
        sample_edge = np.array([0.5, 0.5 * samples, samples - 0.5])
        ll, ss = np.meshgrid(line_edge, sample_edge, indexing="ij")
        with np.errstate(all="ignore"):
            ray = model.image_to_ray(ll, ss)
        origin = np.asarray(ray.origin, dtype=np.float64)
        # lines outside a line scan's ephemeris coverage are masked (NaN): judge the others
        finite = np.all(np.isfinite(origin), axis=-1)
        if getattr(model, "coverage", None) is None or not np.any(finite):
            _finite(origin, source, keys["position"])
        origin = origin[finite]
    band = relief_band(a, b)
    height = height_above_ellipsoid(origin, a, b)
    if np.any(height < band.low):
        worst = int(np.argmin(height))
        centre = origin.reshape(-1, 3)[worst]
        distance = float(np.linalg.norm(centre))
        hint = ("a local-frame camera (rover, lander, lab rig)? --body and body radii only "
                "apply to models in the body's body-fixed frame" if distance < 1e-3 * a
                else "positions in km labelled metres?")
        raise _fail(source, keys["position"], centre,
                    f"puts the camera inside the body ({distance / 1e3:.6g} km from its "
                    f"centre, radius {a / 1e3:.6g} km: {-float(height.min()) / 1e3:.6g} km "
                    f"below the reference ellipsoid, deeper than {band.label} allows): "
                    f"{hint}")
    from demtool.sensors.body_view import SURFACE_CLEARANCE_M

    if np.any(height <= band.high + SURFACE_CLEARANCE_M):
        h = float(np.median(height))
        where = f"{abs(h) / 1e3:.3g} km {'below' if h < 0 else 'above'} the reference ellipsoid"
        _note(model, f"a surface camera (rover or lander): {where}, within {band.label}")
        try:
            model.surface_camera = True
        except (AttributeError, TypeError):
            object.__setattr__(model, "surface_camera", True)
    if ray is None:
        return
    direction = np.asarray(ray.direction, dtype=np.float64)
    finite = np.all(np.isfinite(direction), axis=-1) | ~np.all(np.isfinite(ray.origin), axis=-1)
    if not np.all(finite):
        raise _fail(source, keys["rotation"], direction.reshape(-1, 3)[0],
                    "gives non-finite look directions")
    view = body_view(model, height=reference_height(model))
    if view.boresight:
        return
    if view.in_view:
        _note(model, f"the boresight misses the body: a limb image ({view.where})"
              if view.fraction > 0 else view.where)
        return
    if require_surface:
        raise _fail(source, keys["rotation"], direction[1, 1],
                    f"the camera looks away from the body: {view.where} (demtool camera "
                    "reads such a model; this stage needs ground)")
    _note(model, f"the camera sees no surface of the body: {view.where}; stages that need "
          "ground refuse it")


def check_named_body(model, body, source, option: str = "--body") -> None:
    """Refuse a body named on the command line whose radius is not the model's.

    ``body`` is a :class:`demtool.maps.Body`; models without radii (local pinholes,
    ``.tsai``) take the named body and pass.
    """
    radii = getattr(model, "radii", None)
    if body is None or radii is None:
        return
    a = float(radii[0])
    expected = float(body.a)
    if abs(a - expected) > BODY_RADIUS_RTOL * expected:
        raise InputError(f"{source}: its radii ({a / 1e3:.6g} km) are not those of "
                         f"{option} {body.name} ({expected / 1e3:.6g} km): name the body the "
                         f"model is of, or drop {option}")
