"""ISIS3 line-scan cubes with SPICE attached (LRO NAC, MRO CTX, MRO HiRISE; THEMIS IR in
:mod:`demtool.sensors.isis_linescan_cameras`) as
:class:`~demtool.sensors.linescan.LineScanSensor` models.

The cube carries what ALE's ``IsisSpice`` drivers read (DOI-USGS/ale
``ale/base/data_isis.py``, ``ale/drivers/lro_drivers.py``, ``mro_drivers.py``): the
ephemerides and attitude as binary tables (``InstrumentPosition``/``SunPosition``: J2000
km and km/s with ``ET``; ``InstrumentPointing``/``BodyRotation``: J2000 → frame
quaternions, scalar first, with the label's ``ConstantRotation`` from the table's first
time-dependent frame to the instrument frame), and the instrument kernel's keys in the
``NaifKeywords`` object.  :func:`cube_isd` turns them into the ALE image support data
(ISD) of the cube, and :func:`read_linescan_cube` builds the model from that ISD with
:func:`demtool.sensors.isd.sensor_from_isd` (usgscsm's resampling, the ephemeris
coverage of :mod:`demtool.sensors.coverage`).

Line times.  ISIS tables are in ephemeris time (TDB seconds past J2000).  The image
start comes from ``spiceinit``'s own conversion of the label's spacecraft clock count,
stored as ``CLOCK_ET_<sc>_<count>_COMPUTED`` (the IEEE double's bytes in hexadecimal,
as ALE's ``IsisSpice.ephemeris_start_time`` reads it): exact, no kernel needed.  Then,
per camera, as ISIS's camera models and ALE's drivers do:

==========  ==================================================================
camera      start ET, line time (s)
==========  ==================================================================
LRO NAC     ``clock(SpacecraftClockPrerollCount) + CONSTANT_TIME_OFFSET +
            ADDITIONAL_PREROLL · r``, ``r = LineExposureDuration · (1 +
            MULTIPLI_LINE_ERROR) + ADDITIVE_LINE_ERROR`` (ISIS LroNarrowAngleCamera)
CTX         ``clock(SpacecraftClockCount)``, ``r = LineExposureDuration``
            (ISIS MroCtxCamera)
HiRISE      ``clock(SpacecraftClockStartCount) − u (Tdi/2 − 0.5) + u (Summing/2 −
            0.5)``, ``r = u · Summing``, ``u = (74 + DeltaLineTimerCount/16) µs``
            (ISIS HiriseCamera)
==========  ==================================================================

ISIS's ``LineScanCameraDetectorMap`` exposes parent line ``L`` (1-based) at ``start +
(L − 0.5) r``; an ``AlphaCube`` crop or rescale maps cube line ``c`` (CSM, 0 = top edge)
to parent line ``AlphaStartingLine + c k`` (``k`` the line ratio), so the cube's
line-scan rate is ``[[0.5, start + (AlphaStartingLine − 0.5) r − centre, k r]]``.  The
uncertainty of these times is that of ISIS's own camera model (the clock conversion is
ISIS's double); the reader checks that the first cube line lies within the pointing
table's span, and :func:`time_check` reports where ``spiceinit``'s tables start against
the derived start of the parent image (``bench/sensor_files.py``): the label's
``CkTableStartTime`` is the derived start to 0.00 lines for the shared LRO NAC, CTX and
HiRISE "before" cubes and 0.06 lines (4.7 µs) for the HiRISE "after" cube.

Interior orientation (ISIS → CSM: 1-based detector pixels become 0-based by −0.5, as
ALE does): LRO NAC and CTX ``detector_center = (BORESIGHT_LINE, BORESIGHT_SAMPLE −
0.5)``, first detector sample ``SampleFirstPixel`` (ISIS ``SetStartingDetectorSample(
SampleFirstPixel + 1)``), sample summing ``SpatialSumming``; HiRISE the CCD's own affine
``INS-746nn_ITRANSS/L`` (CCD ``nn`` from ``CpmmNumber``, ALE's ``hirise_ccd_lookup``)
about ISIS's detector origin (sample 1024.5, ISIS 1-based), at the detector line of the
TDI block's centre (``−64 + Tdi/2``), first sample 1024 for channel 0, sample summing
``Summing`` (ISIS ``HiriseCamera``: ``SetDetectorOrigin(1024.5, 0)``,
``SetDetectorOffset(0, ccdLine_c)``).  ALE's HiRISE driver puts the origin at detector
(0, 0) instead, 1024 samples away: on the shared ``cam2map`` pair ISIS's origin is the
one under which both cameras see the map (below).
Distortion: LRO NAC ``lrolrocnac`` (``_OD_K``, ISIS LroNarrowAngleDistortionMap), CTX and
HiRISE ``radial`` (``_OD_K``, ISIS CameraDistortionMap; HiRISE's from ``INS-74699``).

MGS MOC-NA cubes of the old ISIS label layout (no ``NaifKeywords``, per-line tables
without ``TimeDependentFrames``: the pointing is J2000 → instrument) are read with the
constants of the MOC-NA IK and the timing of their per-line tables (:func:`_moc_na`).
Not read (refused in one line): other cameras, polynomial (jigsaw
``J2000SVX``/``J2000Ang1``) tables, and cubes without the computed clock key.
"""

