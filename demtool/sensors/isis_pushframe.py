"""ISIS push-frame cubes: MRO MARCI (ISIS ``MarciCamera``) and LRO WAC
(``LroWideAngleCamera``, :func:`wac_isd`) as usgscsm push-frame models; the other ISIS
push-frame cameras (THEMIS VIS, JunoCam, MVIC framing) are refused in one line naming
the camera (their ALE ISDs are read instead).

MARCI, as ISIS's ``MarciCamera`` and ``PushFrameCameraDetectorMap`` define it:

- framelets of 16 detector lines, ``h = 16 / SummingMode`` image lines each; parent
  line ``L`` (ISIS, 1-based) lies in framelet ``f = ⌊(L − 0.5) / h⌋ + 1``, exposed at
  ``t0 + (f − o − 1) Δ`` (or, ``DataFlipped``, at ``t0 + (N − f + o) Δ``, ``N =
  ⌊ParentLines / h⌋``), ``t0`` the clock count's ET less ``ExposureDuration / 2000``
  (ISIS reads the value as milliseconds), ``Δ`` = ``InterframeDelay`` and ``o`` the
  filter's framelet offset (NIR 0, RED 1, ORANGE 2, GREEN 3, BLUE 4, LONG_UV 5,
  SHORT_UV 6, times ``ColorOffset``, negated when ``DataFlipped``);
- the detector line of framelet line ``ℓ`` is the filter's first detector row (BLUE
  709, GREEN 734, ORANGE 760, RED 786, NIR 811, LONG_UV 266, SHORT_UV 293) plus
  ``(ℓ − 0.5) · SummingMode + 0.5``, about the detector origin (512.5, 768.5) of the
  VIS camera (−74410) or (512.5, 288.5) of the UV camera (−74420), through
  ``INS-74400_ITRANSS/L``; focal length ``INS<code>_FOCAL_LENGTH``; distortion ISIS's
  ``MarciDistortionMap`` (``INS<code>_DISTORTION_COEFFS`` in pixels of
  ``INS<code>_PIXEL_SIZE``: the ``marci`` model of :mod:`demtool.sensors.distortion_cubes`).

That is usgscsm's push-frame model (:class:`~demtool.sensors.pushframe.PushFrameSensor`)
with ``starting_ephemeris_time = t0 ∓ o Δ``, ``framelet_order_reversed = DataFlipped``,
zero exposure in the time (ISIS adds none for MARCI), ``starting_detector_line`` the
filter's first row and line summing ``SummingMode``.  The framelets are those of the
parent image: an ``AlphaCube`` crop maps cube lines to parent lines
(:class:`CubeWindowPushFrame`).  A cube of several filters is modelled for its first
band (ISIS's camera before ``SetBand``), with a note; ISIS's ground map searches only
the even or odd framelets the cube holds (``Framelets``), this model all of them.

References: DOI-USGS/ISIS3 ``isis/src/mro/objs/MarciCamera/MarciCamera.cpp``,
``MarciDistortionMap.cpp``, ``isis/src/lro/objs/LroWideAngleCamera/`` (camera, focal plane
and distortion maps), ``isis/src/base/objs/PushFrameCameraDetectorMap``; DOI-USGS/ale
``ale/drivers/lro_drivers.py`` (``LroLrocWacIsisLabelNaifSpiceDriver``: the filter codes);
DOI-USGS/usgscsm ``src/UsgsAstroPushFrameSensorModel.cpp``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from demtool.errors import InputError
from demtool.sensors.pushframe import PushFrameSensor

#: MarciCamera: first detector row, framelet-offset index, distortion filter number.
MARCI_FILTERS = {"BLUE": (709, 4), "GREEN": (734, 3), "ORANGE": (760, 2), "RED": (786, 1),
                 "NIR": (811, 0), "LONG_UV": (266, 5), "SHORT_UV": (293, 6)}
#: MarciCamera's detector origin (ISIS 1-based sample, line) by camera code.
MARCI_ORIGIN = {-74410: (512.5, 768.5), -74420: (512.5, 288.5)}
MARCI_FRAMELET_LINES = 16


class CubeWindowPushFrame(PushFrameSensor):
    """A push-frame model of a parent image seen through an ``AlphaCube`` line window:
    cube line ``l`` (CSM) is parent line ``line_offset + line_scale · l`` (the samples
    are folded into the detector's start and summing).  Every method takes and returns
    cube lines; framelet numbers are the parent image's (``framelet``, and the
    ``framelet`` hint of ``ground_to_image``)."""

    line_offset: float = 0.0
    line_scale: float = 1.0

    def _parent(self, line) -> np.ndarray:
        return self.line_offset + self.line_scale * np.asarray(line, dtype=np.float64)

    def framelet(self, line) -> np.ndarray:
        """Framelet number (int64, parent image order) of cube lines."""
        return super().framelet(self._parent(line))

    def time_line(self, time) -> np.ndarray:
        return (super().time_line(time) - self.line_offset) / self.line_scale

    def _detector_line(self, line) -> np.ndarray:
        return super()._detector_line(self._parent(line))

    def ground_to_image(self, xyz, *, framelet=None, max_iterations: int = 20):
        """Cube (line, sample) of body-fixed points (S + (3,), metres).

        Without a ``framelet`` hint the framelet is searched among those of the cube's
        window only (a point outside them is outside the image): each candidate that
        sees the point in front of the camera on the body's visible side (``(C − X) ·
        X > 0``) is scored by the distance of its (distorted) detector line from the
        framelet's middle (usgscsm's ``calcFrameDistance`` with the lens distortion,
        which MARCI's fisheye needs), the best kept.  Up to
        64 candidates are scored at once; a wider window is scanned coarsely, then
        densely about the best.  usgscsm's secant over the whole parent image is not
        used: over a half-orbit MARCI strip the frame distance is not monotonic and
        the secant can stop on a framelet that sees the point through the planet.
        """
        if framelet is not None:
            return super().ground_to_image(xyz, framelet=framelet)
        xyz = np.asarray(xyz, dtype=np.float64)
        shape = xyz.shape[:-1]
        pts = xyz.reshape(-1, 3)
        first = int(self.framelet(0.0))
        last = int(self.framelet(max(self.lines - 1e-9, 0.0)))
        low, high = min(first, last), max(first, last)
        step = max(1, (high - low + 1) // 64)
        best, score = self._best_framelet(np.arange(low, high + 1, step), pts)
        if step > 1:  # densely about the coarse best
            for offset in range(-step + 1, step):
                cand = np.clip(best + offset, low, high)
                d = self._score(cand, pts)
                better = d < score
                best, score = np.where(better, cand, best), np.where(better, d, score)
        return self._project(best, pts, shape)

    def _score(self, framelet, pts) -> np.ndarray:
        """|detector line − framelet middle| of points (N, 3) seen from framelets (N,);
        inf where the point is behind the camera or on the body's far side from it."""
        time = self.framelet_time(framelet)
        position = self.position_at(time)
        with np.errstate(all="ignore"):
            det_line, _, depth = self._view(framelet, pts)
            distance = np.abs(det_line - 0.5 * self.summed_height)
        facing = np.sum((position - pts) * pts, axis=-1) > 0
        return np.where((depth > 0) & facing & np.isfinite(distance), distance, np.inf)

    def _best_framelet(self, candidates, pts):
        best = np.full(len(pts), candidates[0], dtype=np.int64)
        score = np.full(len(pts), np.inf)
        for k in candidates:
            d = self._score(np.full(len(pts), k, dtype=np.int64), pts)
            better = d < score
            best, score = np.where(better, k, best), np.where(better, d, score)
        return best, score

    def _project(self, best, pts, shape):
        """(cube line, sample) of points (N, 3) projected into parent framelets ``best``."""
        det_line, det_sample, depth = self._view(best, pts)
        if self.framelets_flipped:
            det_line = self.summed_height - det_line
        line = (det_line + best * self.summed_height - self.line_offset) / self.line_scale
        bad = ~(depth > 0) | ~np.isfinite(line) | ~np.isfinite(det_sample)
        if self.coverage is not None:
            bad |= ~self.coverage.covers(self.framelet_time(best)) & (line >= 0) \
                & (line <= self.lines)
        line = np.where(bad, np.nan, line)
        sample = np.where(bad, np.nan, det_sample)
        return line.reshape(shape), sample.reshape(shape)


