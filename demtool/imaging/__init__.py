"""Image and numeric helpers shared by the stages (no stage imports another through them).

:mod:`~demtool.imaging.features` (SIFT extraction and matching, the one ``to_uint8``),
:mod:`~demtool.imaging.feature_cache` (features cached per image),
:mod:`~demtool.imaging.epipolar` (fundamental matrices, epipolar geometry),
:mod:`~demtool.imaging.homography` (rectification homographies: apply, invert, warp),
:mod:`~demtool.imaging.interpolate` (spring-metaphor gap filling),
:mod:`~demtool.imaging.reflectance` (lunar-Lambert, Lambert, the model registry),
:mod:`~demtool.imaging.spectral` (coherence, effective resolution),
:mod:`~demtool.imaging.robust` (robust statistics: NMAD),
:mod:`~demtool.imaging.checks` (texture, disparity-range and raster sanity checks).
"""
