"""ISIS line-scan cameras read from cubes beyond LRO NAC, CTX and HiRISE
(:mod:`demtool.sensors.isis_linescan`): Mars Odyssey THEMIS IR and MGS MOC wide angle.

THEMIS IR (ISIS ``ThemisIrCamera``, NAIF −53031) has no ``LineExposureDuration``: its
line time is 33.2871 ms × ``SpatialSumming`` (Duxbury's model), the image starts at the
clock count ``SpacecraftClockCount`` plus ``SpacecraftClockOffset`` (``thm2isis``'s
timing correction), and each of the ten filters sits on its own detector line ``d``
(TDI ``ENABLED``: 8.5, 24.5, …, 231.5; disabled: 9, 24, …, 232), which ISIS
(``SetBand``) turns into a start-time offset ``(d − 0.5) · 33.2871 ms`` and an
along-track detector offset ``120.5 − d`` plus Kirk's empirical per-band corrections,
with the sample origin 160.5 less its own per-band correction.  Focal length 203.9213
mm, pixel pitch 0.05 mm (``INS-53031_ITRANSS/L``); the distortion is ISIS's
``ThemisIrDistortionMap`` (``x_d = k x``, ``y_d = y + α₁ y + α₂ y²``, ``k`` per band),
written in ALE's ``themisir`` form (``p_k``, ``p_alpha1``, ``p_alpha2``).  A cube of
several bands is modelled for its first band (ISIS's camera before ``SetBand``), with
a note.

MOC-WA (ISIS ``MocWideAngleCamera``, NAIF −94032 red, −94033 blue): the image starts
at the clock count ``SpacecraftClockCount``, ``LineExposureDuration × DowntrackSumming``
per line (``MocLabels``), detector samples from ``FirstLineSample`` summed by
``CrosstrackSumming`` (the variable summing modes 13 and 27, a per-sample table of
``MocWideAngleDetectorMap``, are refused), detector origin sample 1674.65 and
along-track offset 6.7785 (red) or 1688.58 and −0.8486 (blue), focal length and pixel
pitch from the IK keywords, and ``MocWideAngleDistortionMap`` (the ``mocwa`` model of
:mod:`demtool.sensors.distortion_cubes`).  A red cube of the old label layout (no
``NaifKeywords``) takes the IK's red constants and its start time from its per-line
tables, as MOC-NA's (:func:`demtool.sensors.isis_linescan._moc_na`).

References: DOI-USGS/ISIS3 ``isis/src/odyssey/objs/ThemisIrCamera/ThemisIrCamera.cpp``
and ``ThemisIrDistortionMap.cpp``, ``isis/src/mgs/objs/MocWideAngleCamera/``
(``MocWideAngleCamera.cpp``, ``MocWideAngleDetectorMap.cpp``,
``MocWideAngleDistortionMap.cpp``), ``isis/src/mgs/objs/MocLabels/MocLabels.cpp``;
DOI-USGS/ale ``ale/drivers/ody_drivers.py`` (``OdyThemisIrIsisLabelNaifSpiceDriver``).
"""

from __future__ import annotations

import numpy as np

from demtool.errors import InputError

THEMIS_IR_CODE = -53031
#: ThemisIrCamera: seconds per line at SpatialSumming 1, focal length (mm).
THEMIS_IR_LINE_TIME = 33.2871e-3
THEMIS_IR_FOCAL = 203.9213
#: ThemisIrCamera::SetBand, per filter 1..10: the detector line with TDI enabled and
#: disabled, Kirk's along-track and sample-boresight corrections (pixels).
THEMIS_IR_LINE_TDI = (8.5, 24.5, 50.5, 76.5, 102.5, 128.5, 154.5, 180.5, 205.5, 231.5)
THEMIS_IR_LINE_NO_TDI = (9, 24, 52, 77, 102, 129, 155, 181, 206, 232)
THEMIS_IR_ALONG = (-0.076, -0.098, -0.089, -0.022, 0.0, -0.020, -0.005, -0.069, 0.025, 0.0)
THEMIS_IR_BORESIGHT = (0.021, 0.027, 0.005, 0.005, 0.0, -0.007, -0.012, -0.039, -0.045, 0.0)
#: ThemisIrDistortionMap: x scale per filter, and the y terms α₁, α₂.
THEMIS_IR_K = (0.996005, 0.995358, 0.994260, 0.993290, 0.992389, 0.991474, 0.990505,
               0.989611, 0.988653, 0.9877)
THEMIS_IR_ALPHA = (0.00447623, 0.00107556)


