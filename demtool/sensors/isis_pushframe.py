"""ISIS push-frame cubes (MRO MARCI, LRO WAC, THEMIS VIS, JunoCam, New Horizons MVIC
framing): ISIS's ``PushFrameCamera`` subclasses.

Their framelets are described by per-mission keywords and code (``MarciCamera``: the
filters' CCD offsets ``INS-74400_BAND_CCD_OFFSET``, ``ColorOffset``, ``DataFlipped``,
``VariableExposureDuration``/``FrameNumber`` and ``MarciDistortionMap``;
``LroWideAngleCamera``: per-band framelet offsets and ``LroWideAngleCameraDistortionMap``),
which demtool does not reproduce from a cube: such a cube is refused in one line
naming the camera, and its ALE ISD (``isd_generate``, usgscsm's push-frame model) is
read instead.

References: DOI-USGS/ISIS3 ``isis/src/mro/objs/MarciCamera/MarciCamera.cpp``,
``isis/src/lro/objs/LroWideAngleCamera/LroWideAngleCamera.cpp``,
``isis/src/base/objs/PushFrameCameraDetectorMap``.
"""

from __future__ import annotations

from pathlib import Path

from demtool.errors import InputError


def read_pushframe_cube(path: Path, label, data: bytes):
    """Refuse an ISIS push-frame cube in one line (module docstring)."""
    instrument = label["IsisCube"].get("Instrument", {})
    ident = str(instrument.get("InstrumentId", "")) or "an unnamed camera"
    raise InputError(f"{path}: is a push-frame cube of {ident} (ISIS PushFrameCamera, "
                     "framelets with per-filter offsets): demtool does not build this "
                     "camera from a cube; pass its ALE ISD (isd_generate) instead")