from __future__ import annotations

import re
import struct
from pathlib import Path

import numpy as np

from demtool.errors import InputError
from demtool.sensors.isis_linescan_cameras import MOC_WA_CODES, THEMIS_IR_CODE, moc_wa, themis_ir

#: NAIF codes of the line-scan cameras read here: LRO NAC left/right, CTX, HiRISE.
LRO_NAC_CODES = (-85600, -85610)
CTX_CODE = -74021
HIRISE_CODE = -74699
#: ALE's ``hirise_ccd_lookup``: CpmmNumber → CCD number (NAIF code −74600 − CCD).
HIRISE_CCD = {0: 0, 1: 1, 2: 2, 3: 3, 4: 12, 5: 4, 6: 10, 7: 11, 8: 5, 9: 13, 10: 6,
              11: 7, 12: 8, 13: 9}
_SECONDS = {"ms": 1e-3, "msec": 1e-3, "milliseconds": 1e-3, "millisecond": 1e-3,
            "microseconds": 1e-6, "microsecond": 1e-6, "us": 1e-6, "usec": 1e-6,
            "s": 1.0, "sec": 1.0, "seconds": 1.0}


class _Cube:
    """Lookups in one cube's label that fail with one line naming the file and key."""

    def __init__(self, path: Path, label, data: bytes):
        self.path, self.label, self.data = path, label, data
        self.cube = label["IsisCube"]
        self.instrument = self.cube.get("Instrument", {})
        self.naif = label.get("NaifKeywords")

    def inst(self, key: str):
        if key not in self.instrument:
            raise InputError(f"{self.path}: the Instrument group lacks the key '{key}'")
        return self.instrument[key]

    def number(self, key: str) -> float:
        value = self.inst(key)
        return float(getattr(value, "value", value))

    def seconds(self, key: str, default_unit: str) -> float:
        """A duration of the Instrument group in seconds (its unit, or ``default_unit``)."""
        value = self.inst(key)
        unit = str(getattr(value, "units", "") or default_unit).strip().lower()
        if unit not in _SECONDS:
            raise InputError(f"{self.path}: the Instrument key '{key}' has the unit "
                             f"{unit!r}, expected milliseconds or microseconds")
        return float(getattr(value, "value", value)) * _SECONDS[unit]

    def key(self, key: str, size: int | None = None) -> np.ndarray:
        if self.naif is None:
            raise InputError(f"{self.path}: the cube has no NaifKeywords object (needed: "
                             f"'{key}'); an old ISIS label layout, re-run spiceinit in "
                             "ISIS 3.6 or later, or pass an ALE ISD (isd_generate)")
        if key not in self.naif:
            raise InputError(f"{self.path}: NaifKeywords lacks the key '{key}'")
        value = np.atleast_1d(np.asarray(self.naif[key], dtype=np.float64))
        if size is not None and value.size != size:
            raise InputError(f"{self.path}: NaifKeywords '{key}' has {value.size} values, "
                             f"expected {size}")
        return value

    def scalar(self, key: str) -> float:
        return float(self.key(key, 1)[0])

    def clock_et(self, count_key: str) -> float:
        """spiceinit's ET of the label's clock count ``count_key`` (module docstring)."""
        count = str(self.inst(count_key)).strip()
        end = self.data.find(b"\nEnd\n")
        text = self.data[: end if end > 0 else 65536].decode("latin-1")
        pattern = r"CLOCK_ET_(-?\d+)_" + re.escape(count) + r"_COMPUTED\s*=\s*([0-9A-Fa-f]+)"
        match = re.search(pattern, text)
        if match is None:  # a decimal count the label parser re-wrote (698713127.000)
            for candidate in re.finditer(r"CLOCK_ET_(-?\d+)_([0-9.]+)_COMPUTED\s*=\s*"
                                         r"([0-9A-Fa-f]+)", text):
                try:
                    same = float(candidate.group(2)) == float(count)
                except ValueError:
                    same = False
                if same:
                    return struct.unpack("<d", bytes.fromhex(
                        candidate.group(3).zfill(16)))[0]
            raise InputError(f"{self.path}: NaifKeywords lacks the key 'CLOCK_ET_<sc>_{count}"
                             f"_COMPUTED' (spiceinit's ephemeris time of {count_key}); "
                             "re-run spiceinit, or pass an ALE ISD (isd_generate)")
        return struct.unpack("<d", bytes.fromhex(match.group(2).zfill(16)))[0]


