"""On-disk cache of SIFT features, keyed by image content and extraction parameters.

``select`` over hundreds of images extracts features once per image: a cache entry is
an NPZ file ``<cache dir>/<stem>-<key>.npz`` whose key is a SHA-256 over the image
file's content hash, the extraction parameters, the cache format and the OpenCV
version, so a changed image, parameter or library never reuses stale features.  The
cache is not a stage output: entries are written atomically as soon as they are made
(outside any output transaction), and unreadable entries are recomputed.
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from demtool import io as dio
from demtool.imaging.features import Features
from demtool.logs import get_logger
from demtool.provenance import file_sha256

log = get_logger(__name__)

CACHE_FORMAT = 1


class FeatureCache:
    """Feature cache in ``folder`` (created on first write); ``folder=None`` disables it.

    Attributes
    ----------
    hits, misses : int
        Counts since creation (for the stage report).
    """

    def __init__(self, folder: str | os.PathLike | None) -> None:
        self.folder = Path(folder) if folder is not None else None
        self.hits = 0
        self.misses = 0
        self._lock = threading.Lock()

    def key(self, image_path: str | os.PathLike, params: Mapping[str, Any]) -> str:
        """Cache key of an image file and extraction parameters (hex)."""
        import cv2

        content = file_sha256(image_path) or ""
        description = json.dumps({"sha256": content, "params": dict(params),
                                  "format": CACHE_FORMAT, "opencv": cv2.__version__},
                                 sort_keys=True, default=str)
        return hashlib.sha256(description.encode()).hexdigest()[:32]

    def _path(self, image_path: str | os.PathLike, key: str) -> Path:
        assert self.folder is not None
        return self.folder / f"{Path(image_path).stem}-{key}.npz"

    def load(self, image_path: str | os.PathLike, key: str) -> Features | None:
        """Cached features under ``key`` (see :meth:`key`), or None (disabled, absent, bad)."""
        if self.folder is None:
            return None
        path = self._path(image_path, key)
        if not path.is_file():
            return None
        try:
            with np.load(path, allow_pickle=False) as npz:
                found = Features.from_arrays({k: npz[k] for k in npz.files})
        except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as exc:
            log.debug("%s: ignoring unreadable cache entry (%s)", path, exc)
            return None
        return found

    def store(self, image_path: str | os.PathLike, key: str, found: Features) -> None:
        """Write the features of an image under ``key`` (atomically; failures only logged)."""
        if self.folder is None:
            return
        path = self._path(image_path, key)
        try:
            with dio.atomic_path(path, suffix=".npz") as temporary:
                with open(temporary, "wb") as handle:
                    np.savez(handle, **found.to_arrays())
        except OSError as exc:
            log.warning("%s: cannot write the feature cache (%s); continuing without it",
                        path, exc)

    def get_or_compute(self, image_path: str | os.PathLike, params: Mapping[str, Any],
                       compute: Callable[[], Features]) -> Features:
        """Cached features of the image for ``params``, or ``compute()`` and store them."""
        if self.folder is None:
            return compute()
        key = self.key(image_path, params)
        found = self.load(image_path, key)
        with self._lock:
            if found is not None:
                self.hits += 1
            else:
                self.misses += 1
        if found is None:
            found = compute()
            self.store(image_path, key, found)
        return found
