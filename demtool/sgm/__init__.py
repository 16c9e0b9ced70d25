"""Semi-global matching (Hirschmüller 2008) of a rectified stereo pair.

``sgm(left, right, *, min_disparity, num_disparities, ...)`` returns the left image's
disparity (``x_right = x_left − d``, float32 pixels, NaN = invalid) and a confidence
map.  Modules: :mod:`~demtool.sgm.cost` (census, absolute difference and table costs;
window-summed cost rows), :mod:`~demtool.sgm.mutual_information` (the MI cost table),
:mod:`~demtool.sgm.aggregate` (8/16-path aggregation sweeps, numba),
:mod:`~demtool.sgm.disparity` (WTA, sub-pixel, left–right check, speckles, median),
:mod:`~demtool.sgm.strips` (one pass: strips, sweep threads, timing),
:mod:`~demtool.sgm.matcher` (MI iterations, the HMI pyramid, the public :func:`sgm`).
"""

from demtool.sgm.matcher import COST_DEFAULTS, COSTS, SGMResult, sgm
from demtool.sgm.strips import plan_strips

__all__ = ["COSTS", "COST_DEFAULTS", "SGMResult", "plan_strips", "sgm"]
