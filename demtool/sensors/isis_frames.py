"""Interior orientation of ISIS frame cameras whose constants are not all ``INS<code>``
keywords of the cube: ISIS's mission camera classes, reproduced.

==============  ===================================================================
camera          what ISIS's camera class does (and this module)
==============  ===================================================================
MESSENGER MDIS  ``MdisCamera``: the Kernels code is the camera's (−236800 WAC, −236820
                NAC); the WAC filter's code is ``code − BandBin/Number`` (``fnCode``),
                whose ``INS<fnCode>_ITRANSS/L`` map the focal plane and whose
                ``_OD_T_X``/``_OD_T_Y`` are the Taylor distortion
                (``TaylorCameraDistortionMap``, usgscsm's ``transverse``); boresight
                ``INS<code>_BORESIGHT_SAMPLE/LINE``; the focal length temperature
                dependent, ``Σ INS<fnCode>_FL_TEMP_COEFFS[i] · T^i`` with ``T`` the
                ``FocalPlaneTemperature`` (°C) — ``spiceinit`` stores the value as
                ``TempDependentFocalLength``, read first; summing ``PixelBinningMode``
                (0 → 1) doubled by FPU binning (``FpuBinningMode`` 1), which also moves
                the first detector pixel to ``INS<code>_FPUBIN_START_SAMPLE/LINE``
TGO CaSSIS      ``TgoCassisCamera``: ``INS<code>`` focal length, ``ITRANSS/L`` and boresight
                (the detector origin), summing ``2 × SummingMode`` (0: none), and
                ``TgoCassisDistortionMap`` (``_OD_A1/2/3_CORR``, the ``cassis`` model)
Viking VIS      ``VikingCamera``: focal length by spacecraft and camera (474.398,
                474.448 mm for VO1 A, B; 474.610, 474.101 mm for VO2 A, B), detector
                origin (602, 528); ISIS's ``ReseauDistortionMap`` reads the reseau
                positions from the ``$viking`` data area, not from the cube: the model
                is ideal, as ALE's Viking drivers write it (a note says so)
==============  ===================================================================

References: DOI-USGS/ISIS3 ``isis/src/messenger/objs/MdisCamera/MdisCamera.cpp``,
``isis/src/tgo/objs/TgoCassisCamera/`` (camera and distortion map)
(``computeFocalLength``), ``isis/src/base/objs/TaylorCameraDistortionMap``,
``isis/src/viking/objs/VikingCamera/VikingCamera.cpp``; DOI-USGS/ale
``ale/drivers/viking_drivers.py``, ``ale/drivers/mess_drivers.py``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from demtool.errors import InputError
from demtool.sensors.distortion import Distortion

CASSIS_CODE = -143400
MDIS_WAC_CODE = -236800
MDIS_NAC_CODE = -236820
#: VikingCamera's focal lengths (mm) by (SpacecraftName, InstrumentId).
VIKING_FOCAL = {("VIKING_ORBITER_1", "VISUAL_IMAGING_SUBSYSTEM_CAMERA_A"): 474.398,
                ("VIKING_ORBITER_1", "VISUAL_IMAGING_SUBSYSTEM_CAMERA_B"): 474.448,
                ("VIKING_ORBITER_2", "VISUAL_IMAGING_SUBSYSTEM_CAMERA_A"): 474.610,
                ("VIKING_ORBITER_2", "VISUAL_IMAGING_SUBSYSTEM_CAMERA_B"): 474.101}
#: VikingCamera's detector origin (ISIS 1-based sample, line).
VIKING_ORIGIN = (602.0, 528.0)


@dataclass(frozen=True)
class FrameInterior:
    """A frame camera's interior orientation in ISIS's terms.

    ``focal`` mm; ``itrans_sample``/``itrans_line`` (3,) focal plane (mm) → detector
    pixels; ``center_*`` the detector origin (ISIS 1-based); ``start_*`` the first
    detector pixel of the parent image (CSM, 0-based) and ``binning`` the detector
    pixels per parent pixel; ``distortion``; ``notes`` what the model leaves out.
    """

    focal: float
    itrans_sample: np.ndarray
    itrans_line: np.ndarray
    center_sample: float
    center_line: float
    distortion: Distortion | None = None
    start_sample: float = 0.0
    start_line: float = 0.0
    binning: float = 1.0
    notes: tuple = field(default_factory=tuple)


def naif_values(path: Path, naif, key: str, size: int | None = None) -> np.ndarray:
    """A NaifKeywords value as a float64 array (InputError naming the cube and the key
    when it is absent or has another number of values than ``size``)."""
    if key not in naif:
        raise InputError(f"{path}: NaifKeywords lacks the key '{key}'")
    value = np.atleast_1d(np.asarray(naif[key], dtype=np.float64))
    if size is not None and value.size != size:
        raise InputError(f"{path}: NaifKeywords '{key}' has {value.size} values, expected {size}")
    return value


def _number(path: Path, group, name: str, key: str, default=None) -> float:
    if key not in group:
        if default is not None:
            return float(default)
        raise InputError(f"{path}: the {name} group lacks the key '{key}'")
    value = group[key]
    try:
        return float(getattr(value, "value", value))
    except (TypeError, ValueError):
        raise InputError(f"{path}: the {name} key '{key}' is {value!r}, not a number") \
            from None


def mission_interior(path: Path, label, naif, code: int) -> FrameInterior | None:
    """The interior of an MDIS, CaSSIS or Viking frame cube (module docstring); None for another
    camera (described by its ``INS<code>`` keywords alone)."""
    if code in (MDIS_WAC_CODE, MDIS_NAC_CODE):
        return _mdis(path, label, naif, code)
    if code == CASSIS_CODE:
        return _cassis(path, label, naif, code)
    instrument = label["IsisCube"].get("Instrument", {})
    viking = (str(instrument.get("SpacecraftName", "")).upper(),
              str(instrument.get("InstrumentId", "")).upper())
    if viking in VIKING_FOCAL:
        ins = f"INS{code}"
        return FrameInterior(
            focal=VIKING_FOCAL[viking], itrans_sample=naif_values(path, naif, f"{ins}_ITRANSS", 3),
            itrans_line=naif_values(path, naif, f"{ins}_ITRANSL", 3),
            center_sample=VIKING_ORIGIN[0], center_line=VIKING_ORIGIN[1],
            notes=("Viking reseau distortion not applied (ISIS's ReseauDistortionMap reads "
                   "the $viking reseau files; ALE's drivers write none either)",))
    return None


def _mdis(path: Path, label, naif, code: int) -> FrameInterior:
    cube = label["IsisCube"]
    instrument = cube.get("Instrument", {})
    filter_number = 0
    if code == MDIS_WAC_CODE:
        filter_number = int(_number(path, cube.get("BandBin", {}), "BandBin", "Number"))
    ins, fn = f"INS{code}", f"INS{code - filter_number}"
    if "TempDependentFocalLength" in naif:
        focal = float(naif_values(path, naif, "TempDependentFocalLength", 1)[0])
    elif f"{fn}_FL_TEMP_COEFFS" in naif:
        coefficients = naif_values(path, naif, f"{fn}_FL_TEMP_COEFFS")
        temperature = _number(path, instrument, "Instrument", "FocalPlaneTemperature")
        focal = float(np.polynomial.polynomial.polyval(temperature, coefficients))
    else:
        focal = float(naif_values(path, naif, f"{fn}_FOCAL_LENGTH", 1)[0])
    pixel_binning = int(_number(path, instrument, "Instrument", "PixelBinningMode", 0))
    fpu_binning = int(_number(path, instrument, "Instrument", "FpuBinningMode", 0))
    binning = float(max(pixel_binning, 1))
    start_s = start_l = 0.0
    if fpu_binning == 1:
        # ISIS SetStartingDetectorSample/Line (1-based): CSM's first detector pixel − 1
        start_s = float(naif_values(path, naif, f"{ins}_FPUBIN_START_SAMPLE", 1)[0]) - 1.0
        start_l = float(naif_values(path, naif, f"{ins}_FPUBIN_START_LINE", 1)[0]) - 1.0
        binning *= 2.0
    distortion = None
    if f"{fn}_OD_T_X" in naif or f"{fn}_OD_T_Y" in naif:
        distortion = Distortion("transverse", np.concatenate(
            [naif_values(path, naif, f"{fn}_OD_T_X", 10),
             naif_values(path, naif, f"{fn}_OD_T_Y", 10)]), focal)
    return FrameInterior(
        focal=focal, itrans_sample=naif_values(path, naif, f"{fn}_ITRANSS", 3),
        itrans_line=naif_values(path, naif, f"{fn}_ITRANSL", 3),
        center_sample=float(naif_values(path, naif, f"{ins}_BORESIGHT_SAMPLE", 1)[0]),
        center_line=float(naif_values(path, naif, f"{ins}_BORESIGHT_LINE", 1)[0]),
        distortion=distortion, start_sample=start_s, start_line=start_l, binning=binning)


def _cassis(path: Path, label, naif, code: int) -> FrameInterior:
    ins = f"INS{code}"
    instrument = label["IsisCube"].get("Instrument", {})
    mode = int(_number(path, instrument, "Instrument", "SummingMode", 0))
    pitch = float(naif_values(path, naif, f"{ins}_PIXEL_PITCH", 1)[0])
    half = (0.5 * pitch * float(naif_values(path, naif, f"{ins}_FILTER_SAMPLES", 1)[0]),
            0.5 * pitch * float(naif_values(path, naif, f"{ins}_FILTER_LINES", 1)[0]))
    terms = [naif_values(path, naif, f"{ins}_OD_A{i}_CORR", 6) for i in (1, 2, 3)]
    focal = float(naif_values(path, naif, f"{ins}_FOCAL_LENGTH", 1)[0])
    return FrameInterior(
        focal=focal, itrans_sample=naif_values(path, naif, f"{ins}_ITRANSS", 3),
        itrans_line=naif_values(path, naif, f"{ins}_ITRANSL", 3),
        center_sample=float(naif_values(path, naif, f"{ins}_BORESIGHT_SAMPLE", 1)[0]),
        center_line=float(naif_values(path, naif, f"{ins}_BORESIGHT_LINE", 1)[0]),
        distortion=Distortion("cassis", np.concatenate([half, *terms]), focal),
        binning=float(2 * mode) if mode > 0 else 1.0)
