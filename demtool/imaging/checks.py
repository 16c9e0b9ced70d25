"""Checks of input content: what each stage needs from its inputs, beyond readability.

Pure functions (arrays and small metadata in, a verdict out) that raise one-line
:class:`~demtool.errors.InputError` messages naming the file, so a stage refuses
nonsense instead of turning it into plausible numbers:

* :func:`check_texture` — a constant or near-constant image (``rectify``, ``sgm``,
  ``match``, ``refine``);
* :func:`check_disparity_range` — disparities far outside the rectification's range
  (``dem``);
* :func:`check_rectification_matches` — a ``rectify.npz`` of another pair;
* :func:`check_same_grid` — a mask (or any raster) on another grid or frame;
* :func:`check_has_valid` and :func:`check_magnitude` — NaN-only rasters and values
  no product can hold (1e27 m).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from statistics import NormalDist
from typing import Any, NamedTuple

import numpy as np

from demtool.errors import InputError

# --------------------------------------------------------------------------------------
# Texture
# --------------------------------------------------------------------------------------

#: Signal-to-noise ratio below which an image has no texture (see :func:`texture`).
MIN_TEXTURE_SNR = 1.5
#: Fewest block means a scale needs to be measured (so pure noise cannot pass by chance).
MIN_BLOCKS = 256
#: Fraction of the block means dropped at each end before their spread is measured.
TEXTURE_TRIM = 0.05
#: Fraction of the pixels clipped at each end first (isolated hot or dead pixels).
PIXEL_CLIP = 0.005
#: Larger images are averaged in 2 × 2 blocks (NaN-aware) until they fit: memory and time
#: stay bounded, and only the finest scales are skipped (real texture spans many).
MAX_TEXTURE_PIXELS = 4_000_000


class Texture(NamedTuple):
    """What :func:`texture` measured, at the scale where the structure stands out most.

    Attributes
    ----------
    noise_sigma : float
        Pixel noise (image units): the larger of Immerkær's estimate and the
        quantisation noise ``step / sqrt(12)``.
    signal_sigma : float
        Spread of the structure at that scale, noise removed (image units).
    snr : float
        ``signal_sigma`` over the noise of a block mean (``noise_sigma / block``);
        ``inf`` for a noiseless image with structure, 0 for a constant one.
    block : int
        Block side of that scale, pixels (1 = single pixels).
    """

    noise_sigma: float
    signal_sigma: float
    snr: float
    block: int


def noise_sigma(image: np.ndarray) -> float:
    """Standard deviation of the pixel noise by Immerkær's Laplacian-difference estimator.

    ``sigma = sqrt(pi/2) / (6 N) * sum |I * M|`` with
    ``M = [[1, -2, 1], [-2, 4, -2], [1, -2, 1]]``, over the ``N`` pixels whose 3 × 3
    neighbourhood is valid.  The mask cancels planes and most smooth structure, so
    what remains is noise (an overestimate on strong edges).

    References
    ----------
    J. Immerkær, "Fast noise variance estimation", Computer Vision and Image
    Understanding 64(2), 300-302, 1996 (eq. 3).

    Parameters
    ----------
    image : (H, W) float array
        NaN = invalid.

    Returns
    -------
    float
        Noise standard deviation in image units; 0 for images under 3 × 3 valid pixels.
    """
    data = np.asarray(image, dtype=np.float64)
    if data.shape[0] < 3 or data.shape[1] < 3:
        return 0.0
    c = data[1:-1, 1:-1]
    laplace = (data[:-2, :-2] + data[:-2, 2:] + data[2:, :-2] + data[2:, 2:]
               - 2.0 * (data[:-2, 1:-1] + data[2:, 1:-1] + data[1:-1, :-2] + data[1:-1, 2:])
               + 4.0 * c)
    valid = np.isfinite(laplace)
    if not valid.any():
        return 0.0
    return float(math.sqrt(math.pi / 2.0) / 6.0 * np.abs(laplace[valid]).mean())


def quantisation_step(values: np.ndarray, sample: int = 200_000) -> float:
    """Smallest difference between distinct values (1 for integer DN); 0 if constant."""
    flat = np.asarray(values, dtype=np.float64).ravel()
    flat = flat[np.isfinite(flat)]
    if flat.size > sample:
        flat = flat[:: flat.size // sample]
    distinct = np.unique(flat)
    if distinct.size < 2:
        return 0.0
    return float(np.diff(distinct).min())


def _halve(array: np.ndarray) -> np.ndarray:
    """Sum of each 2 × 2 tile (an odd last row or column is dropped)."""
    height, width = array.shape[0] // 2 * 2, array.shape[1] // 2 * 2
    a = array[:height, :width]
    return a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2]


def _trimmed_variance(values: np.ndarray) -> float:
    """Variance after dropping TEXTURE_TRIM at each end, rescaled to a normal's variance."""
    if values.size > 1_000_000:  # a strided sample measures the spread as well, faster
        values = values[:: values.size // 1_000_000]
    ordered = np.sort(values)
    drop = int(TEXTURE_TRIM * ordered.size)
    kept = ordered[drop:ordered.size - drop]
    z = NormalDist().inv_cdf(1.0 - TEXTURE_TRIM)
    factor = 1.0 - 2.0 * z * NormalDist().pdf(z) / (1.0 - 2.0 * TEXTURE_TRIM)
    return float(kept.var()) / factor


def _binned(image: np.ndarray) -> tuple[np.ndarray, int]:
    """The image as float64, averaged in 2 × 2 blocks until under MAX_TEXTURE_PIXELS."""
    data = np.asarray(image)
    factor = 1
    while data.size > MAX_TEXTURE_PIXELS and min(data.shape) >= 4:
        values = data.astype(np.float32, copy=False)
        finite = np.isfinite(values)
        if finite.all():
            data = _halve(values) * np.float32(0.25)
        else:
            sums = _halve(np.where(finite, values, np.float32(0.0)))
            counts = _halve(finite.view(np.uint8))
            with np.errstate(invalid="ignore", divide="ignore"):
                data = np.where(counts > 0, sums / counts, np.float32(np.nan))
        factor *= 2
    return np.array(data, dtype=np.float64), factor


def texture(image: np.ndarray) -> Texture:
    """Measure how much structure an image has above its noise and quantisation.

    At each scale ``b`` = 1, 2, 4, … px (as long as there are ``MIN_BLOCKS`` blocks),
    the image is averaged in ``b`` × ``b`` blocks and the variance of the block means
    (trimmed of ``TEXTURE_TRIM`` at each end, so a few bright spots are not texture)
    is compared with what the pixel noise alone gives a block mean,
    ``(noise_sigma / b)²``; the structure is what exceeds it.  Shading of relief
    lives at small scales, albedo and large landforms at large ones, so the best scale
    counts.  The pixels are first clipped to their ``PIXEL_CLIP`` quantiles (hot and
    dead pixels).  A dark sky over most of the frame does not hide a body covering
    more than ``TEXTURE_TRIM`` of it.  Images over ``MAX_TEXTURE_PIXELS`` are first
    averaged in 2 × 2 blocks until they fit (``block`` and ``noise_sigma`` are then
    given in the original pixels).

    Parameters
    ----------
    image : (H, W) float array
        Image values (DN or radiance), NaN = invalid.

    Returns
    -------
    Texture
    """
    data, factor = _binned(image)
    finite = np.isfinite(data)
    if not finite.any():
        return Texture(0.0, 0.0, 0.0, 1)
    if factor > 1:
        found = texture(data)
        return Texture(found.noise_sigma * factor, found.signal_sigma, found.snr,
                       found.block * factor)
    sample = data[finite]
    sample = sample[:: max(1, sample.size // 1_000_000)]
    low, high = np.quantile(sample, [PIXEL_CLIP, 1.0 - PIXEL_CLIP])
    np.clip(data, low, high, out=data, where=finite)
    step = quantisation_step(data)
    if step == 0.0:
        return Texture(0.0, 0.0, 0.0, 1)
    noise = max(noise_sigma(data), step / math.sqrt(12.0))
    best = Texture(noise, 0.0, 0.0, 1)
    sums = np.where(finite, data, 0.0)
    counts = finite.astype(np.float64)
    block = 1
    while True:
        keep = counts >= block * block / 2  # blocks at least half valid
        if keep.sum() < min(MIN_BLOCKS, int(finite.sum())) or keep.sum() < 2:
            break
        means = sums[keep] / counts[keep]
        block_noise = noise / block
        signal = math.sqrt(max(_trimmed_variance(means) - block_noise ** 2, 0.0))
        snr = signal / block_noise if block_noise > 0 else (math.inf if signal > 0 else 0.0)
        if snr > best.snr:
            best = Texture(noise, signal, snr, block)
        sums, counts = _halve(sums), _halve(counts)
        block *= 2
    return best


def check_texture(image: np.ndarray, path: str | os.PathLike, *, what: str = "image",
                  min_snr: float = MIN_TEXTURE_SNR) -> Texture:
    """Refuse a constant or near-constant image; return the measurement otherwise.

    Threshold: at its best scale the structure must exceed ``min_snr`` (default 1.5)
    times the noise of a block mean (see :func:`texture`): the block variance at least
    ``1 + 1.5² = 3.25`` times what noise alone gives.  Pure noise reaches that with a
    probability far below 1e-9 (with ``MIN_BLOCKS`` = 256 blocks the variance ratio
    of noise scatters by about ±0.1), so a flat field, a blank or saturated frame,
    pure noise, or a few hot pixels on a constant background are refused; shading
    of a few DN under as many DN of noise passes (measured in the tests, and on
    Apollo 15 Metric Camera frames at 1/20 of their contrast).

    Raises
    ------
    InputError
        ``"<path>: <what> has no usable texture (...)"``.
    """
    found = texture(image)
    if found.snr < min_snr:
        finite = np.asarray(image)[np.isfinite(image)]
        if finite.size and float(finite.min()) == float(finite.max()):
            detail = f"every valid pixel is {float(finite[0]):g}"
        else:
            detail = (f"structure {found.signal_sigma:.3g} against noise {found.noise_sigma:.3g} "
                      f"per pixel, signal-to-noise {found.snr:.2f} in {found.block} px blocks "
                      f"< {min_snr:g}")
        raise InputError(f"{path}: {what} has no usable texture ({detail}); is it blank, "
                         "saturated or the wrong file?")
    return found


# --------------------------------------------------------------------------------------
# Disparities
# --------------------------------------------------------------------------------------

#: Margin beyond the rectification's disparity range: max(this, 25 % of the range width).
DISPARITY_MARGIN_PX = 4.0
#: Above this fraction of finite values outside the range the file is refused.
MAX_OUTSIDE_FRACTION = 0.5


class DisparityCheck(NamedTuple):
    """Result of :func:`check_disparity_range`.

    Attributes
    ----------
    disparity : (H, W) float32
        A copy with the values outside ``[low, high]`` set to NaN.
    outside : int
        How many finite values were masked (for the log).
    low, high : float
        The accepted interval, pixels (the range widened by the margin).
    """

    disparity: np.ndarray
    outside: int
    low: float
    high: float


def check_disparity_range(disparity: np.ndarray, disparity_range: Sequence[float],
                          path: str | os.PathLike, *, source: str = "the rectification",
                          margin: float | None = None,
                          max_outside_fraction: float = MAX_OUTSIDE_FRACTION
                          ) -> DisparityCheck:
    """Mask disparities outside the rectification's range; refuse a file mostly outside it.

    Choice (issue 16): values outside ``[min − margin, max + margin]`` are **masked and
    counted** (the caller logs the count): a matcher's few wild values should not sink
    a run.  When more than ``max_outside_fraction`` (half) of the finite values are
    outside, the file is **refused**: it is not a disparity of this pair (another
    pair's, a uint16 or RGB raster, values like 1e27).

    Parameters
    ----------
    disparity : (H, W) float array
        Pixels, NaN = invalid, ``x_right = x_left − d``.
    disparity_range : (2,) float
        ``(min, max)`` of the rectification (``rectify.npz`` ``disparity_range``).
    path : path-like
        The disparity file, for the message.
    source : str
        Where the range comes from, for the message.
    margin : float, optional
        Pixels; default ``max(DISPARITY_MARGIN_PX, 0.25 * (max − min))``.
    max_outside_fraction : float
        Refusal threshold.

    Raises
    ------
    InputError
        No finite value, an invalid range, or most values outside it.
    """
    low, high = (float(v) for v in disparity_range)
    if not (math.isfinite(low) and math.isfinite(high)) or high < low:
        raise InputError(f"{source}: disparity range {low:g} … {high:g} is not a valid range")
    if margin is None:
        margin = max(DISPARITY_MARGIN_PX, 0.25 * (high - low))
    low, high = low - margin, high + margin
    data = np.array(disparity, dtype=np.float32)
    finite = np.isfinite(data)
    count = int(finite.sum())
    check_has_valid(data, path, "disparity")
    with np.errstate(invalid="ignore"):
        outside = finite & ((data < low) | (data > high))
    n_outside = int(outside.sum())
    if n_outside > max_outside_fraction * count:
        values = data[finite]
        raise InputError(
            f"{path}: {100 * n_outside / count:.0f} % of the disparities lie outside "
            f"{low:g} … {high:g} px, the range of {source} with a {margin:g} px margin "
            f"(values {float(values.min()):.4g} … {float(values.max()):.4g}); is it a "
            "disparity of this pair?")
    data[outside] = np.nan
    return DisparityCheck(data, n_outside, low, high)


# --------------------------------------------------------------------------------------
# Rectification, grids, values
# --------------------------------------------------------------------------------------


def _size(shape: Sequence[int]) -> str:
    return f"{shape[1]} x {shape[0]}"


def check_rectification_matches(rectification: Mapping[str, Any],
                                rect_path: str | os.PathLike,
                                images: Mapping[str | os.PathLike, tuple[int, int]], *,
                                rectified: bool,
                                sources: Mapping[str | os.PathLike, str | None] | None = None
                                ) -> None:
    """Refuse a ``rectify.npz`` that does not belong to the images.

    Parameters
    ----------
    rectification : mapping
        The arrays of the rectification file (``io.read_npz(..., "rectification")``).
    rect_path : path-like
        The file, for messages.
    images : mapping of path to (height, width)
        Left first, then right: the images' shapes.
    rectified : bool
        True if the images are rectified (they must fill ``size_rect``), False if they
        are the originals (``size_left``, ``size_right``).
    sources : mapping of path to str or None, optional
        For rectified images, the ``rectified_from`` tag of each (None if absent): it
        must name the ``left_name`` / ``right_name`` of the file.

    Raises
    ------
    InputError
        A size or a name that does not match, naming both files.
    """
    (left, left_shape), (right, right_shape) = list(images.items())[:2]
    if rectified:
        width, height = (int(v) for v in rectification["size_rect"])
        expected = {left: (height, width), right: (height, width)}
        what = "rectified canvas"
    else:
        wl, hl = (int(v) for v in rectification["size_left"])
        wr, hr = (int(v) for v in rectification["size_right"])
        expected = {left: (hl, wl), right: (hr, wr)}
        what = "original image"
    for image, shape in ((left, left_shape), (right, right_shape)):
        if tuple(shape) != expected[image]:
            raise InputError(
                f"{image}: {_size(shape)} px, but {rect_path} describes a "
                f"{_size(expected[image])} px {what}; is it the rectification of this pair?")
    if rectified and sources:
        names = {left: str(rectification["left_name"]), right: str(rectification["right_name"])}
        for image, source in sources.items():
            if source is not None and image in names and source != names[image]:
                raise InputError(f"{image}: rectified from {source}, but {rect_path} "
                                 f"rectifies {names[image]}; is it the rectification of this "
                                 "pair?")


def check_same_grid(reference: Any, other: Any, *, what: str = "mask",
                    reference_what: str = "DEM", tolerance: float = 1e-6) -> None:
    """Refuse a raster (a mask) that is not on the same grid and frame as another.

    Parameters
    ----------
    reference, other : demtool.io.Raster
        Their ``data.shape``, ``transform``, ``crs`` and ``frame`` tag are compared;
        ``path`` names them in messages.
    tolerance : float
        Relative tolerance on the transform coefficients (pixel size units).

    Raises
    ------
    InputError
        Another size, pixel grid (spacing or origin), CRS or frame.
    """
    a, b = reference, other
    if a.data.shape != b.data.shape:
        raise InputError(f"{b.path}: {what} is {_size(b.data.shape)} px but the {reference_what} "
                         f"{a.path} is {_size(a.data.shape)} px; they must share one grid")
    ta = np.asarray(tuple(a.transform)[:6], dtype=float)
    tb = np.asarray(tuple(b.transform)[:6], dtype=float)
    scale = max(abs(ta[0]), abs(ta[4]), 1e-12)
    if np.any(np.abs(ta - tb) > tolerance * scale * np.maximum(1.0, np.abs(ta) / scale)):
        raise InputError(f"{b.path}: {what} grid {tuple(round(v, 6) for v in tb)} differs from "
                         f"the {reference_what} grid {tuple(round(v, 6) for v in ta)} of "
                         f"{a.path}; they must share one grid")
    if (a.crs is None) != (b.crs is None) or (a.crs is not None and a.crs != b.crs):
        raise InputError(f"{b.path}: {what} CRS {b.crs} differs from the {reference_what} CRS "
                         f"{a.crs} of {a.path}")
    fa, fb = a.tags.get("frame"), b.tags.get("frame")
    if fa is not None and fb is not None and fa != fb:
        raise InputError(f"{b.path}: {what} is in the frame {fb}, the {reference_what} "
                         f"{a.path} in {fa}; they must share one frame")


def check_has_valid(data: np.ndarray, path: str | os.PathLike, what: str = "raster") -> None:
    """Refuse a raster without a single finite value (NaN-only, all nodata)."""
    if not np.isfinite(data).any():
        raise InputError(f"{path}: {what} contains no valid (finite) pixel")


#: Largest plausible |height| or |radius| of a DEM, metres (above Jupiter's radius).
MAX_DEM_MAGNITUDE_M = 1e8


def check_magnitude(data: np.ndarray, path: str | os.PathLike, *, what: str = "DEM",
                    limit: float = MAX_DEM_MAGNITUDE_M, unit: str = "m") -> None:
    """Refuse values no product can hold (|value| > ``limit``: 1e27 m, -3.4e38 fill).

    The default limit, 1e8 m, passes heights and radii of every solid body (and
    Jupiter's radius) and refuses fill values and garbage.
    """
    finite = np.asarray(data)[np.isfinite(data)]
    if finite.size == 0:
        return
    worst = float(np.max(np.abs(finite)))
    if worst > limit:
        count = int(np.count_nonzero(np.abs(finite) > limit))
        raise InputError(f"{path}: {what} has {count} value(s) beyond ±{limit:g} {unit} (up to "
                         f"{worst:.3g} {unit}); an unmarked fill value or the wrong file?")
