"""Semi-global matching (Hirschmüller 2008) of a rectified stereo pair.

``sgm(left, right, *, min_disparity, num_disparities, ...)`` returns the left image's
disparity (``x_right = x_left − d``, float32 pixels, NaN = invalid) and a confidence
map.  Modules: :mod:`~demtool.sgm.cost` (census, absolute difference and table costs;
window-summed cost rows), :mod:`~demtool.sgm.mutual_information` (the MI cost table),
:mod:`~demtool.sgm.aggregate` (8/16-path aggregation sweeps, numba),
:mod:`~demtool.sgm.disparity` (WTA, sub-pixel, left–right check, speckles, median),
:mod:`~demtool.sgm.strips` (one pass: strips, sweep threads, timing),
:mod:`~demtool.sgm.passes` (one cost's pass: MI iterations, the HMI pyramid, filters,
fill), :mod:`~demtool.sgm.auto` (the default cost's rules and passes),
:mod:`~demtool.sgm.matcher` (the public :func:`sgm`).

Names are imported lazily (PEP 562), so ``demtool sgm --help`` and the
parameter module ``demtool.sgm.params`` do not pull in numba, OpenCV or pycolmap.
"""

from demtool.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "matcher": ("COST_DEFAULTS", "COSTS", "SGMResult", "sgm"),
    "strips": ("plan_strips",),
})
