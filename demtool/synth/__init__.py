"""Synthetic planetary scenes: terrain, albedo, cameras, rendered images and truth.

The pure core of ``demtool synth`` (no file I/O).  :func:`make_scene` builds and
renders a seeded scene from :class:`SceneParams`; :mod:`demtool.synth.truth` derives
ground truth (disparities, surface points) for the later stages' benchmarks.

Names are imported lazily, so ``demtool.synth.params`` (used by the command line)
does not pull in numba.
"""

from demtool.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "params": ("SceneParams",),
    "scene": ("Scene", "make_scene", "make_cameras", "make_terrain"),
    "truth": ("TruthDisparity", "Correspondence", "truth_disparity", "rectified_correspondence",
        "target_points"),
})