def _alpha(cube: _Cube) -> tuple[float, float, float, float, int, int]:
    """(start_sample, start_line, k_sample, k_line, samples, lines) of the cube in its
    parent image: ISIS ``AlphaCube`` (starts 1-based, in parent pixels), or the identity.
    For a map-projected cube the size is the camera image's (``BetaSamples/Lines``)."""
    alpha = cube.cube.get("AlphaCube")
    dims = cube.cube.get("Core", {}).get("Dimensions", {})
    if alpha is None:
        if "Mapping" in cube.cube:
            raise InputError(f"{cube.path}: the map-projected cube has no AlphaCube group; "
                             "the camera image's size is unknown")
        try:
            return 0.5, 0.5, 1.0, 1.0, int(dims["Samples"]), int(dims["Lines"])
        except KeyError as exc:
            raise InputError(f"{cube.path}: the cube label lacks the key {exc}") from None
    try:
        samples, lines = int(alpha["BetaSamples"]), int(alpha["BetaLines"])
        k_s = (float(alpha["AlphaEndingSample"]) - float(alpha["AlphaStartingSample"])) / samples
        k_l = (float(alpha["AlphaEndingLine"]) - float(alpha["AlphaStartingLine"])) / lines
        return (float(alpha["AlphaStartingSample"]), float(alpha["AlphaStartingLine"]),
                k_s, k_l, samples, lines)
    except KeyError as exc:
        raise InputError(f"{cube.path}: the AlphaCube group lacks the key {exc}") from None


