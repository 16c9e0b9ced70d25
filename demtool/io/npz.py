"""NPZ files with schemas: ``format_version`` and ``kind`` in every file, one schema per
kind (keys, shapes, dtypes) checked on write and on read, naming the file and the key.
Part of :mod:`demtool.io`'s interface (``io.write_npz``, ``io.read_npz``, ``io.NPZ_SCHEMAS``).
"""

from __future__ import annotations

import os
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from demtool.errors import InputError
from demtool.io.files import _first_line, require_file
from demtool.outputs import atomic_path

# 2: cameras/bundle files may carry an optional 'distortion' array (see NPZ_SCHEMAS).
# 3: rectification files may be calibrated (NPZ_OPTIONAL_SCHEMAS: the two sensor models).
NPZ_FORMAT_VERSION = 3


# Shape patterns: ints are fixed sizes, strings are named sizes that must agree across
# the keys of one file, "*" is any size.  dtype kinds: "f" float, "i" integer
# (signed or unsigned), "b" bool, "U" string.
NPZ_SCHEMAS: dict[str, dict[str, tuple[tuple, str]]] = {
    "cameras": {
        "names": (("N",), "U"),
        "K": (("N", 3, 3), "f"),
        "R": (("N", 3, 3), "f"),
        "t": (("N", 3), "f"),
        "width": (("N",), "i"),
        "height": (("N",), "i"),
        # optional (format 2): "distortion" (N, 5) OpenCV k1, k2, p1, p2, k3 per camera;
        # checked by demtool.sensors.pinhole.cameras_from_arrays
    },
    "rectification": {
        "H_left": ((3, 3), "f"),
        "H_right": ((3, 3), "f"),
        "F": ((3, 3), "f"),
        "size_left": ((2,), "i"),  # (width, height) of the original left image
        "size_right": ((2,), "i"),
        "size_rect": ((2,), "i"),  # (width, height) of the rectified canvas
        "points_left": (("N", 2), "f"),  # inlier matches, original pixel coordinates (x, y)
        "points_right": (("N", 2), "f"),
        "points_left_rect": (("N", 2), "f"),  # the same, rectified coordinates
        "points_right_rect": (("N", 2), "f"),
        "disparity_range": ((2,), "f"),  # (min, max) of x_left - x_right, with margin
        "left_name": ((), "U"),
        "right_name": ((), "U"),
    },
    "bundle": {
        "points": (("N", 3), "f"),
        "colors": (("N",), "f"),  # mean intensity of the track
        "track_length": (("N",), "i"),
        "reprojection_error": (("N",), "f"),  # pixels, mean over the track
        "image_names": (("M",), "U"),
        "K": (("M", 3, 3), "f"),
        "R": (("M", 3, 3), "f"),
        "t": (("M", 3), "f"),
        "width": (("M",), "i"),
        "height": (("M",), "i"),
        "target_index": ((), "i"),
        "aligned": ((), "b"),  # True when a similarity put the model in metric coordinates
        # optional: "distortion" (M, 2) COLMAP radial k1, k2, or (M, 5) OpenCV coefficients
    },
    "matches": {
        "points_left": (("N", 2), "f"),
        "points_right": (("N", 2), "f"),
        "left_name": ((), "U"),
        "right_name": ((), "U"),
    },
}


# Keys a kind may carry (format 3), checked when present; a calibrated rectification
# (``calibrated`` true, from ``rectify --sensor-left/--sensor-right``) must have them all,
# and its two sensor models under ``sensor_left_*`` / ``sensor_right_*``
# (demtool.sensors.arrays, read back by demtool.dem.run).
NPZ_OPTIONAL_SCHEMAS: dict[str, dict[str, tuple[tuple, str]]] = {
    "rectification": {
        "calibrated": ((), "b"),
        "R_rect": ((3, 3), "f"),  # body-fixed -> rectified camera frame (rows x, y, z)
        "K_left_rect": ((3, 3), "f"),  # rectified intrinsics, pixels
        "K_right_rect": ((3, 3), "f"),
        "pointing_correction": ((3, 3), "f"),  # applied to the right model, body frame
        "pointing_correction_mrad": ((3,), "f"),  # rotation vector, rectified frame
        "sensor_left_type": ((), "U"),
        "sensor_right_type": ((), "U"),
    },
}


# Keys whose every value is a number a geometry can use (issue 46: a NaN in a camera's K
# went on unnoticed); their cameras' focal lengths K[0, 0], K[1, 1] must be positive.
FINITE_KEYS = {"cameras": ("K", "R", "t"), "bundle": ("K", "R", "t"),
               "rectification": ("H_left", "H_right", "F")}
_NAMES_KEY = {"cameras": "names", "bundle": "image_names"}


def _check_values(path: Path, kind: str, arrays: Mapping[str, np.ndarray]) -> None:
    """Refuse a non-finite value in :data:`FINITE_KEYS` or a focal length ≤ 0, naming
    the key, the camera and the value."""
    names = np.asarray(arrays.get(_NAMES_KEY.get(kind, ""), []))

    def which(index: tuple) -> str:
        if names.ndim == 1 and index and index[0] < len(names):
            return f" of camera {names[index[0]]}"
        return ""

    for key in FINITE_KEYS.get(kind, ()):
        value = np.asarray(arrays[key], dtype=np.float64)
        bad = np.argwhere(~np.isfinite(value))
        if len(bad):
            index = tuple(int(i) for i in bad[0])
            raise InputError(f"{path}: '{key}'{which(index)} holds {value[index]} at "
                             f"{list(index)}: not a number a camera can have")
    if "K" in FINITE_KEYS.get(kind, ()):
        K = np.asarray(arrays["K"], dtype=np.float64)
        focal = np.stack([K[..., 0, 0], K[..., 1, 1]], axis=-1)
        bad = np.argwhere(focal <= 0)
        if len(bad):
            index = tuple(int(i) for i in bad[0][:-1])
            raise InputError(f"{path}: 'K'{which(index)} has the focal length "
                             f"{focal[(*index, bad[0][-1])]:g} px: it must be positive")