def read_pushframe_cube(path: Path, label, data: bytes):
    """An ISIS push-frame cube with SPICE attached: MARCI or LRO WAC as a
    :class:`CubeWindowPushFrame`; another camera refused in one line."""
    instrument = label["IsisCube"].get("Instrument", {})
    ident = str(instrument.get("InstrumentId", "")) or "an unnamed camera"
    if ident.upper() in ("MARCI", "WAC-VIS", "WAC-UV"):
        return _window_model(path, label, data)
    raise InputError(f"{path}: is a push-frame cube of {ident} (ISIS PushFrameCamera, "
                     "framelets with per-filter offsets): demtool builds MARCI's and LRO "
                     "WAC's from cubes, not this camera's; pass its ALE ISD (isd_generate)")


def marci_isd(path: Path, label, data: bytes) -> tuple[dict, float, float]:
    """The usgscsm push-frame ISD of a MARCI cube's parent image (module docstring), and
    the cube's window in it: (ISD, line offset, line scale)."""
    from demtool.sensors.isis_kinds import naif_ik_code
    from demtool.sensors.isis_linescan import _Cube

    cube = _Cube(path, label, data)
    code = naif_ik_code(path, label)
    if code not in MARCI_ORIGIN:
        raise InputError(f"{path}: the Kernels NAIF code {code} is not a MARCI camera "
                         "(-74410 VIS, -74420 UV)")
    names = cube.cube.get("BandBin", {}).get("FilterName")
    names = names if isinstance(names, (list, tuple)) else [names]
    band = str(names[0]).strip().upper()
    if band not in MARCI_FILTERS:
        raise InputError(f"{path}: BandBin 'FilterName' {names[0]!r} is not a MARCI filter "
                         f"({', '.join(MARCI_FILTERS)})")
    first_row, order = MARCI_FILTERS[band]
    summing = int(cube.number("SummingMode"))
    if summing <= 0 or MARCI_FRAMELET_LINES % summing:
        raise InputError(f"{path}: the Instrument key 'SummingMode' is {summing}, not a "
                         "divisor of MARCI's 16-line framelets")
    flipped = int(cube.number("DataFlipped")) != 0
    ins = f"INS{code}"
    origin = MARCI_ORIGIN[code]
    notes = []
    if len(names) > 1:
        notes.append(f"MARCI: the geometry of band 1 ({band}) of {len(names)}; each filter "
                     "has its own detector rows and framelet offset")
    camera = dict(
        name="MARCI", height=MARCI_FRAMELET_LINES, summing=summing, first_row=first_row,
        sample_offset=0.0, reversed=flipped,
        framelet_offset=order * int(cube.number("ColorOffset")) * (-1 if flipped else 1),
        delay=cube.number("InterframeDelay"),  # ISIS reads the number as seconds
        t0=cube.clock_et("SpacecraftClockCount") - cube.number("ExposureDuration") / 2000.0,
        focal=cube.scalar(f"{ins}_FOCAL_LENGTH"),
        itrans=(cube.key("INS-74400_ITRANSS", 3).tolist(),
                cube.key("INS-74400_ITRANSL", 3).tolist()),
        center=(origin[1] - 0.5, origin[0] - 0.5),
        distortion={"marci": {"coefficients": [cube.scalar(f"{ins}_PIXEL_SIZE"),
                                               *cube.key(f"{ins}_DISTORTION_COEFFS", 4)
                                               .tolist()]}},
        notes=notes)
    return _framelet_isd(cube, camera)