def _camera(cube: _Cube, code: int) -> dict:
    """Timing (start ET of parent line 0.5, seconds per parent line) and interior
    orientation of the three cameras (module docstring's table)."""
    ins = f"INS{code}"
    if code == MOC_NA_CODE and cube.naif is None:
        return _moc_na(cube)
    if code in MOC_WA_CODES:
        return moc_wa(cube, ins)
    if cube.naif is None:
        cube.key(f"{ins}_FOCAL_LENGTH")  # raises: no NaifKeywords (old layout)
    if code in LRO_NAC_CODES:
        rate = cube.seconds("LineExposureDuration", "ms") \
            * (1.0 + cube.scalar(f"{ins}_MULTIPLI_LINE_ERROR")) \
            + cube.scalar(f"{ins}_ADDITIVE_LINE_ERROR")
        start = (cube.clock_et("SpacecraftClockPrerollCount")
                 + cube.scalar(f"{ins}_CONSTANT_TIME_OFFSET")
                 + cube.scalar(f"{ins}_ADDITIONAL_PREROLL") * rate)
        return dict(start=start, rate=rate, itrans=_itrans(cube, ins),
                    focal=cube.scalar(f"{ins}_FOCAL_LENGTH"),
                    center=(cube.scalar(f"{ins}_BORESIGHT_LINE"),
                            cube.scalar(f"{ins}_BORESIGHT_SAMPLE") - 0.5),
                    first_sample=cube.number("SampleFirstPixel"),
                    summing=cube.number("SpatialSumming"),
                    distortion={"lrolrocnac": {"coefficients":
                                               cube.key(f"{ins}_OD_K", 1).tolist()}})
    if code == CTX_CODE:
        return dict(start=cube.clock_et("SpacecraftClockCount"),
                    rate=cube.seconds("LineExposureDuration", "ms"), itrans=_itrans(cube, ins),
                    focal=cube.scalar(f"{ins}_FOCAL_LENGTH"),
                    center=(cube.scalar(f"{ins}_BORESIGHT_LINE"),
                            cube.scalar(f"{ins}_BORESIGHT_SAMPLE") - 0.5),
                    first_sample=cube.number("SampleFirstPixel"),
                    summing=cube.number("SpatialSumming"),
                    distortion={"radial": {"coefficients": cube.key(f"{ins}_OD_K", 3).tolist()}})
    if code == HIRISE_CODE:
        unbinned = (74.0 + cube.number("DeltaLineTimerCount") / 16.0) / 1e6
        tdi, summing = cube.number("Tdi"), cube.number("Summing")
        start = (cube.clock_et("SpacecraftClockStartCount") - unbinned * (tdi / 2.0 - 0.5)
                 + unbinned * (summing / 2.0 - 0.5))
        cpmm = int(cube.number("CpmmNumber"))
        if cpmm not in HIRISE_CCD:
            raise InputError(f"{cube.path}: the Instrument key 'CpmmNumber' is {cpmm}, "
                             "not a HiRISE CCD (0-13)")
        ccd = f"INS{-74600 - HIRISE_CCD[cpmm]}"
        channel = int(cube.number("ChannelNumber"))
        # ISIS HiriseCamera: detector origin (1024.5, 0) (ISIS 1-based: CSM 1024), and the
        # line of the TDI block's centre, ccdLine_c = −64 + Tdi / 2, as the detector line
        return dict(start=start, rate=unbinned * summing, itrans=_itrans(cube, ccd),
                    focal=cube.scalar(f"{ins}_FOCAL_LENGTH"),
                    center=(64.0 - tdi / 2.0, 1024.0),
                    first_sample=1024.0 if channel == 0 else 0.0, summing=summing,
                    distortion={"radial": {"coefficients": cube.key(f"{ins}_OD_K", 3).tolist()}})
    if code == THEMIS_IR_CODE:
        return themis_ir(cube, ins)
    if code in MOC_WA_CODES:
        return moc_wa(cube, ins)
    what = str(cube.instrument.get("InstrumentId", "")) or "an unnamed camera"
    raise InputError(f"{cube.path}: is a line-scan cube of {what} (NAIF code {code}); "
                     "demtool reads the ISIS line-scan models of LRO NAC, MRO CTX, MRO "
                     "HiRISE, MOC and THEMIS IR from cubes: pass an ALE ISD of this image "
                     "(isd_generate)")


def _itrans(cube: _Cube, ins: str) -> tuple[list, list]:
    return cube.key(f"{ins}_ITRANSS", 3).tolist(), cube.key(f"{ins}_ITRANSL", 3).tolist()


#: MGS MOC narrow angle (NAIF −94031), the constants of its IK (``moc20.ti``, as ALE's
#: test ISD ``mgsmocna_isd.json`` carries them in its ``naif_keywords``): the old ISIS
#: label layout has no NaifKeywords object.
MOC_NA_CODE = -94031
MOC_NA_IK = {"focal": 3500.0, "pitch": 0.0131240578522949, "boresight_sample": 1024.5}


