"""Synthetic planetary scenes: terrain, albedo, cameras, rendered images and truth.

The pure core of ``demtool synth`` (no file I/O).  :func:`make_scene` builds and
renders a seeded scene from :class:`SceneParams`; :mod:`demtool.synth.truth` derives
ground truth (disparities, surface points) for the later stages' benchmarks.

Names are imported lazily, so ``demtool.synth.params`` (used by the command line)
does not pull in numba.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "SceneParams": "demtool.synth.params",
    "Scene": "demtool.synth.scene",
    "make_scene": "demtool.synth.scene",
    "make_cameras": "demtool.synth.scene",
    "make_terrain": "demtool.synth.scene",
    "TruthDisparity": "demtool.synth.truth",
    "Correspondence": "demtool.synth.truth",
    "truth_disparity": "demtool.synth.truth",
    "rectified_correspondence": "demtool.synth.truth",
    "target_points": "demtool.synth.truth",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'demtool.synth' has no attribute {name!r}")


def __dir__() -> list[str]:
    return __all__
