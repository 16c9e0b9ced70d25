"""Robust statistics shared by the stages."""

from __future__ import annotations

import numpy as np

#: Scale from the median absolute deviation to the standard deviation of Gaussian
#: scatter, 1 / Φ⁻¹(3/4) (Höhle & Höhle 2009, ISPRS J. 64, 398–406).
NMAD_FACTOR = 1.4826


def nmad(values: np.ndarray, *, median: float | None = None,
         scratch: np.ndarray | None = None) -> float:
    """Normalised median absolute deviation ``1.4826 · median(|x − median(x)|)``.

    Parameters
    ----------
    values : array of float
        Finite values (any shape; NaN must be removed first).
    median : float, optional
        ``np.median(values)`` where the caller has it already (it is not recomputed).
    scratch : float64 array of ``values``' shape, optional
        Overwritten with the deviations (no new array of them: the same number).

    Returns
    -------
    float
        The robust standard deviation, in the values' units.
    """
    x = np.asarray(values, dtype=np.float64)
    centre = np.median(x) if median is None else median
    if scratch is None:
        return float(NMAD_FACTOR * np.median(np.abs(x - centre)))
    np.subtract(x, centre, out=scratch)
    np.abs(scratch, out=scratch)
    return float(NMAD_FACTOR * np.median(scratch, overwrite_input=True))