def _moc_na(cube: _Cube) -> dict:
    """The MGS MOC-NA camera of an old-layout cube (no NaifKeywords), ISIS
    ``MocNarrowAngleCamera``: the IK's constants (:data:`MOC_NA_IK`), detector origin
    sample 1024.5, no distortion, sample summing ``CrosstrackSumming`` from detector
    sample ``FirstLineSample``; no computed clock either, so the timing is that of the
    per-line tables ``spiceinit`` wrote for the parent image, which must hold one record
    per parent line edge (``AlphaLines + 1`` records, evenly spaced by
    ``LineExposureDuration × DowntrackSumming`` to 1e-4): start = the first record's ET,
    line time = the records' span over the lines."""
    from demtool.sensors.isis import _columns, _tables

    _, table = _table(cube, "InstrumentPointing", _tables(cube.label))
    times = _columns(cube.path, table, "InstrumentPointing", ["ET"])[:, 0]
    alpha = cube.cube.get("AlphaCube", {})
    dims = cube.cube.get("Core", {}).get("Dimensions", {})
    parent_lines = int(alpha.get("AlphaLines", dims.get("Lines", 0)))
    label_rate = cube.seconds("LineExposureDuration", "ms") * cube.number("DowntrackSumming")
    steps = np.diff(times)
    spacing = float(np.median(steps)) if len(steps) else 0.0
    if (len(times) != parent_lines + 1 or len(steps) == 0
            or not np.allclose(steps, label_rate, rtol=1e-4, atol=0.0)):
        raise InputError(f"{cube.path}: the old-layout MOC cube's InstrumentPointing table "
                         f"({len(times)} records, spacing {spacing:.7g} s) is not one record "
                         f"per edge of its {parent_lines} lines at {label_rate:.7g} s: the "
                         "image start time cannot be derived (no NaifKeywords clock); pass "
                         "an ALE ISD (isd_generate)")
    rate = (times[-1] - times[0]) / parent_lines  # the cache's own line time
    inverse = 1.0 / MOC_NA_IK["pitch"]
    return dict(start=float(times[0]), rate=rate, focal=MOC_NA_IK["focal"],
                itrans=([0.0, 0.0, inverse], [0.0, inverse, 0.0]),
                center=(0.0, MOC_NA_IK["boresight_sample"] - 0.5),
                first_sample=cube.number("FirstLineSample") - 1.0,
                summing=cube.number("CrosstrackSumming"),
                distortion={"radial": {"coefficients": [0.0, 0.0, 0.0]}},
                note="MGS MOC-NA constants from its IK (moc20.ti; the cube's old label "
                     "layout has none), start time from the per-line tables")


def _radii(cube: _Cube) -> tuple[np.ndarray, str | None]:
    """Body radii (km) from NaifKeywords, or (old layout) from PROJ's body of the
    Instrument group's ``TargetName`` with a note."""
    if cube.naif is not None:
        key = next((k for k in cube.naif.keys() if re.fullmatch(r"BODY-?\d+_RADII", k)), None)
        if key is None:
            raise InputError(f"{cube.path}: NaifKeywords lacks the key 'BODY<code>_RADII'")
        return cube.key(key, 3), None
    from demtool.maps.bodies import body_by_name

    target = str(cube.instrument.get("TargetName", ""))
    try:
        body = body_by_name(target)
    except (InputError, KeyError, ValueError):
        raise InputError(f"{cube.path}: the cube has no NaifKeywords (BODY<code>_RADII) and "
                         f"its TargetName {target!r} is not a body PROJ knows") from None
    return (np.array(body.radii) / 1000.0,
            f"radii of {body.name} from PROJ (the cube has no NaifKeywords)")


def _table(cube: _Cube, name: str, tables: dict) -> tuple[dict, dict]:
    from demtool.sensors.isis import _read_table

    if name not in tables:
        raise InputError(f"{cube.path}: the cube has no {name} table (no attached SPICE); "
                         "run 'spiceinit attach=true' in ISIS, or pass an ALE ISD")
    values = _read_table(cube.path, cube.data, tables[name])
    poly = [k for k in ("J2000SVX", "J2000Ang1") if k in values]
    if poly:
        raise InputError(f"{cube.path}: table {name} holds polynomial coefficients "
                         f"('{poly[0]}', as jigsaw writes them); demtool reads sampled "
                         "tables: run 'spiceinit' again or pass an ALE ISD")
    return tables[name], values


