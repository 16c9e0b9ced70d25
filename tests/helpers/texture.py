"""Band-limited random textures: the one texture generator of the stereo tests."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import ndimage


def texture(shape: tuple[int, int], rng: np.random.Generator, *,
            blurs: Sequence[float] = (1.0,), weights: Sequence[float] = (1.0,),
            mode: str = "reflect", centred: bool = False, sigma: float = 1.0,
            mean: float = 0.0) -> np.ndarray:
    """Sum of Gaussian-smoothed white noise fields, each scaled to unit standard deviation.

    Parameters
    ----------
    shape : (H, W)
    rng : numpy Generator
        One normal field is drawn per entry of ``blurs``, in order.
    blurs, weights : sequences of float
        Gaussian σ (pixels) of each field and its weight in the sum.
    mode : str
        Border mode of the Gaussian filter (``"wrap"`` for a periodic texture).
    centred : bool
        Remove each field's mean before scaling.
    sigma, mean : float
        The sum is scaled by ``sigma`` and shifted by ``mean`` (grey levels).

    Returns
    -------
    (H, W) float64
    """
    total = np.zeros(shape)
    for blur, weight in zip(blurs, weights, strict=True):
        field = ndimage.gaussian_filter(rng.normal(size=shape), blur, mode=mode)
        if centred:
            field = field - field.mean()
        total += weight * field / field.std()
    return total * sigma + mean
