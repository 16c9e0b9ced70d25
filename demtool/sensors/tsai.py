"""Reader of Ames Stereo Pipeline ``.tsai`` pinhole models (VisionWorkbench format).

A ``.tsai`` file holds ``VERSION_n``, ``PINHOLE``, the intrinsics ``fu fv cu cv``
(physical units or pixels), the camera axes ``u_direction v_direction w_direction``,
the camera centre ``C`` and the camera-to-world rotation ``R`` (row-major, 9 values)
in the body-fixed frame (e.g. ECEF), the pixel ``pitch``, then the lens model's name
and its ``key = value`` lines.  A world point P maps to camera coordinates
``Q = Rᵀ (P − C)`` and to the undistorted pixel
``(fu u·Q / w·Q + cu, fv v·Q / w·Q + cv) / pitch``; VisionWorkbench puts pixel centres
at integer coordinates, demtool's ``(u, v)`` convention (CSM ``line = v + 0.5``).

Lens models read: ``NULL``; ``TSAI`` (``k1 k2 p1 p2 [k3]``: OpenCV's radial-tangential
model on normalised coordinates, kept as the pinhole's Brown coefficients);
``BrownConrady`` (``xp yp k1 k2 k3 p1 p2 phi``) and ``Photometrix`` (``xp yp k1 k2
k3 p1 p2 b1 b2``; b1, b2 unused, as in VisionWorkbench), both defined from distorted
to undistorted physical focal-plane coordinates relative to ``(cu, cv)``; their
coefficients are rescaled to normalised coordinates (``fu = fv`` required).
Fisheye, FOV, RPC and AdjustableTSAI lenses are refused in one line.

The legacy VisionWorkbench layout (ASP's ``examples/K10/*.tsai``: no ``VERSION_n``,
``PINHOLE`` or lens-name lines, no ``pitch``) is read too: ``k1 k2 p1 p2`` lines after
``R`` imply a TSAI lens, as VisionWorkbench's ``PinholeModel::read`` does for files
without a version line.

References: ASP documentation "Pinhole models" (``docs/pinholemodels.rst``);
VisionWorkbench ``src/vw/Camera/PinholeModel.cc`` (``read``) and
``LensDistortion.cc`` (``undistorted_coordinates``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from demtool.errors import InputError
from demtool.sensors.base import SensorModel
from demtool.sensors.distortion import Distortion
from demtool.sensors.pinhole import PinholeCamera

_SIZES = {"fu": 1, "fv": 1, "cu": 1, "cv": 1, "u_direction": 3, "v_direction": 3,
          "w_direction": 3, "C": 3, "R": 9, "pitch": 1}
_LENSES = {"null": (), "none": (), "tsai": ("k1", "k2", "p1", "p2", "k3"),
           "brownconrady": ("xp", "yp", "k1", "k2", "k3", "p1", "p2", "phi"),
           "photometrix": ("xp", "yp", "k1", "k2", "k3", "p1", "p2", "b1", "b2")}
_OPTIONAL = {"k3", "b1", "b2"}


@dataclass(frozen=True, eq=False)
class TsaiCamera(PinholeCamera):
    """An ASP pinhole in a body-fixed frame (see the module docstring).

    Adds to :class:`PinholeCamera`: ``lens_model`` (a :class:`Distortion` on normalised
    coordinates, for lenses other than Brown/TSAI), ``body_radii`` (semi-major,
    semi-minor axes in metres, for :meth:`image_to_ground`; ``None`` when unknown)
    and ``pitch`` (the file's pixel pitch, kept for reference).
    """

    lens_model: Distortion | None = None
    body_radii: tuple[float, float] | None = None
    pitch: float = 1.0

    @property
    def radii(self):  # type: ignore[override]
        return self.body_radii

    @property
    def lens(self) -> Distortion:
        if self.lens_model is not None:
            return self.lens_model
        return super().lens

    @property
    def _has_lens(self) -> bool:
        if self.lens_model is not None:
            return not self.lens_model.is_identity
        return self.distortion is not None

    def image_to_ground(self, line, sample, height=0.0) -> np.ndarray:
        """Intersect the rays with the body's ellipsoid raised by ``height`` (metres).

        Raises ``ValueError`` when the body's radii are unknown (a ``.tsai`` file does
        not carry them: pass ``radii`` to :func:`read_tsai`).
        """
        if self.body_radii is None:
            raise ValueError(f"{self.name or 'tsai camera'}: the body's radii are unknown; "
                             "pass radii=(a, b) when reading the .tsai file")
        return SensorModel.image_to_ground(self, line, sample, height)


def _numbers(path: Path, number: int, key: str, text: str, size: int) -> np.ndarray:
    try:
        values = np.array([float(v) for v in text.split()], dtype=np.float64)
    except ValueError:
        raise InputError(f"{path}: line {number}: '{key}' has a non-numeric value "
                         f"({text.strip()!r})") from None
    if values.size != size or not np.all(np.isfinite(values)):
        raise InputError(f"{path}: line {number}: '{key}' needs {size} finite number"
                         f"{'s' if size > 1 else ''}, got {text.strip()!r}")
    return values


def parse_tsai(text: str, path: str | Path = "<tsai>") -> dict:
    """Parse the text of a ``.tsai`` file into its fields.

    Returns a dict with the pinhole keys of ``_SIZES`` (arrays), ``lens`` (the lens
    model's lower-case name) and ``lens_params`` (name → float).

    Raises
    ------
    InputError
        One line naming the file and the line number of the first malformed line, or
        the missing key.
    """
    path = Path(path)
    fields: dict = {}
    lens = None
    lens_params: dict[str, float] = {}
    started = False
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line:
            continue
        if "=" not in line:
            word = line.split()[0].lower()
            if len(line.split()) != 1:
                raise InputError(f"{path}: line {number}: cannot parse {line!r}")
            if word.startswith("version_") and not started and not fields:
                continue
            if word == "pinhole" and not fields:
                started = True
                continue
            if lens is None and "R" in fields:
                if word not in _LENSES:
                    raise InputError(f"{path}: line {number}: lens model {line!r} is not "
                                     "supported (NULL, TSAI, BrownConrady, Photometrix)")
                lens = word
                continue
            if word in ("optical_bar", "opticalbar", "cahvor", "cahvore", "cahv"):
                raise InputError(f"{path}: line {number}: a {line} camera is not a pinhole "
                                 "model demtool reads")
            raise InputError(f"{path}: line {number}: cannot parse {line!r}")
        key, _, value = (part.strip() for part in line.partition("="))
        if lens is None and key in _LENSES["tsai"] and key not in _SIZES and "R" in fields:
            lens = "tsai"  # VisionWorkbench's legacy layout: k1 k2 p1 p2 straight after R
        if lens is None:
            if key not in _SIZES:
                raise InputError(f"{path}: line {number}: unknown key '{key}'")
            fields[key] = _numbers(path, number, key, value, _SIZES[key])
        else:
            if key not in _LENSES[lens]:
                raise InputError(f"{path}: line {number}: unknown {lens} lens parameter "
                                 f"'{key}'")
            lens_params[key] = float(_numbers(path, number, key, value, 1)[0])
    for key in ("fu", "fv", "cu", "cv", "C", "R"):
        if key not in fields:
            raise InputError(f"{path}: lacks the key '{key}'")
    lens = lens or "null"
    missing = [k for k in _LENSES[lens] if k not in lens_params and k not in _OPTIONAL]
    if missing:
        raise InputError(f"{path}: the {lens} lens lacks the parameter '{missing[0]}'")
    fields["lens"] = lens
    fields["lens_params"] = lens_params
    return fields


def _lens(path: Path, lens: str, params: dict, fu: float, fv: float):
    """(Brown coefficients or None, Distortion or None) on normalised coordinates."""
    get = params.get
    if lens in ("null", "none"):
        return None, None
    if lens == "tsai":
        return np.array([get("k1"), get("k2"), get("p1"), get("p2"), get("k3", 0.0)]), None
    if not np.isclose(fu, fv, rtol=1e-12, atol=0.0):
        raise InputError(f"{path}: a {lens} lens with fu != fv ({fu} vs {fv}) is not "
                         "supported")
    f = fu
    scaled = [get("xp") / f, get("yp") / f, get("k1") * f ** 2, get("k2") * f ** 4,
              get("k3") * f ** 6, get("p1") * f, get("p2") * f ** 3]
    if lens == "brownconrady":  # tangential (p1 r² + p2 r⁴) / f
        return None, Distortion("brownconrady", scaled + [get("phi")])
    scaled[6] = get("p2") * f  # Photometrix: p2 (r² + 2y²) / f, like p1
    return None, Distortion("photometrix", scaled)


def read_tsai(path: str | Path, *, radii: tuple[float, float] | None = None) -> TsaiCamera:
    """Read an ASP ``.tsai`` pinhole model into a :class:`TsaiCamera`.

    Parameters
    ----------
    path : path-like
        The ``.tsai`` file.
    radii : (float, float), optional
        The body's semi-major and semi-minor axes (metres), needed by
        ``image_to_ground`` (the file does not carry them).

    Raises
    ------
    InputError
        Unreadable file, a malformed line (named by its number), a missing key, an
        unsupported lens model, a singular rotation.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8", errors="strict")
    except OSError as exc:
        raise InputError(f"{p}: cannot read .tsai file ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise InputError(f"{p}: not a text .tsai file") from None
    fields = parse_tsai(text, p)
    pitch = float(fields.get("pitch", np.ones(1))[0])
    fu, fv, cu, cv = (float(fields[k][0]) for k in ("fu", "fv", "cu", "cv"))
    if pitch <= 0 or fu <= 0 or fv <= 0:
        raise InputError(f"{p}: fu, fv and pitch must be positive (fu={fu}, fv={fv}, "
                         f"pitch={pitch})")
    axes = np.vstack([fields.get(k, np.eye(3)[i]) for i, k in
                      enumerate(("u_direction", "v_direction", "w_direction"))])
    rotation = fields["R"].reshape(3, 3)
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6):
        raise InputError(f"{p}: 'R' is not a rotation matrix")
    world_to_camera = axes @ rotation.T
    K = np.array([[fu / pitch, 0.0, cu / pitch], [0.0, fv / pitch, cv / pitch],
                  [0.0, 0.0, 1.0]])
    brown, lens_model = _lens(p, fields["lens"], fields["lens_params"], fu, fv)
    width = height = 0  # a .tsai file carries no image size
    return TsaiCamera(K=K, R=world_to_camera, t=-world_to_camera @ fields["C"], width=width,
                      height=height, distortion=brown, name=p.stem, lens_model=lens_model,
                      body_radii=None if radii is None else (float(radii[0]),
                                                             float(radii[1])),
                      pitch=pitch)