def _check_array(path: Path, kind: str, key: str, value: np.ndarray, pattern: tuple,
                 dtype_kind: str, sizes: dict[str, int]) -> None:
    kinds = {"f": "fc", "i": "iu", "b": "b", "U": "U"}[dtype_kind]
    if value.dtype.kind not in kinds:
        wanted = {"f": "float", "i": "integer", "b": "bool", "U": "string"}[dtype_kind]
        raise InputError(f"{path}: '{key}' of {kind} file has dtype {value.dtype}, "
                         f"expected {wanted}")
    if value.ndim != len(pattern):
        raise InputError(f"{path}: '{key}' of {kind} file has shape {value.shape}, "
                         f"expected {len(pattern)} dimension(s) {pattern}")
    for axis, (size, want) in enumerate(zip(value.shape, pattern, strict=True)):
        if want == "*":
            continue
        if isinstance(want, int):
            if size != want:
                raise InputError(f"{path}: '{key}' of {kind} file has shape {value.shape}, "
                                 f"expected {pattern}")
        elif sizes.setdefault(want, size) != size:
            raise InputError(f"{path}: '{key}' of {kind} file has {size} entries along axis "
                             f"{axis}, but other arrays have {want}={sizes[want]}")


def validate_npz(path: Path, kind: str, arrays: Mapping[str, np.ndarray]) -> None:
    """Check ``arrays`` against the schema of ``kind``; raise InputError naming the key."""
    if kind not in NPZ_SCHEMAS:
        raise ValueError(f"unknown NPZ kind {kind!r}; known: {', '.join(NPZ_SCHEMAS)}")
    sizes: dict[str, int] = {}
    for key, (pattern, dtype_kind) in NPZ_SCHEMAS[kind].items():
        if key not in arrays:
            raise InputError(f"{path}: {kind} file lacks the key '{key}'")
        _check_array(path, kind, key, np.asarray(arrays[key]), pattern, dtype_kind, sizes)
    _check_values(path, kind, arrays)
    optional = NPZ_OPTIONAL_SCHEMAS.get(kind, {})
    if kind == "rectification" and "calibrated" in arrays and bool(arrays["calibrated"]):
        for key in optional:
            if key not in arrays:
                raise InputError(f"{path}: calibrated {kind} file lacks the key '{key}'")
    for key, (pattern, dtype_kind) in optional.items():
        if key in arrays:
            _check_array(path, kind, key, np.asarray(arrays[key]), pattern, dtype_kind, sizes)


def write_npz(path: str | os.PathLike, kind: str, arrays: Mapping[str, Any]) -> Path:
    """Write an NPZ file of a known ``kind`` atomically, after checking its schema.

    Extra keys beyond the schema are allowed (and kept).  ``format_version`` and
    ``kind`` are added.
    """
    p = Path(path)
    content = {key: np.asarray(value) for key, value in arrays.items()}
    validate_npz(p, kind, content)
    content["format_version"] = np.asarray(NPZ_FORMAT_VERSION)
    content["kind"] = np.asarray(kind)
    with atomic_path(p, suffix=".npz") as temporary:
        with open(temporary, "wb") as handle:
            np.savez_compressed(handle, **content)
    return p


def read_npz(path: str | os.PathLike, kind: str) -> dict[str, np.ndarray]:
    """Read an NPZ file of ``kind``, checking its kind, version, keys, shapes and dtypes.

    Returns
    -------
    dict of str to ndarray
        All arrays of the file; 0-d arrays stay 0-d (use ``.item()``).

    Raises
    ------
    InputError
        Missing or corrupt file, another kind, a missing key or a wrong shape/dtype.
    """
    p = require_file(path, f"{kind} file")
    if not zipfile.is_zipfile(p):  # else np.load tries it as a pickle and says so
        raise InputError(f"{p}: not a readable NPZ file (not a zip archive); expected a {kind} "
                         "file")
    try:
        # Our own handle: np.load leaks its own when a truncated archive fails to open.
        with open(p, "rb") as handle, np.load(handle, allow_pickle=False) as npz:
            content = {key: npz[key] for key in npz.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise InputError(f"{p}: not a readable NPZ file ({_first_line(exc)})") from None
    if "kind" not in content:
        raise InputError(f"{p}: not a demtool NPZ file (no 'kind' entry); expected a {kind} file")
    found = str(content["kind"])
    if found != kind:
        raise InputError(f"{p}: is a {found} file, expected a {kind} file")
    version = int(content.get("format_version", -1))
    if version > NPZ_FORMAT_VERSION:
        raise InputError(f"{p}: format_version {version} is newer than this demtool "
                         f"understands ({NPZ_FORMAT_VERSION}); upgrade demtool")
    validate_npz(p, kind, content)
    return content
