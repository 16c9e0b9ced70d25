"""What kind of ISIS camera a cube holds, and the one-line refusals of cubes no camera
model can be built from.

ISIS picks a cube's camera class from its ``Instrument`` group (``CameraFactory``, the
``Camera.plugin`` table of ``SpacecraftName``/``InstrumentId``); the instrument code
whose ``INS<code>_…`` keywords describe the camera is ``Kernels``' ``NaifFrameCode`` when
present, else its ``NaifIkCode`` (ISIS ``Spice::init``: ``trykey = "NaifIkCode"; if
(kernels.hasKeyword("NaifFrameCode")) trykey = "NaifFrameCode"``).  The geometry needs
no frame code: the ``InstrumentPointing`` table's quaternions (``TimeDependentFrames``)
and ``ConstantRotation`` (``ConstantFrames``) already end in the instrument frame.

Refused, each with its true reason (:func:`refuse_unread_kinds`):

- a map-projected cube (``Mapping`` group, ISIS ``cam2map``; ``Planar`` and
  ``RingCylindrical`` are projections onto a planet's ring plane);
- a synthetic-aperture radar (ISIS ``MiniRF : RadarCamera``, LRO Mini-RF and
  Chandrayaan-1 Mini-SAR): range/Doppler geometry, not an optical camera;
- no SPICE attached: a ``Kernels`` group with the NAIF code only (level-0/1 cubes
  before ``spiceinit``), or kernel files named but no ``Table`` (``spiceinit
  attach=false``);
- tables named ``Table`` in the ``Kernels`` group but not attached to the file.

References: DOI-USGS/ISIS3 ``isis/src/base/objs/Spice/Spice.cpp``,
``isis/src/base/objs/CameraFactory/CameraFactory.cpp``,
``isis/src/lro/objs/MiniRF/MiniRF.cpp``, ``isis/src/base/objs/RingPlaneProjection``.
"""

from __future__ import annotations

from pathlib import Path

from demtool.errors import InputError

#: The four tables ``spiceinit attach=true`` writes, by the Kernels keyword naming each.
SPICE_TABLES = {"InstrumentPointing": "InstrumentPointing",
                "InstrumentPosition": "InstrumentPosition",
                "TargetAttitudeShape": "BodyRotation", "TargetPosition": "SunPosition"}
#: ``InstrumentId`` of ISIS's radar camera (``MiniRF : RadarCamera``).
SAR_INSTRUMENTS = ("MRFLRO", "CHANDRAYAAN1_MRFFR")
#: ISIS map projections onto a ring plane (``RingPlaneProjection`` subclasses).
RING_PROJECTIONS = ("PLANAR", "RINGCYLINDRICAL")
#: ``InstrumentId`` of ISIS push-frame cameras (``PushFrameCamera`` subclasses).
PUSH_FRAME_INSTRUMENTS = ("MARCI", "WAC-VIS", "WAC-UV", "THEMIS_VIS", "JNC", "MVIC_FRAMING")
#: ``InstrumentId`` of ISIS line-scan cameras without ``LineExposureDuration``.
LINE_SCAN_INSTRUMENTS = ("THEMIS_IR",)


def naif_ik_code(path: Path, label) -> int:
    """The instrument code of ``INS<code>_…`` keywords: ``Kernels``' ``NaifFrameCode``,
    else ``NaifIkCode`` (ISIS ``Spice::init``)."""
    kernels = label["IsisCube"].get("Kernels", {})
    key = "NaifFrameCode" if "NaifFrameCode" in kernels else "NaifIkCode"
    if key not in kernels:
        raise InputError(f"{path}: the Kernels group has neither 'NaifFrameCode' nor "
                         "'NaifIkCode' (the instrument's NAIF code)")
    try:
        return int(kernels[key])
    except (TypeError, ValueError):
        raise InputError(f"{path}: the Kernels keyword '{key}' is {kernels[key]!r}, not a "
                         "NAIF code") from None