def themis_ir(cube, ins: str) -> dict:
    """The timing and interior of a THEMIS IR cube (module docstring), in the form of
    :func:`demtool.sensors.isis_linescan._camera`."""
    band_bin = cube.cube.get("BandBin", {})
    filters = band_bin.get("FilterNumber", band_bin.get("OriginalBand"))
    if filters is None:
        raise InputError(f"{cube.path}: the BandBin group lacks the key 'FilterNumber' (the "
                         "THEMIS IR filter of each band)")
    filters = filters if isinstance(filters, (list, tuple)) else [filters]
    band = int(filters[0])
    if not 1 <= band <= 10:
        raise InputError(f"{cube.path}: BandBin 'FilterNumber' {band} is not a THEMIS IR "
                         "filter (1-10)")
    summing = cube.number("SpatialSumming") if "SpatialSumming" in cube.instrument else 1.0
    tdi = str(cube.inst("TimeDelayIntegration")).strip().upper() == "ENABLED"
    detector_line = float((THEMIS_IR_LINE_TDI if tdi else THEMIS_IR_LINE_NO_TDI)[band - 1])
    offset = cube.seconds("SpacecraftClockOffset", "s") \
        if "SpacecraftClockOffset" in cube.instrument else 0.0
    start = (cube.clock_et("SpacecraftClockCount") + offset
             + (detector_line - 0.5) * THEMIS_IR_LINE_TIME)
    along = 120.5 - detector_line + THEMIS_IR_ALONG[band - 1]
    origin = 160.5 - THEMIS_IR_BORESIGHT[band - 1]
    note = None
    if len(filters) > 1:
        note = (f"THEMIS IR: the geometry of band 1 (filter {band}) of {len(filters)}; "
                "each filter sits on its own detector line")
    itrans = (cube.key(f"{ins}_ITRANSS", 3).tolist(), cube.key(f"{ins}_ITRANSL", 3).tolist())
    if not np.allclose(np.abs([itrans[0][1], itrans[1][2]]), 20.0, rtol=1e-6):
        raise InputError(f"{cube.path}: NaifKeywords '{ins}_ITRANSS/L' are not THEMIS IR's "
                         "0.05 mm pixels")
    return dict(start=start, rate=THEMIS_IR_LINE_TIME * summing, itrans=itrans,
                focal=THEMIS_IR_FOCAL, center=(-along, origin - 0.5), first_sample=0.0,
                summing=summing, note=note,
                distortion={"themisir": {"p_k": THEMIS_IR_K[band - 1],
                                         "p_alpha1": THEMIS_IR_ALPHA[0],
                                         "p_alpha2": THEMIS_IR_ALPHA[1]}})


MOC_WA_CODES = (-94032, -94033)
#: MocWideAngleCamera / MocWideAngleDistortionMap by filter: detector origin sample and
#: along-track offset (ISIS pixels), distortion [y scale, c0 … c5].
MOC_WA = {"RED": dict(origin=1674.65, offset=6.7785,
                      distortion=[1.0, 0.9993258, 0.4655529, -0.1548756, 1.827967,
                                  -3.057435, 2.226331]),
          "BLUE": dict(origin=1688.58, offset=-0.8486,
                       distortion=[1.000452, 1.000246, 0.4612695, 0.2352545, 0.3535922,
                                   -0.2853861, 0.5574971])}
#: The MOC-WA red IK's constants (moc20.ti / mocAddendum, as spiceinit copies them into a
#: cube's NaifKeywords) for red cubes of the old label layout.
MOC_WA_RED_IK = {"focal": 11.20537656, "itrans": ([0.0, 0.0, -142.8571429],
                                                  [0.0, 142.8571429, 0.0])}


def moc_wa(cube, ins: str) -> dict:
    """The timing and interior of a MOC-WA cube (module docstring)."""
    band_bin = cube.cube.get("BandBin", {})
    colour = str(band_bin.get("FilterName", "")).strip().upper()
    if colour not in MOC_WA:
        raise InputError(f"{cube.path}: BandBin 'FilterName' {colour!r} is not a MOC-WA "
                         "filter (RED, BLUE)")
    crosstrack = int(cube.number("CrosstrackSumming"))
    if crosstrack in (13, 27):
        raise InputError(f"{cube.path}: MOC-WA CrosstrackSumming {crosstrack} is a variable "
                         "summing mode (ISIS's per-sample MocWideAngleDetectorMap table), "
                         "which demtool does not reproduce; pass an ALE ISD")
    rate = cube.seconds("LineExposureDuration", "ms") * cube.number("DowntrackSumming")
    note = None
    if cube.naif is None:
        if colour != "RED":
            raise InputError(f"{cube.path}: a blue MOC-WA cube of the old label layout (no "
                             "NaifKeywords): its IK constants are not in the file; re-run "
                             "spiceinit, or pass an ALE ISD")
        start = _per_line_start(cube, rate)
        focal, itrans = MOC_WA_RED_IK["focal"], MOC_WA_RED_IK["itrans"]
        note = ("MGS MOC-WA red constants from its IK (the cube's old label layout has "
                "none), start time from the per-line tables")
    else:
        start = cube.clock_et("SpacecraftClockCount")
        focal = cube.scalar(f"{ins}_FOCAL_LENGTH")
        itrans = (cube.key(f"{ins}_ITRANSS", 3).tolist(), cube.key(f"{ins}_ITRANSL", 3).tolist())
    camera = MOC_WA[colour]
    return dict(start=start, rate=rate, itrans=itrans, focal=focal,
                center=(-camera["offset"], camera["origin"] - 0.5),
                first_sample=cube.number("FirstLineSample") - 1.0, summing=float(crosstrack),
                note=note, distortion={"mocwa": {"coefficients": camera["distortion"]}})


def _per_line_start(cube, rate: float) -> float:
    """The image's start ET from an old-layout cube's per-line pointing table: one record
    per parent line edge, evenly spaced by the line time (to 1e-4)."""
    from demtool.sensors.isis import _columns, _read_table, _tables

    tables = _tables(cube.label)
    table = _read_table(cube.path, cube.data, tables["InstrumentPointing"])
    times = _columns(cube.path, table, "InstrumentPointing", ["ET"])[:, 0]
    alpha = cube.cube.get("AlphaCube", {})
    dims = cube.cube.get("Core", {}).get("Dimensions", {})
    parent_lines = int(alpha.get("AlphaLines", dims.get("Lines", 0)))
    steps = np.diff(times)
    if (len(times) != parent_lines + 1 or len(steps) == 0
            or not np.allclose(steps, rate, rtol=1e-4, atol=0.0)):
        raise InputError(f"{cube.path}: the old-layout MOC cube's InstrumentPointing table "
                         f"({len(times)} records) is not one record per edge of its "
                         f"{parent_lines} lines at {rate:.7g} s: the image start time cannot "
                         "be derived (no NaifKeywords clock); pass an ALE ISD (isd_generate)")
    return float(times[0])