def _states_block(cube: _Cube, name: str, tables: dict) -> dict:
    from demtool.sensors.isis import _columns

    _, table = _table(cube, name, tables)
    block = {"ephemeris_times": _columns(cube.path, table, name, ["ET"])[:, 0].tolist(),
             "positions": _columns(cube.path, table, name,
                                   ["J2000X", "J2000Y", "J2000Z"]).tolist(), "unit": "km"}
    if all(k in table for k in ("J2000XV", "J2000YV", "J2000ZV")):
        block["velocities"] = _columns(cube.path, table, name,
                                       ["J2000XV", "J2000YV", "J2000ZV"]).tolist()
    return block


def _rotations_block(cube: _Cube, name: str, tables: dict) -> dict:
    from demtool.sensors.isis import _columns

    label_table, table = _table(cube, name, tables)
    block = {"ephemeris_times": _columns(cube.path, table, name, ["ET"])[:, 0].tolist(),
             "quaternions": _columns(cube.path, table, name,
                                     ["J2000Q0", "J2000Q1", "J2000Q2", "J2000Q3"]).tolist()}
    if "ConstantRotation" in label_table:
        values = np.asarray(label_table["ConstantRotation"], dtype=np.float64).ravel()
        if values.size != 9:
            raise InputError(f"{cube.path}: table {name} has a ConstantRotation of "
                             f"{values.size} values, expected 9")
        block["constant_rotation"] = values.tolist()
    return block


def cube_isd(path: str | Path, label=None, data: bytes | None = None, *,
             mapped: bool = False) -> dict:
    """The ALE image support data (a ``USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL`` ISD dict)
    of an ISIS line-scan cube with attached SPICE (module docstring).

    Parameters
    ----------
    path : path-like
        The cube.
    label, data : optional
        Its parsed label and bytes, when already read.
    mapped : bool
        Accept a map-projected cube (``cam2map``: ``Mapping`` group): the ISD is then its
        camera image's (size from ``AlphaCube``'s ``BetaSamples/Lines``).

    Raises
    ------
    InputError
        One line naming the file and the missing key, table or field; a camera other
        than LRO NAC, CTX or HiRISE; a map-projected cube when ``mapped`` is False.
    """
    from demtool.sensors.isis import _tables
    from demtool.sensors.isis_kinds import camera_kind, naif_ik_code
    from demtool.sensors.isis_label import read_label

    p = Path(path)
    if label is None or data is None:
        label, data = read_label(p)
    cube = _Cube(p, label, data)
    if "Mapping" in cube.cube and not mapped:
        raise InputError(f"{p}: is a map-projected cube: its pixels lie on the map, not in "
                         "the camera")
    if camera_kind(label) != "linescan":
        raise InputError(f"{p}: the Instrument group lacks the key 'LineExposureDuration' "
                         "(not a line-scan camera cube)")
    code = naif_ik_code(p, label)
    camera = _camera(cube, code)
    start_s, start_l, k_s, k_l, samples, lines = _alpha(cube)
    tables = _tables(label)
    pointing = _rotations_block(cube, "InstrumentPointing", tables)
    rate = k_l * camera["rate"]
    first = camera["start"] + (start_l - 0.5) * camera["rate"]  # ET of cube line 0 (top)
    centre = first + 0.5 * lines * rate
    radii, radii_note = _radii(cube)
    summing = camera["summing"]
    isd = {
        "name_model": "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL", "image_identifier": p.stem,
        "name_sensor": str(cube.instrument.get("InstrumentId", "")),
        "image_lines": lines, "image_samples": samples,
        "radii": {"semimajor": float(radii[0]), "semiminor": float(radii[2]), "unit": "km"},
        "focal_length_model": {"focal_length": camera["focal"]},
        "focal2pixel_samples": list(camera["itrans"][0]),
        "focal2pixel_lines": list(camera["itrans"][1]),
        "detector_center": {"line": camera["center"][0], "sample": camera["center"][1]},
        "starting_detector_line": 0.0,
        "starting_detector_sample": (start_s - 0.5) * summing + camera["first_sample"],
        "detector_sample_summing": k_s * summing, "detector_line_summing": 1.0,
        "optical_distortion": camera["distortion"],
        "center_ephemeris_time": centre, "starting_ephemeris_time": first,
        "line_scan_rate": [[0.5, first - centre, rate]],
        "instrument_position": _states_block(cube, "InstrumentPosition", tables),
        "sun_position": _states_block(cube, "SunPosition", tables),
        "instrument_pointing": pointing,
        "body_rotation": _rotations_block(cube, "BodyRotation", tables),
        "notes": [n for n in (camera.get("note"), radii_note) if n],
    }
    times = np.asarray(pointing["ephemeris_times"])
    spacing = float(np.median(np.diff(times))) if len(times) > 1 else 0.0
    if not times[0] - spacing - rate <= first <= times[-1] + spacing:
        raise InputError(f"{p}: the image's first line (ET {first:.6f} s, from the clock "
                         f"count and the camera's timing) lies outside the InstrumentPointing "
                         f"table ({times[0]:.6f}…{times[-1]:.6f} s)")
    return isd


