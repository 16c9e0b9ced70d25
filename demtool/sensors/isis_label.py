"""The PVL label of an ISIS3 cube, read once for the camera reader
(:mod:`demtool.sensors.isis`) and the map-projection reader (:mod:`demtool.sensors.isis_map`)."""

from __future__ import annotations

import threading
from collections import OrderedDict
from pathlib import Path

from demtool.errors import InputError

#: The last few labels parsed, by (path, size, mtime): a cube is looked at by the
#: refusals, the dispatch and its camera reader in turn, and PVL parsing of a 64 KiB
#: label takes a second or more (files up to 64 MiB; the bytes are kept with the label).
#: Callers never modify a label.
_CACHE: OrderedDict = OrderedDict()
_CACHE_SIZE = 4
_CACHE_BYTES = 64 * 2 ** 20
_CACHE_LOCK = threading.Lock()


def read_label(path: Path) -> tuple[dict, bytes]:
    """The parsed PVL label (``pvl``'s module) of an ISIS3 cube and the file's bytes.

    Raises
    ------
    InputError
        Unreadable file, not an ISIS3 cube, or a label PVL cannot parse.
    """
    try:
        stat = path.stat()
        key = (str(Path(path).resolve()), stat.st_size, stat.st_mtime_ns)
    except OSError:
        key = None
    with _CACHE_LOCK:
        if key is not None and key in _CACHE:
            _CACHE.move_to_end(key)
            return _CACHE[key]
    result = _parse(path)
    if key is not None and len(result[1]) <= _CACHE_BYTES:  # big cubes are not kept
        with _CACHE_LOCK:
            _CACHE[key] = result
            while len(_CACHE) > _CACHE_SIZE:
                _CACHE.popitem(last=False)
    return result


def _parse(path: Path) -> tuple[dict, bytes]:
    import warnings

    with warnings.catch_warnings():  # pvl notes the optional multidict package is absent
        warnings.simplefilter("ignore", ImportWarning)
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        import pvl

    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read cube ({exc.strerror or exc})") from None
    if not data.lstrip().startswith(b"Object = IsisCube") and b"IsisCube" not in data[:200]:
        raise InputError(f"{path}: not an ISIS3 cube (no 'Object = IsisCube' label)")
    end = data.find(b"\nEnd\n")
    if end < 0:
        end = data.find(b"\nEnd\r\n")
    text = data[: end + 5 if end >= 0 else 65536].decode("latin-1")
    try:
        with warnings.catch_warnings():  # pvl's Units class (for '<meters>') is deprecated
            warnings.simplefilter("ignore", PendingDeprecationWarning)
            label = pvl.loads(text)
    except Exception as exc:  # pvl raises several parser errors
        detail = str(exc).splitlines()[0] if str(exc).strip() else "it ends early"
        raise InputError(f"{path}: cannot parse the ISIS label ({detail}): a truncated label "
                         "or not an ISIS3 cube") from None
    return label, data
