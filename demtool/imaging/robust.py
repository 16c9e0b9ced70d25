"""Robust statistics shared by the stages."""

from __future__ import annotations

import numpy as np

#: Scale from the median absolute deviation to the standard deviation of Gaussian
#: scatter, 1 / Φ⁻¹(3/4) (Höhle & Höhle 2009, ISPRS J. 64, 398–406).
NMAD_FACTOR = 1.4826


def nmad(values: np.ndarray) -> float:
    """Normalised median absolute deviation ``1.4826 · median(|x − median(x)|)``.

    Parameters
    ----------
    values : array of float
        Finite values (any shape; NaN must be removed first).

    Returns
    -------
    float
        The robust standard deviation, in the values' units.
    """
    x = np.asarray(values, dtype=np.float64)
    return float(NMAD_FACTOR * np.median(np.abs(x - np.median(x))))