def time_check(isd: dict, label) -> dict:
    """Where the pointing table starts, against the image's start time derived from the
    clock (module docstring), in lines of the parent image (the uncropped camera image,
    for which ``spiceinit`` built the tables): ``table_start_lines`` from the first
    record's ET, ``ck_start_lines`` from the label's ``CkTableStartTime``,
    ``cube_start_lines`` the cube's first line (its ``AlphaCube`` crop); a table that
    starts at one of these two is ISIS's cache of the parent or of the cropped image.
    For reports, not a check."""
    from demtool.sensors.isis import _tables

    alpha = label["IsisCube"].get("AlphaCube")
    start_l, k_l = 0.5, 1.0
    if alpha is not None:
        start_l = float(alpha["AlphaStartingLine"])
        k_l = (float(alpha["AlphaEndingLine"]) - start_l) / float(alpha["BetaLines"])
    rate = isd["line_scan_rate"][0][2] / k_l  # seconds per parent line
    parent_first = isd["starting_ephemeris_time"] - (start_l - 0.5) * rate
    t = np.asarray(isd["instrument_pointing"]["ephemeris_times"])
    ck = _tables(label)["InstrumentPointing"].get("CkTableStartTime")
    return {"cube_start_lines": start_l - 0.5, "table_start_lines": (t[0] - parent_first) / rate,
            "ck_start_lines": (float(ck) - parent_first) / rate if ck is not None else np.nan}


def read_linescan_cube(path: str | Path, label=None, data: bytes | None = None, *,
                       mapped: bool = False):
    """Read an ISIS line-scan cube with attached SPICE into a :class:`LineScanSensor`
    (the ISD of :func:`cube_isd` through :func:`~demtool.sensors.isd.sensor_from_isd`).

    The model keeps ``notes``, ``body_name`` (the label's ``TargetName``) and
    ``body_naif_id`` like the frame reader's; ``mapped=True`` reads the camera of a
    ``cam2map`` cube.

    Raises
    ------
    InputError
        See :func:`cube_isd`.
    """
    from demtool.sensors.distortion import MODELS
    from demtool.sensors.isd import sensor_from_isd
    from demtool.sensors.isis_label import read_label

    p = Path(path)
    if label is None or data is None:
        label, data = read_label(p)
    isd = cube_isd(p, label, data, mapped=mapped)
    lens = next(iter(isd["optical_distortion"]))
    if lens not in MODELS:  # a mission distortion map the ISD readers add (themisir)
        raise InputError(f"{p}: needs ISIS's distortion map '{lens}', which this demtool "
                         "lacks; pass an ALE ISD to a demtool that has it")
    model = sensor_from_isd(isd, str(p))
    model.notes = list(getattr(model, "notes", [])) + list(isd["notes"])
    instrument = label["IsisCube"].get("Instrument", {})
    model.body_name = str(instrument.get("TargetName", "")) or None
    naif = label.get("NaifKeywords") or {}
    radii_key = next((k for k in naif.keys() if re.fullmatch(r"BODY-?\d+_RADII", k)), None)
    model.body_naif_id = int(radii_key[4:-6]) if radii_key else None
    return model