def wac_isd(path: Path, label, data: bytes) -> tuple[dict, float, float]:
    """The usgscsm push-frame ISD of an LRO WAC cube's parent image, and the cube's
    window in it (ISIS ``LroWideAngleCamera``):

    - the Kernels code ``c`` (−85621 VIS, −85626 UV; ``NaifIkCode``) holds the filter
      tables ``INS<c>_FILTER_BANDCENTER``, ``_FILTER_OFFSET`` (first detector row) and
      ``_FILTER_BANDID``; the filter of wavelength ``λ`` (band 1's ``BandBin/Center``)
      has its own code ``c − (b + id)``, ``b`` = 7 (VIS) or 14 (UV), holding its focal
      length, boresight (the detector origin ``BORESIGHT + 1``, ISIS 1-based), ``ITRANSS/L``
      and ``OD_K`` (ISIS ``LroWideAngleCameraDistortionMap``: ``u = d (1 + k1 r² + k2 r⁴
      + k3 r⁶)``, the ``lrowac`` model);
    - framelets of 14 (VIS) or 16 (UV) detector lines, summed 1 or 4 in both directions;
      the first detector sample ``INS<c>_<mode>_SAMPLE_OFFSET + 1`` (``mode`` the
      ``InstrumentModeId``, ``BW`` followed by ``Mode``);
    - the framelet times ``t0 + (f − o − 1) Δ`` (``DataFlipped``: ``t0 + (N − f + o) Δ``),
      ``t0`` the clock count ``SpacecraftClockStartCount`` plus half the
      ``ExposureDuration``, ``Δ`` the ``InterframeDelay`` (ms), ``o`` the filter's rank
      among the filters by detector row times ``ColorOffset`` (negated when flipped; 0
      in BW mode).
    """
    from demtool.sensors.isis_kinds import naif_ik_code
    from demtool.sensors.isis_linescan import _Cube

    cube = _Cube(path, label, data)
    code = naif_ik_code(path, label)
    ident = str(cube.inst("InstrumentId")).strip().upper()
    uv = ident == "WAC-UV"
    height, summing, base = (16, 4, 14) if uv else (14, 1, 7)
    ins = f"INS{code}"
    centers = [int(round(v)) for v in cube.key(f"{ins}_FILTER_BANDCENTER")]
    offsets = [int(round(v)) for v in cube.key(f"{ins}_FILTER_OFFSET")]
    band_ids = [int(round(v)) for v in cube.key(f"{ins}_FILTER_BANDID")]
    if not len(centers) == len(offsets) == len(band_ids):
        raise InputError(f"{path}: NaifKeywords '{ins}_FILTER_BANDCENTER', '_FILTER_OFFSET' "
                         "and '_FILTER_BANDID' differ in length")
    wanted = cube.cube.get("BandBin", {}).get("Center")
    wanted = wanted if isinstance(wanted, (list, tuple)) else [wanted]
    try:
        wavelength = int(round(float(getattr(wanted[0], "value", wanted[0]))))
        index = centers.index(wavelength)
    except (TypeError, ValueError):
        raise InputError(f"{path}: BandBin 'Center' {wanted[0]!r} is not a WAC filter of "
                         f"{ins}_FILTER_BANDCENTER {centers}") from None
    filter_code = code - (base + band_ids[index])
    fik = f"INS{filter_code}"
    flipped = str(cube.inst("DataFlipped")).strip().upper() == "YES"
    mode = str(cube.inst("InstrumentModeId")).strip().upper()
    rank = sorted(offsets).index(offsets[index])
    factor = int(cube.number("ColorOffset")) * (-1 if flipped else 1)
    if mode == "BW":
        mode += str(cube.inst("Mode")).strip()
        rank = 0
    notes = []
    if len(wanted) > 1:
        notes.append(f"LRO WAC: the geometry of band 1 ({wavelength} nm) of {len(wanted)}; "
                     "each filter has its own detector rows and framelet offset")
    camera = dict(
        name=ident, height=height, summing=summing, first_row=float(offsets[index]),
        sample_offset=cube.scalar(f"{ins}_{mode}_SAMPLE_OFFSET"), reversed=flipped,
        framelet_offset=rank * factor, delay=cube.seconds("InterframeDelay", "ms"),
        t0=cube.clock_et("SpacecraftClockStartCount")
        + cube.seconds("ExposureDuration", "ms") / 2.0,
        focal=cube.scalar(f"{fik}_FOCAL_LENGTH"),
        itrans=(cube.key(f"{fik}_ITRANSS", 3).tolist(), cube.key(f"{fik}_ITRANSL", 3).tolist()),
        center=(cube.scalar(f"{fik}_BORESIGHT_LINE") + 0.5,
                cube.scalar(f"{fik}_BORESIGHT_SAMPLE") + 0.5),
        distortion={"lrowac": {"coefficients": cube.key(f"{fik}_OD_K", 3).tolist()}},
        notes=notes)
    return _framelet_isd(cube, camera)


