"""Reader of ISIS3 cubes with SPICE attached (``spiceinit attach=true``) into frame models.

The label (PVL, read with ``pvl``) describes binary tables stored in the cube
(``Object = Table``: ``Name``, ``StartByte`` (1-based), ``Records``, ``ByteOrder``
and one ``Group = Field`` per column).  ``InstrumentPosition`` and ``SunPosition``
hold J2000 positions (km) and ET; ``InstrumentPointing`` and ``BodyRotation`` hold
J2000 → frame quaternions ``J2000Q0..3`` (scalar first), with an optional
``ConstantRotation`` (3×3, row-major) to the final frame.  The interior orientation
comes from the ``NaifKeywords`` object: ``INS<code>_FOCAL_LENGTH`` (mm),
``_ITRANSS``/``_ITRANSL`` (focal plane → detector), ``_BORESIGHT_SAMPLE/LINE`` or
``_CCD_CENTER`` (ISIS 1-based detector origin; the image centre when neither is
given: ISIS's ``ApolloMetricCamera`` sets it to ``(ParentSamples / 2, ParentLines / 2)``),
and ``BODY<code>_RADII`` (km).  An
``AlphaCube`` group (a crop or rescale of the original image) maps the cube's
pixels to the original detector: ``alpha = start + (end − start) / beta_size ·
(beta − 0.5)`` in ISIS's 1-based coordinates (ISIS ``AlphaCube``).

Lens distortion: the Apollo Metric cameras (NAIF codes −915240, −916240, −917240) get
ISIS's ``ApolloMetricDistortionMap`` (``INS<code>_PP``, ``_OD_K``, ``_DECENTER``; the
``apollometric`` model of :mod:`demtool.sensors.distortion`), OSIRIS-REx TAGCAMS
(−64081, −64082, −64071) ISIS's ``OsirisRexTagcamsDistortionMap`` (the ``opencv``
model).  A camera without distortion keywords is ideal; another camera whose keywords
describe a distortion is refused in one line (its ALE ISD carries the distortion).

Refused in one line as well: map-projected cubes (a ``Mapping`` group, ISIS ``cam2map``)
and line-scan cameras (``LineExposureDuration``), which
:mod:`demtool.sensors.isis_linescan` reads (``read_sensor`` sends them there).
The body's name and NAIF id (``TargetName``, ``BODY<code>_RADII``) are kept
as ``model.body_name`` / ``model.body_naif_id`` for bodies PROJ does not know.

Reference: DOI-USGS/ISIS3 ``isis/src/apollo/objs/ApolloMetricCamera/`` (camera and
distortion map), ``isis/src/base/objs/AlphaCube``.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from demtool.errors import InputError
from demtool.sensors.base import Detector
from demtool.sensors.distortion import Distortion
from demtool.sensors.frame import FrameSensor
from demtool.sensors.isd import Orientations
from demtool.sensors.isis_frames import FrameInterior, mission_interior, naif_values
from demtool.sensors.isis_kinds import naif_ik_code
from demtool.sensors.isis_label import read_label

_TYPES = {"Double": "f8", "Integer": "i4", "Real": "f4"}
#: NAIF codes of the Apollo 15, 16 and 17 Metric (Mapping) Cameras (ISIS ApolloMetricCamera).
APOLLO_METRIC_CODES = (-915240, -916240, -917240)


def _tables(label) -> dict:
    return {str(obj["Name"]): obj for key, obj in label.items() if key == "Table"}


def _read_table(path: Path, data: bytes, table) -> dict[str, np.ndarray]:
    name = table["Name"]
    fields = [group for key, group in table.items() if key == "Field"]
    order = "<" if str(table.get("ByteOrder", "Lsb")) == "Lsb" else ">"
    try:
        dtype = np.dtype([(str(f["Name"]), order + _TYPES[str(f["Type"])], (int(f["Size"]),))
                          for f in fields])
        start, records = int(table["StartByte"]) - 1, int(table["Records"])
    except KeyError as exc:
        raise InputError(f"{path}: table {name} lacks the key {exc}") from None
    if records <= 0:
        raise InputError(f"{path}: table {name} is empty (Records = {records})")
    if start < 0 or start + records * dtype.itemsize > len(data):
        raise InputError(f"{path}: table {name} runs past the end of the file")
    array = np.frombuffer(data, dtype=dtype, count=records, offset=start)
    return {key: array[key].reshape(records, -1).astype(np.float64) for key in dtype.names}


def _columns(path: Path, table: dict, name: str, keys: list[str]) -> np.ndarray:
    missing = [k for k in keys if k not in table]
    if missing:
        raise InputError(f"{path}: table {name} lacks the field '{missing[0]}'")
    return np.column_stack([table[k][:, 0] for k in keys])


def _orientations(path, label_table, table, name) -> Orientations:
    quats = _columns(path, table, name, ["J2000Q0", "J2000Q1", "J2000Q2", "J2000Q3"])
    times = _columns(path, table, name, ["ET"])[:, 0]
    constant = None
    if "ConstantRotation" in label_table:
        values = np.asarray(label_table["ConstantRotation"], dtype=np.float64)
        if values.size != 9:
            raise InputError(f"{path}: table {name} has a ConstantRotation of {values.size} "
                             "values, expected 9")
        constant = values.reshape(3, 3)
    return Orientations(times, quats[:, [1, 2, 3, 0]], constant)


def read_cube(path: str | Path) -> FrameSensor:
    """Read an ISIS3 cube with attached SPICE into a :class:`FrameSensor` (line-scan
    cubes: :func:`demtool.sensors.isis_cube.read_isis_cube`).

    Raises
    ------
    InputError
        Not a cube; no attached SPICE (the message says to run ``spiceinit
        attach=true`` or to pass an ISD); a missing table, field or NAIF keyword
        (for Apollo Metric also ``_OD_K`` and ``_DECENTER``, 3 values each, and
        ``_PP``, 2 values, when present); an empty table.
    """
    p = Path(path)
    label, data = read_label(p)
    _refuse_unread_kinds(p, label)
    tables = _tables(label)
    needed = ("InstrumentPointing", "InstrumentPosition", "BodyRotation", "SunPosition")
    absent = [t for t in needed if t not in tables]
    if absent:
        raise InputError(f"{p}: the cube has no attached SPICE ({absent[0]} missing); run "
                         "'spiceinit from=CUBE attach=true' in ISIS, or pass an ALE ISD "
                         "(isd_generate) instead")
    if "NaifKeywords" not in label:
        raise InputError(f"{p}: the cube has SPICE tables but no NaifKeywords object (the "
                         "label layout of ISIS before 3.6): the camera's constants are not "
                         "in the file; re-run spiceinit, or pass an ALE ISD (isd_generate)")
    raw = {name: _read_table(p, data, tables[name]) for name in needed}
    core = label["IsisCube"]["Core"]
    try:
        samples = int(core["Dimensions"]["Samples"])
        lines = int(core["Dimensions"]["Lines"])
    except KeyError as exc:
        raise InputError(f"{p}: the cube label lacks the key {exc}") from None
    code = naif_ik_code(p, label)
    naif = label["NaifKeywords"]
    instrument = label["IsisCube"].get("Instrument", {})
    interior = mission_interior(p, label, naif, code)
    if interior is None:
        interior = _generic_interior(p, label, naif, code, samples, lines)
    body_keys = [k for k in naif.keys() if k.startswith("BODY") and k.endswith("_RADII")]
    if not body_keys:
        raise InputError(f"{p}: NaifKeywords lacks the key 'BODY<code>_RADII'")
    radii = naif_values(p, naif, body_keys[0], 3) * 1000.0
    # What the label says the body is (PROJ may not know it: Bennu, 2101955); the radii
    # above are the model's own either way.
    body_naif = re.fullmatch(r"BODY(-?\d+)_RADII", body_keys[0])

    # Cube pixel → parent pixel (AlphaCube) → detector pixel (the camera's binning and
    # first detector pixel; CSM convention: ISIS − 0.5).
    start_s = start_l = 0.0
    sum_s = sum_l = 1.0
    alpha = label["IsisCube"].get("AlphaCube")
    if alpha is not None:
        sum_s = (float(alpha["AlphaEndingSample"]) - float(alpha["AlphaStartingSample"])) \
            / float(alpha["BetaSamples"])
        sum_l = (float(alpha["AlphaEndingLine"]) - float(alpha["AlphaStartingLine"])) \
            / float(alpha["BetaLines"])
        start_s = float(alpha["AlphaStartingSample"]) - 0.5
        start_l = float(alpha["AlphaStartingLine"]) - 0.5
    binning = interior.binning
    itrans_s, itrans_l = interior.itrans_sample, interior.itrans_line
    focal = interior.focal
    detector = Detector(itrans_sample=itrans_s, itrans_line=itrans_l,
                        center_sample=interior.center_sample - 0.5,
                        center_line=interior.center_line - 0.5,
                        start_sample=interior.start_sample + binning * start_s,
                        start_line=interior.start_line + binning * start_l,
                        sample_summing=binning * sum_s, line_summing=binning * sum_l)

    body = _orientations(p, tables["BodyRotation"], raw["BodyRotation"], "BodyRotation")
    pointing = _orientations(p, tables["InstrumentPointing"], raw["InstrumentPointing"],
                             "InstrumentPointing")
    position = raw["InstrumentPosition"]
    pos = _columns(p, position, "InstrumentPosition", ["J2000X", "J2000Y", "J2000Z"])
    pos_times = _columns(p, position, "InstrumentPosition", ["ET"])[:, 0]
    sun = _columns(p, raw["SunPosition"], "SunPosition", ["J2000X", "J2000Y", "J2000Z"])
    sun_times = _columns(p, raw["SunPosition"], "SunPosition", ["ET"])[:, 0]
    time = float(pos_times[len(pos_times) // 2])
    t = np.array([time])
    r_body = body.matrices_at(t)[0]
    rotation = r_body @ pointing.matrices_at(t)[0].T
    position_body = r_body @ pos[len(pos) // 2] * 1000.0
    sun_body = body.matrices_at(sun_times[:1])[0] @ sun[0] * 1000.0
    # ISIS's zDirection: the side of the focal plane the body is on (Apollo Metric: −z).
    z_direction = -1.0 if rotation[:, 2] @ position_body > 0 else 1.0
    distortion = interior.distortion
    model = FrameSensor(position=position_body, rotation=rotation, focal_length=focal,
                        detector=detector, distortion=distortion, lines=lines, samples=samples,
                        radii=(float(radii[0]), float(radii[2])), sun=sun_body, name=p.stem,
                        time=time, z_direction=z_direction)
    model.notes = list(interior.notes)
    model.body_name = str(instrument.get("TargetName", "")) or None
    model.body_naif_id = int(body_naif.group(1)) if body_naif else None
    return model


def _generic_interior(p: Path, label, naif, code: int, samples: int,
                      lines: int) -> FrameInterior:
    """The interior orientation of a frame camera described by its IK keywords alone
    (``INS<code>_FOCAL_LENGTH``, ``_ITRANSS/L``, ``_BORESIGHT_SAMPLE/LINE`` or
    ``_CCD_CENTER``; Apollo Metric's image centre), with :func:`_distortion`."""
    ins = f"INS{code}"
    instrument = label["IsisCube"].get("Instrument", {})
    focal = float(naif_values(p, naif, f"{ins}_FOCAL_LENGTH", 1)[0])
    if code in TAGCAMS_CODES:  # ISIS OsirisRexTagcamsCamera: the IK gives metres
        focal *= 1000.0
    itrans_s = naif_values(p, naif, f"{ins}_ITRANSS", 3)
    itrans_l = naif_values(p, naif, f"{ins}_ITRANSL", 3)
    if f"{ins}_BORESIGHT_SAMPLE" in naif:
        center_s = float(naif_values(p, naif, f"{ins}_BORESIGHT_SAMPLE", 1)[0])
        center_l = float(naif_values(p, naif, f"{ins}_BORESIGHT_LINE", 1)[0])
    elif f"{ins}_CCD_CENTER" in naif:
        center_s, center_l = naif_values(p, naif, f"{ins}_CCD_CENTER", 2)
        if code in TAGCAMS_CODES:  # OsirisRexTagcamsCamera: CCD_CENTER is 0-based
            center_s, center_l = center_s + 1.0, center_l + 1.0
    else:  # Apollo Metric: ISIS sets the origin to (ParentSamples / 2, ParentLines / 2)
        alpha = label["IsisCube"].get("AlphaCube")
        full_s = float(alpha["AlphaSamples"]) if alpha is not None else samples
        full_l = float(alpha["AlphaLines"]) if alpha is not None else lines
        center_s, center_l = full_s / 2.0, full_l / 2.0
    return FrameInterior(focal=focal, itrans_sample=itrans_s, itrans_line=itrans_l,
                         center_sample=float(center_s), center_line=float(center_l),
                         distortion=_distortion(p, naif, code, focal, instrument))


#: NAIF codes of OSIRIS-REx's TAGCAMS cameras (NavCam, NFTCam, StowCam; ISIS
#: OsirisRexTagcamsCamera).
TAGCAMS_CODES = (-64081, -64082, -64071)
#: NAIF keyword suffixes through which ISIS camera models describe lens distortion.
_DISTORTION_KEYS = ("_OD_K", "_OD_T", "_OD_A", "_DECENTER", "_DISTORTION", "_OPENCV", "_PP",
                    "_TRANSX_DIST", "_CD_")


def _distortion(path: Path, naif, code: int, focal: float, instrument) -> Distortion | None:
    """The lens distortion of an ISIS frame camera from its NAIF keywords.

    Applied: the Apollo Metric cameras (``ApolloMetricDistortionMap``) and OSIRIS-REx
    TAGCAMS (``OsirisRexTagcamsDistortionMap``, the OpenCV model of ``_OPENCV_OD_*`` with
    the camera-head temperature term ``_OD_A``).  Another camera with no distortion
    keyword is ideal; one whose keywords describe a distortion ISIS models per mission
    is refused (its ALE ISD carries the distortion in usgscsm's form).
    """
    ins = f"INS{code}"
    if code in APOLLO_METRIC_CODES:
        pp = naif_values(path, naif, f"{ins}_PP", 2) if f"{ins}_PP" in naif else np.zeros(2)
        odk = naif_values(path, naif, f"{ins}_OD_K", 3)
        decenter = naif_values(path, naif, f"{ins}_DECENTER", 3)
        return Distortion("apollometric", np.concatenate([pp, odk, decenter]))
    model = str(naif.get(f"{ins}_DISTORTION_MODEL", "")).upper()
    if code in TAGCAMS_CODES and model == "OPENCV":
        return _tagcams(path, naif, ins, focal, instrument)
    keys = sorted(k for k in naif.keys() if k.startswith(ins)
                  and any(tag in k[len(ins):] for tag in _DISTORTION_KEYS))
    if not keys:
        return None
    raise InputError(f"{path}: the ISIS camera of NAIF code {code} models lens distortion "
                     f"({keys[0]}) in a way demtool does not apply, and ignoring it "
                     "would misplace pixels; pass an ALE ISD of the image (isd_generate)")


def _tagcams(path: Path, naif, ins: str, focal: float, instrument) -> Distortion:
    """ISIS ``OsirisRexTagcamsDistortionMap`` as a :class:`Distortion` ``opencv`` model.

    The distortion acts on detector pixels: normalised ``x' = (s − cx) p / f`` (pixel
    pitch ``p`` mm, focal ``f`` mm, ``(cx, cy)`` = ``_OPENCV_OD_C``, 1-based like ISIS's
    detector origin ``_CCD_CENTER + 1``), distorted pixels ``fx (1 + a T) x'' + cx`` with
    ``(fx, fy)`` = ``_OD_F``, ``a`` = ``_OD_A`` and ``T`` the label's
    ``CameraHeadTemperature`` (°C).  In focal-plane millimetres that is the ``opencv``
    model with ``sx = fx (1 + a T) p / f`` and the distortion centre's offset from the
    detector origin, ``(ox, oy) = ((cx − s0) p, −(cy − l0) p)``.
    """
    itrans_s = naif_values(path, naif, f"{ins}_ITRANSS", 3)
    itrans_l = naif_values(path, naif, f"{ins}_ITRANSL", 3)
    pitch = float(naif_values(path, naif, f"{ins}_PIXEL_SIZE", 1)[0]) / 1000.0  # µm → mm
    if not (np.allclose(itrans_s, [0.0, 1.0 / pitch, 0.0], rtol=1e-6)
            and np.allclose(itrans_l, [0.0, 0.0, -1.0 / pitch], rtol=1e-6)):
        raise InputError(f"{path}: NaifKeywords '{ins}_ITRANSS'/'_ITRANSL' are not the "
                         "TAGCAMS detector layout (x along samples, y against lines) the "
                         "OpenCV distortion map assumes")
    k = naif_values(path, naif, f"{ins}_OPENCV_OD_K", 6)
    p = naif_values(path, naif, f"{ins}_OPENCV_OD_P", 2)
    fxy = naif_values(path, naif, f"{ins}_OPENCV_OD_F", 2)
    cxy = naif_values(path, naif, f"{ins}_OPENCV_OD_C", 2)
    a = float(naif_values(path, naif, f"{ins}_OPENCV_OD_A", 1)[0])
    origin = naif_values(path, naif, f"{ins}_CCD_CENTER", 2) + 1.0
    temperature = instrument.get("CameraHeadTemperature", 0.0)
    temperature = float(getattr(temperature, "value", temperature))
    scale = 1.0 + a * temperature
    coefficients = np.concatenate([k, p, fxy * scale * pitch / focal,
                                   [(cxy[0] - origin[0]) * pitch, -(cxy[1] - origin[1]) * pitch]])
    return Distortion("opencv", coefficients, focal)


def _refuse_unread_kinds(path: Path, label) -> None:
    """One-line refusals of cubes that are not raw frame-camera images: those of
    :func:`demtool.sensors.isis_kinds.refuse_unread_kinds` (map-projected, SAR, no SPICE
    attached, tables named but absent), and line-scan cameras (``LineExposureDuration``
    in the ``Instrument`` group: CTX, HiRISE, LRO NAC, MOC), which are not frame models.
    """
    from demtool.sensors.isis_kinds import refuse_unread_kinds

    refuse_unread_kinds(path, label)
    cube = label["IsisCube"]
    instrument = cube.get("Instrument", {})
    if "LineExposureDuration" in instrument:
        what = instrument.get("InstrumentId", "a line-scan camera")
        duration = instrument["LineExposureDuration"]
        duration = (f"{duration.value:g} {duration.units}" if hasattr(duration, "units")
                    else str(duration))
        raise InputError(f"{path}: is a line-scan camera cube ({what}, LineExposureDuration "
                         f"{duration}), not a frame camera: read it with "
                         "demtool.sensors.read_sensor (a LineScanSensor)")


def read_footprint(path: str | Path) -> list[np.ndarray]:
    """The footprint polygon ISIS's ``footprintinit`` stored in a cube.

    The label's ``Object = Polygon`` (``Name = Footprint``, ``StartByte`` 1-based,
    ``Bytes``) points at a WKT ``MULTIPOLYGON`` of planetocentric longitude and latitude
    (degrees) of the image border, each ring closed; ISIS computes it with the camera
    and the cube's shape model (a DEM such as LOLA's where ``spiceinit`` used one).

    Returns
    -------
    list of (N, 2) float64
        Each outer ring's vertices ``(longitude, latitude)``, degrees, without the
        closing repeat of the first vertex.

    Raises
    ------
    InputError
        Not a cube; no footprint (run ``footprintinit``); a polygon that is not WKT.
    """
    p = Path(path)
    label, data = read_label(p)
    polygon = next((obj for key, obj in label.items()
                    if key == "Polygon" and str(obj.get("Name", "")) == "Footprint"), None)
    if polygon is None:
        raise InputError(f"{p}: the cube has no footprint polygon (run footprintinit)")
    try:
        start, size = int(polygon["StartByte"]) - 1, int(polygon["Bytes"])
    except KeyError as exc:
        raise InputError(f"{p}: the footprint polygon lacks the key {exc}") from None
    if start < 0 or start + size > len(data):
        raise InputError(f"{p}: the footprint polygon runs past the end of the file")
    text = data[start:start + size].decode("latin-1").strip()
    if not text.upper().startswith(("MULTIPOLYGON", "POLYGON")):
        raise InputError(f"{p}: the footprint polygon is not WKT (starts {text[:20]!r})")
    rings = []
    for polygon_text in re.findall(r"\(\(([^()]*)\)", text):  # outer rings only
        try:
            ring = np.array([[float(v) for v in vertex.split()]
                             for vertex in polygon_text.split(",")], dtype=np.float64)
        except ValueError:
            ring = np.zeros((0, 1))
        if ring.ndim != 2 or ring.shape[1] != 2 or len(ring) < 4:
            raise InputError(f"{p}: the footprint polygon has a malformed ring")
        rings.append(ring[:-1] if np.array_equal(ring[0], ring[-1]) else ring)
    if not rings:
        raise InputError(f"{p}: the footprint polygon has no ring")
    return rings
