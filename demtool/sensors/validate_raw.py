"""The *raw* stage of sensor-model validation (:mod:`demtool.sensors.validate`): an ISD's
or a cube label's own values, checked before a model is built from them, where building
would crash (a string for ``image_lines``, a ``BetaSamples`` of 0) or silently repair them
(a zero quaternion normalised to NaN, a sheared ``constant_rotation`` multiplied in).

References: usgscsm ``UsgsAstroLsSensorModel`` / ``UsgsAstroFrameSensorModel``
(``constructStateFromIsd``: the same keys); ISIS ``AlphaCube`` (``BetaSamples`` divides).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from numbers import Real
from pathlib import Path
from typing import Any

import numpy as np

from demtool.errors import InputError
from demtool.sensors.validate import (
    LINESCAN_MODEL,
    _fail,
    _increasing,
    _number,
    _numbers,
    check_focal_plane_map,
    check_quaternions,
    check_radii_of_body,
    check_rotation,
)


def _block(isd: Mapping, key: str) -> Mapping | None:
    block = isd.get(key)
    return block if isinstance(block, Mapping) else None


def check_isd(isd: Mapping, source: Any) -> dict:
    """Check the values of a parsed ALE ISD before a model is built from it.

    Missing keys and shapes are left to the reader (:func:`demtool.sensors.isd.
    sensor_from_isd` names them); here: the image size a positive whole number; the
    radii, focal length, detector centre and summing finite (and positive where a
    length); ``focal2pixel`` invertible; quaternions of unit norm; constant rotations
    proper rotations; ephemeris times strictly increasing; a line scan's line times
    finite and running forwards (positive seconds per line).  A line scan with one
    position state is extended with its velocity over the image (see the module
    docstring), or refused without one.

    Returns
    -------
    dict
        The ISD (a shallow copy with a two-state ``instrument_position`` for a one-state
        line scan).

    Raises
    ------
    InputError
        One line: the file, the key and the value.
    """
    isd = dict(isd)
    for key in ("image_lines", "image_samples"):
        if key in isd:
            _number(source, key, isd[key], positive=True, integer=True)
    radii = _block(isd, "radii")
    if radii is not None:
        for key in ("semimajor", "semiminor"):
            if key in radii:
                _number(source, f"radii.{key}", radii[key], positive=True)
    focal_block = _block(isd, "focal_length_model")
    if focal_block is not None and "focal_length" in focal_block:
        _number(source, "focal_length_model.focal_length", focal_block["focal_length"],
                positive=True)
    center = _block(isd, "detector_center")
    if center is not None:
        for key in ("line", "sample"):
            if key in center:
                _number(source, f"detector_center.{key}", center[key])
    for key in ("starting_detector_line", "starting_detector_sample", "center_ephemeris_time"):
        if key in isd:
            _number(source, key, isd[key])
    for key in ("detector_line_summing", "detector_sample_summing"):
        if key in isd:  # (a summing mode of 0 is read as 1: demtool.sensors.isd_forms)
            _number(source, key, isd[key], positive=True)
    if "focal2pixel_samples" in isd and "focal2pixel_lines" in isd:
        s = _numbers(source, "focal2pixel_samples", isd["focal2pixel_samples"], 3)
        ln = _numbers(source, "focal2pixel_lines", isd["focal2pixel_lines"], 3)
        check_focal_plane_map(s, ln, source, "focal2pixel_samples/focal2pixel_lines")
    for name in ("instrument_pointing", "body_rotation", "sensor_orientation"):
        block = _block(isd, name)
        if block is None:
            continue
        if "quaternions" in block:
            q = _numbers(source, f"{name}.quaternions", block["quaternions"])
            if q.size and q.size % 4 == 0:
                check_quaternions(q, source, f"{name}.quaternions")
        if "constant_rotation" in block:
            m = _numbers(source, f"{name}.constant_rotation", block["constant_rotation"], 9)
            check_rotation(m, source, f"{name}.constant_rotation")
        if "ephemeris_times" in block:
            _increasing(_numbers(source, f"{name}.ephemeris_times", block["ephemeris_times"]),
                        source, f"{name}.ephemeris_times")
    for name in ("instrument_position", "sun_position", "sensor_position"):
        block = _block(isd, name)
        if block is None:
            continue
        for key in ("positions", "velocities"):
            if key in block:
                _numbers(source, f"{name}.{key}", block[key])
        if "ephemeris_times" in block:
            _increasing(_numbers(source, f"{name}.ephemeris_times", block["ephemeris_times"]),
                        source, f"{name}.ephemeris_times")
    if isd.get("name_model") == LINESCAN_MODEL and "line_scan_rate" in isd:
        rate = _numbers(source, "line_scan_rate", isd["line_scan_rate"])
        if rate.size and rate.size % 3 == 0:
            rate = rate.reshape(-1, 3)
            bad = rate[:, 2] == 0
            if np.any(bad):
                raise _fail(source, "line_scan_rate", rate[bad][0],
                            "seconds per line must be positive (zero: the lines all at once)")
            if np.any(rate[:, 2] < 0):
                _check_backward_lines(isd, rate, source)
            order = np.argsort(rate[:, 0])
            _increasing(rate[order, 0], source, "line_scan_rate (lines)")
            _increasing(rate[order, 1], source, "line_scan_rate (start times)")
            isd = _extend_one_state(isd, rate, source)
    check_radii_of_body(_isd_radii_m(isd), _isd_naif_body(isd), source, "radii")
    return isd


def _check_backward_lines(isd: Mapping, rate: np.ndarray, source) -> None:
    """A negative time per line is usgscsm's: the time of line ``l`` is ``t_i + dt_i (l −
    l_i + 0.5)`` whatever the sign (Apollo's panoramic camera scans backwards in time:
    ALE writes its start 2 s *after* the centre time).  It is refused when the lines it
    times cannot be the image's: ALE's ``center_ephemeris_time`` is the middle of the
    image's time span, so it must lie within the lines' times, and at least one line
    must lie within the sampled ephemeris (one median spacing beyond its ends; lines
    partly outside are masked by the model, :mod:`demtool.sensors.coverage`)."""
    if "image_lines" not in isd:
        return
    order = np.argsort(rate[:, 0])
    rate = rate[order]
    lines = np.array([0.5, float(isd["image_lines"]) - 0.5])
    i = np.clip(np.searchsorted(rate[:, 0], lines, side="right") - 1, 0, len(rate) - 1)
    line_times = rate[i, 1] + rate[i, 2] * (lines - rate[i, 0] + 0.5)  # from the centre
    lo, hi = float(line_times.min()), float(line_times.max())
    step = float(np.max(np.abs(rate[:, 2])))
    if not lo - step <= 0.0 <= hi + step:
        raise _fail(source, "line_scan_rate", rate[rate[:, 2] < 0][0],
                    "seconds per line must be positive, or negative with the lines running "
                    f"backwards through the centre time: these lines run from {hi:.6g} s "
                    f"back to {lo:.6g} s, not through center_ephemeris_time (0 s)")
    block = _block(isd, "instrument_position")
    times = None if block is None else block.get("ephemeris_times")
    if not isinstance(times, list) or len(times) < 2:
        return
    t = np.asarray(times, dtype=np.float64) - float(isd.get("center_ephemeris_time", 0.0))
    margin = float(np.median(np.diff(t)))
    if hi < t[0] - margin or lo > t[-1] + margin:
        raise _fail(source, "line_scan_rate", rate[rate[:, 2] < 0][0],
                    "seconds per line must be positive, or negative with lines inside the "
                    f"ephemeris: these lines run backwards in time over {lo:.6g} … "
                    f"{hi:.6g} s, outside the positions' {t[0]:.6g} … {t[-1]:.6g} s")


def _isd_radii_m(isd: Mapping) -> tuple[float, float] | None:
    radii = _block(isd, "radii")
    if radii is None:
        return None
    scale = {"m": 1.0, "km": 1000.0}.get(str(radii.get("unit", "km")).lower())
    try:
        return float(radii["semimajor"]) * scale, float(radii["semiminor"]) * scale
    except (KeyError, TypeError, ValueError):
        return None


def _isd_naif_body(isd: Mapping) -> tuple[int, tuple[float, ...] | None] | None:
    """The NAIF id of the target an ISD's ``naif_keywords`` name, and its radii (km)
    when the keywords give them."""
    keywords = _block(isd, "naif_keywords") or {}
    ids = {int(m.group(1)) for k in keywords
           if (m := re.fullmatch(r"BODY(\d+)_(RADII|PM|POLE_RA|POLE_DEC|NUT_PREC_.*)", k))}
    code = keywords.get("BODY_CODE")
    if isinstance(code, Real) and not isinstance(code, bool) and code > 0:
        ids.add(int(code))
    if len(ids) != 1:
        return None
    naif = ids.pop()
    given = keywords.get(f"BODY{naif}_RADII")
    try:
        radii = tuple(float(v) for v in given) if given is not None else None
    except (TypeError, ValueError):
        radii = None
    return naif, radii


def _extend_one_state(isd: dict, rate: np.ndarray, source) -> dict:
    """Two position states over the image from one state and its velocity."""
    block = _block(isd, "instrument_position")
    if block is None or not isinstance(block.get("positions"), list) \
            or len(block["positions"]) != 1:
        return isd
    velocities = block.get("velocities")
    v = None if velocities is None else np.asarray(velocities, dtype=np.float64).reshape(-1)
    if v is None or v.size != 3 or not np.any(v != 0):
        raise InputError(f"{source}: key 'instrument_position' has one state and no velocity: "
                         "a line scan needs the sensor's motion over its lines (give the "
                         "ephemeris over the image, e.g. isd_generate)")
    times = block.get("ephemeris_times")
    p = np.asarray(block["positions"], dtype=np.float64).reshape(3)
    t_state = float(np.asarray(times, dtype=np.float64).reshape(-1)[0])
    lines = float(isd.get("image_lines", 1))
    center = float(isd.get("center_ephemeris_time", t_state))
    order = np.argsort(rate[:, 0])
    rate = rate[order]

    def line_time(line: float) -> float:
        i = int(np.clip(np.searchsorted(rate[:, 0], line, side="right") - 1, 0, len(rate) - 1))
        return center + rate[i, 1] + rate[i, 2] * (line - rate[i, 0] + 0.5)

    first, last = line_time(0.5), line_time(lines + 0.5)
    span = max(last - first, 1e-6)
    t0, t1 = min(first, t_state) - 0.05 * span, max(last, t_state) + 0.05 * span
    new = dict(block)
    new["ephemeris_times"] = [t0, t1]
    new["positions"] = [(p + v * (t0 - t_state)).tolist(), (p + v * (t1 - t_state)).tolist()]
    new["velocities"] = [v.tolist(), v.tolist()]
    isd["instrument_position"] = new
    return isd


#: bytes of a cube read for its label (ISIS labels are a few KiB; the reader's own
#: fallback is 64 KiB).
LABEL_BYTES = 1 << 20


def check_cube_label(path: str | Path) -> None:
    """Check the values of an ISIS cube's label that the reader divides by or casts.

    The image size (``Core/Dimensions`` ``Samples``, ``Lines``) positive whole numbers;
    ``AlphaCube`` ``BetaSamples``/``BetaLines`` positive and its window finite; every
    ``NaifKeywords`` value the model uses (``INS<code>_FOCAL_LENGTH`` positive,
    ``_ITRANSS``/``_ITRANSL`` invertible, ``BODY<id>_RADII`` positive) finite, and the
    radii those of the body ``<id>``.  A label without ``Object = IsisCube`` holding a
    ``Core`` is refused here in one line.
    """
    import warnings

    p = Path(path)
    try:
        with open(p, "rb") as handle:
            head = handle.read(LABEL_BYTES)
    except OSError as exc:
        raise InputError(f"{p}: cannot read cube ({exc.strerror or exc})") from None
    end = head.find(b"\nEnd\n")
    if end < 0:
        end = head.find(b"\nEnd\r\n")
    text = head[: end + 5 if end >= 0 else 65536].decode("latin-1")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ImportWarning)
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        import pvl

        try:
            label = pvl.loads(text)
        except Exception as exc:  # pvl raises several parser errors
            detail = str(exc).splitlines()[0] if str(exc) else "it ends early"
            raise InputError(f"{p}: cannot parse the ISIS label ({detail}): a truncated label "
                             "or not an ISIS3 cube") from None
    cube = label.get("IsisCube") if hasattr(label, "get") else None
    if not hasattr(cube, "get") or not hasattr(cube.get("Core"), "get"):
        raise InputError(f"{p}: the label's 'Object = IsisCube' has no 'Core' object: not an "
                         "ISIS3 cube (only its first line?)")
    dims = cube["Core"].get("Dimensions")
    if not hasattr(dims, "get"):
        raise InputError(f"{p}: the cube label lacks the key 'Core/Dimensions'")
    for key in ("Samples", "Lines"):
        if key in dims:
            _number(p, f"Dimensions/{key}", dims[key], positive=True, integer=True)
    alpha = cube.get("AlphaCube")
    if hasattr(alpha, "get"):
        for key in ("BetaSamples", "BetaLines", "AlphaSamples", "AlphaLines"):
            if key in alpha:
                _number(p, f"AlphaCube/{key}", alpha[key], positive=True)
        for key in ("AlphaStartingSample", "AlphaStartingLine", "AlphaEndingSample",
                    "AlphaEndingLine"):
            if key in alpha:
                _number(p, f"AlphaCube/{key}", alpha[key])
    naif = label.get("NaifKeywords")
    kernels = cube.get("Kernels")
    if not hasattr(naif, "get") or not hasattr(kernels, "get"):
        return  # the reader says the SPICE is not attached
    code = kernels.get("NaifFrameCode")
    ins = f"INS{code}"
    if f"{ins}_FOCAL_LENGTH" in naif:
        _number(p, f"NaifKeywords/{ins}_FOCAL_LENGTH",
                _scalar(naif[f"{ins}_FOCAL_LENGTH"]), positive=True)
    if f"{ins}_ITRANSS" in naif and f"{ins}_ITRANSL" in naif:
        s = _numbers(p, f"NaifKeywords/{ins}_ITRANSS", _listed(naif[f"{ins}_ITRANSS"]), 3)
        ln = _numbers(p, f"NaifKeywords/{ins}_ITRANSL", _listed(naif[f"{ins}_ITRANSL"]), 3)
        check_focal_plane_map(s, ln, p, f"NaifKeywords/{ins}_ITRANSS/_ITRANSL")
    for key in list(naif.keys()):
        m = re.fullmatch(r"BODY(-?\d+)_RADII", str(key))
        if m is None:
            continue
        radii = _numbers(p, f"NaifKeywords/{key}", _listed(naif[key]), 3)
        if np.any(radii <= 0):
            raise _fail(p, f"NaifKeywords/{key}", radii, "radii must be positive")
        check_radii_of_body((radii[0] * 1000.0, radii[2] * 1000.0), (int(m.group(1)), None),
                            p, f"NaifKeywords/{key}")


def _listed(value) -> list:
    if isinstance(value, (list, tuple)):
        return list(value)
    return [value]


def _scalar(value):
    if isinstance(value, (list, tuple)) and len(value) == 1:
        return value[0]
    return value