def _framelet_isd(cube, camera: dict) -> tuple[dict, float, float]:
    """usgscsm's push-frame ISD of an ISIS push-frame camera's parent image (``camera``:
    framelet ``height`` and ``summing``, first detector ``first_row``/``sample_offset``,
    ``framelet_offset`` and order, ``delay``, ``t0``, interior), and the cube's window."""
    from demtool.sensors.isis import _tables
    from demtool.sensors.isis_linescan import _alpha, _radii, _rotations_block, _states_block

    start_s, start_l, k_s, k_l, samples, lines = _alpha(cube)
    alpha = cube.cube.get("AlphaCube", {})
    dims = cube.cube.get("Core", {}).get("Dimensions", {})
    parent_lines = int(alpha.get("AlphaLines", dims.get("Lines", lines)))
    summing, delay = camera["summing"], camera["delay"]
    n_framelets = parent_lines // (camera["height"] // summing)
    offset = camera["framelet_offset"] * delay
    start = camera["t0"] + offset if camera["reversed"] else camera["t0"] - offset
    radii, radii_note = _radii(cube)
    tables = _tables(cube.label)
    isd = {
        "name_model": "USGS_ASTRO_PUSH_FRAME_SENSOR_MODEL", "image_identifier": cube.path.stem,
        "name_sensor": camera["name"], "image_lines": parent_lines, "image_samples": samples,
        "radii": {"semimajor": float(radii[0]), "semiminor": float(radii[2]), "unit": "km"},
        "focal_length_model": {"focal_length": camera["focal"]},
        "focal2pixel_samples": list(camera["itrans"][0]),
        "focal2pixel_lines": list(camera["itrans"][1]),
        "detector_center": {"line": camera["center"][0], "sample": camera["center"][1]},
        "starting_detector_line": float(camera["first_row"]),
        "starting_detector_sample": camera["sample_offset"] + summing * (start_s - 0.5),
        "detector_sample_summing": summing * k_s, "detector_line_summing": summing,
        "optical_distortion": camera["distortion"],
        "framelet_height": camera["height"], "exposure_duration": 0.0,
        "interframe_delay": delay, "starting_ephemeris_time": start,
        "center_ephemeris_time": start + 0.5 * n_framelets * delay,
        "framelets_flipped": False, "framelet_order_reversed": bool(camera["reversed"]),
        "instrument_position": _states_block(cube, "InstrumentPosition", tables),
        "sun_position": _states_block(cube, "SunPosition", tables),
        "instrument_pointing": _rotations_block(cube, "InstrumentPointing", tables),
        "body_rotation": _rotations_block(cube, "BodyRotation", tables),
        "notes": [n for n in (radii_note, *camera["notes"]) if n],
    }
    return isd, start_l - 0.5, k_l