def camera_kind(label) -> str:
    """``"frame"``, ``"linescan"`` or ``"pushframe"``: the ISIS camera class of the
    cube's instrument (push-frame and the line-scan cameras without a
    ``LineExposureDuration`` by ``InstrumentId``; any other with one is a line scan)."""
    instrument = label["IsisCube"].get("Instrument", {})
    ident = str(instrument.get("InstrumentId", "")).upper()
    if ident in PUSH_FRAME_INSTRUMENTS:
        return "pushframe"
    if ident in LINE_SCAN_INSTRUMENTS or "LineExposureDuration" in instrument:
        return "linescan"
    return "frame"


def refuse_cube_kind(path: Path) -> None:
    """:func:`refuse_unread_kinds` of the cube at ``path`` (its label read here), before
    any value of the label is checked: a radar's focal-plane keywords are no optical
    camera's."""
    from demtool.sensors.isis_label import read_label

    label, _ = read_label(path)
    refuse_unread_kinds(path, label)


def _tables(label) -> set[str]:
    return {str(obj.get("Name", "")) for key, obj in label.items() if key == "Table"}


def refuse_unread_kinds(path: Path, label) -> None:
    """Raise :class:`InputError` (one line naming the file) for a cube from which no
    camera model can be built (module docstring); return quietly otherwise."""
    cube = label["IsisCube"]
    mapping = cube.get("Mapping")
    if mapping is not None:
        from demtool.sensors.isis_map import mapping_summary

        projection = str(mapping.get("ProjectionName", "")).upper()
        where = (" onto the ring plane" if projection in RING_PROJECTIONS else "")
        raise InputError(f"{path}: is a map-projected cube{where} "
                         f"({mapping_summary(mapping)}): its "
                         "pixels lie on that map, not in the camera; use it as a map, or "
                         "the raw image's cube or ISD for a camera model")
    instrument = cube.get("Instrument", {})
    ident = str(instrument.get("InstrumentId", "")).upper()
    if ident in SAR_INSTRUMENTS or str(instrument.get("InstrumentModeDesc", "")).upper() \
            == "SAR":
        raise InputError(f"{path}: is a synthetic-aperture radar image ({ident or 'SAR'}, "
                         "ISIS's MiniRF radar camera): range and Doppler geometry, not an "
                         "optical camera; demtool does not model SAR")
    kernels = cube.get("Kernels")
    if kernels is None:
        raise InputError(f"{path}: the cube has no Kernels group: no SPICE attached (run "
                         "'spiceinit attach=true' in ISIS, or pass an ALE ISD)")
    attached = _tables(label)
    named = [key for key in SPICE_TABLES if _names_table(kernels.get(key))]
    absent_named = [key for key in named if SPICE_TABLES[key] not in attached]
    if absent_named:
        raise InputError(f"{path}: the Kernels group names 'Table' for "
                         f"{', '.join(absent_named)} but the file has no "
                         f"{SPICE_TABLES[absent_named[0]]} table attached: its geometry is "
                         "missing (re-run 'spiceinit attach=true' on the full cube)")
    missing = [t for t in ("InstrumentPointing", "InstrumentPosition", "BodyRotation",
                           "SunPosition") if t not in attached]
    if len(missing) == 4:
        what = ("the Kernels group holds only the NAIF code"
                if not any(k in kernels for k in SPICE_TABLES)
                else "kernel files named, no table attached")
        raise InputError(f"{path}: the cube has no SPICE attached ({what}): run "
                         "'spiceinit attach=true' in ISIS, or pass an ALE ISD "
                         "(isd_generate)")
    if missing:
        raise InputError(f"{path}: the cube has no {missing[0]} table (SPICE partly "
                         "attached); run 'spiceinit attach=true' in ISIS, or pass an ALE ISD")


def _names_table(value) -> bool:
    values = value if isinstance(value, (list, tuple)) else [value]
    return any(str(v).strip() == "Table" for v in values)
