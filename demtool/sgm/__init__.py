"""Semi-global matching (Hirschmüller 2008) of a rectified stereo pair.

``sgm(left, right, *, min_disparity, num_disparities, ...)`` returns the left image's
disparity (``x_right = x_left − d``, float32 pixels, NaN = invalid) and a confidence
map.  Modules: :mod:`~demtool.sgm.cost` (census, MI, absolute difference; windowed
cost volumes), :mod:`~demtool.sgm.aggregate` (8/16-path aggregation, numba),
:mod:`~demtool.sgm.disparity` (WTA, sub-pixel, left–right check, speckles, median),
:mod:`~demtool.sgm.matcher` (strips, MI iterations, the HMI pyramid).
"""

from demtool.sgm.matcher import COST_DEFAULTS, COSTS, SGMResult, plan_strips, sgm

__all__ = ["COSTS", "COST_DEFAULTS", "SGMResult", "plan_strips", "sgm"]