def _window_model(path: Path, label, data: bytes) -> CubeWindowPushFrame:
    import logging
    import re

    from demtool.sensors.coverage import coverage_note, covered_lines
    from demtool.sensors.isd import sensor_from_isd

    marci = str(label["IsisCube"]["Instrument"].get("InstrumentId", "")).upper() == "MARCI"
    isd, line_offset, line_scale = (marci_isd if marci else wac_isd)(path, label, data)
    sensors_log = logging.getLogger("demtool.sensors")
    level = sensors_log.level
    sensors_log.setLevel(logging.ERROR)  # the parent image's coverage is not the cube's
    try:
        model = sensor_from_isd(isd, str(path))
    finally:
        sensors_log.setLevel(level)
    model.__class__ = CubeWindowPushFrame  # the parent image's model, through the window
    model.line_offset, model.line_scale = line_offset, line_scale
    model.lines = int(label["IsisCube"]["Core"]["Dimensions"]["Lines"])
    model.name = path.stem
    model.notes = list(isd["notes"])
    if model.coverage is not None:  # the cube's own lines against the tables
        runs = covered_lines(model, model.coverage)
        note = coverage_note(model, runs)
        if note is not None and not runs:
            raise InputError(f"{path}: no cube line lies within the attached tables "
                             f"({note.split(': masked')[0]})")
        if note is not None:
            model.notes.append(note)
            sensors_log.warning("%s: %s", path, note)
    model.body_name = str(label["IsisCube"].get("Instrument", {}).get("TargetName", "")) \
        or None
    naif = label.get("NaifKeywords") or {}
    radii_key = next((k for k in naif.keys() if re.fullmatch(r"BODY-?\d+_RADII", k)), None)
    model.body_naif_id = int(radii_key[4:-6]) if radii_key else None
    return model
