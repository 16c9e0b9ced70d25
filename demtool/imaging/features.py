"""SIFT features, descriptor matching and robust epipolar geometry, shared by the stages.

``rectify``, ``select`` and ``match`` (seed points) all need the same three steps:

1. :func:`to_uint8` — a NaN-aware robust stretch of a float image (12-bit DN, radiance,
   NaN = nodata) to the 8-bit image OpenCV's SIFT expects, plus a validity mask;
2. :func:`detect_sift` — SIFT keypoints and descriptors (Lowe 2004) as plain arrays
   (:class:`Features`), never inside the masked-out (NaN) area;
3. :func:`match_descriptors` — nearest neighbours with Lowe's ratio test and an
   optional mutual-nearest-neighbour check, then :func:`ransac_fundamental` —
   a fundamental matrix by USAC/MAGSAC (Barath et al. 2019/2020) or classic RANSAC
   that rejects the remaining false matches (the epipolar geometry lives in
   :mod:`demtool.imaging.epipolar` and is re-exported here).

All functions are pure (arrays in, arrays out) and use the array conventions of
CONTRIBUTING.md: point arrays are ``(N, 2)`` as ``(x, y)`` = ``(column, row)``, with
the centre of pixel (row r, column c) at (x, y) = (c, r).

References
----------
Lowe, D. G. (2004). Distinctive image features from scale-invariant keypoints.
    IJCV 60(2), 91-110 (SIFT; ratio test, sect. 7.1).
Hartley, R., Zisserman, A. (2004). Multiple View Geometry, 2nd ed. (Sampson
    distance, eq. 11.9; the fundamental matrix, ch. 9-11).
Barath, D., Noskova, J., Ivashechkin, M., Matas, J. (2020). MAGSAC++, a fast,
    reliable and accurate robust estimator. CVPR.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from demtool.errors import ParameterError

# Epipolar geometry lives in demtool.imaging.epipolar; re-exported for the stages' imports
# (rectify.py also uses the private _normalising_transform).
from demtool.imaging.epipolar import (
    _normalising_transform,  # noqa: F401
    fit_fundamental,
    ransac_fundamental,
    sampson_distance,
)
from demtool.logs import get_logger

log = get_logger(__name__)

#: Descriptor length of SIFT.
SIFT_DESCRIPTOR_SIZE = 128

#: Above this many query × train descriptor pairs, "auto" matching uses FLANN k-d trees.
_BRUTE_FORCE_LIMIT = 1.0e8


# --------------------------------------------------------------------------------------
# 8-bit conversion
# --------------------------------------------------------------------------------------


def to_uint8(image: np.ndarray, mask: np.ndarray | None = None,
             percentiles: tuple[float, float] = (0.5, 99.5), *,
             exact: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Stretch a float image (any DN range, NaN = nodata) robustly to 8 bits.

    The values between the ``percentiles`` of the valid pixels map linearly to
    0 … 255 (values outside are clipped), so 12- or 16-bit images and radiances keep
    their contrast and a few hot pixels do not compress it.

    Parameters
    ----------
    image : (H, W) array
        Grey image, any real dtype; NaN and ±inf mark nodata.  A ``uint8`` image is
        returned unchanged (apart from the copy).
    mask : (H, W) bool, optional
        True where the pixel may be used; combined with the finite-value mask.
    percentiles : (float, float)
        Lower and upper percentile (0-100) of the valid values mapped to 0 and 255.
    exact : bool
        False (SIFT on large images): float32 arithmetic on a subsample's percentiles,
        nodata filled with the median.  True (the 8-bit scratch copies ``bundle`` hands
        to COLMAP, which must stay bit for bit what they were): float64 arithmetic
        rounded to the nearest integer, nodata 0, and a float image that already holds
        8-bit values (integers in 0 … 255) kept as it is.

    Returns
    -------
    image8 : (H, W) uint8
        The stretched image; nodata pixels hold the stretched median (a neutral grey,
        so they create no strong artificial edges).
    valid : (H, W) bool
        True where ``image`` is finite (and ``mask`` is True).

    Raises
    ------
    ParameterError
        Not a 2-D array, mask of another shape, or bad percentiles.
    """
    array = np.asarray(image)
    if array.ndim != 2:
        raise ParameterError(f"to_uint8 expects a 2-D grey image, got shape {array.shape}")
    low_pct, high_pct = (float(p) for p in percentiles)
    if not 0.0 <= low_pct < high_pct <= 100.0:
        raise ParameterError(f"percentiles must satisfy 0 <= low < high <= 100, got {percentiles}")
    valid = np.isfinite(array) if array.dtype.kind == "f" else np.ones(array.shape, bool)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != array.shape:
            raise ParameterError(f"mask shape {mask.shape} differs from image shape {array.shape}")
        valid &= mask
    if array.dtype == np.uint8:
        return array.copy(), valid
    if exact:
        return _to_uint8_exact(array, valid, (low_pct, high_pct)), valid
    values = array[valid]
    if values.size == 0:
        return np.zeros(array.shape, np.uint8), valid
    # A subsample is enough for the percentiles of a large image.
    step = max(1, values.size // 2_000_000)
    low, median, high = np.percentile(values[::step].astype(np.float64),
                                      [low_pct, 50.0, high_pct])
    scale = 255.0 / (high - low) if high > low else 0.0
    work = np.where(valid, array, median).astype(np.float32)
    stretched = np.clip((work - np.float32(low)) * np.float32(scale) + np.float32(0.5), 0, 255)
    return stretched.astype(np.uint8), valid


def _to_uint8_exact(array: np.ndarray, valid: np.ndarray,
                   percentiles: tuple[float, float]) -> np.ndarray:
    """The ``exact=True`` stretch of :func:`to_uint8` (float64, rounded, nodata 0)."""
    values = array[valid]
    if values.size == 0:
        return np.zeros(array.shape, np.uint8)
    if values.min() >= 0 and values.max() <= 255 and np.all(values == np.round(values)):
        scaled = np.where(valid, array, 0.0)
    else:
        low, high = np.percentile(values, percentiles)
        span = max(float(high - low), 1e-12)
        scaled = np.where(valid, (array - low) / span * 255.0, 0.0)
    return np.clip(np.round(scaled), 0, 255).astype(np.uint8)


# --------------------------------------------------------------------------------------
# SIFT detection
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Features:
    """SIFT keypoints and descriptors of one image, as plain arrays.

    Attributes
    ----------
    points : (N, 2) float32
        Keypoint positions (x, y) in pixels of the image given to :func:`detect_sift`
        (plus its ``offset``).
    descriptors : (N, 128) float32
        SIFT descriptors (OpenCV's scaling: components 0 … 255 after clipping at 0.2).
    sizes : (N,) float32
        Keypoint diameters in pixels.
    angles : (N,) float32
        Keypoint orientations in degrees (0 … 360, OpenCV convention).
    responses : (N,) float32
        Detector responses (DoG contrast), larger = stronger.
    """

    points: np.ndarray
    descriptors: np.ndarray
    sizes: np.ndarray
    angles: np.ndarray
    responses: np.ndarray

    def __len__(self) -> int:
        return int(self.points.shape[0])

    @classmethod
    def empty(cls) -> Features:
        """A feature set with no keypoint."""
        return cls(np.zeros((0, 2), np.float32), np.zeros((0, SIFT_DESCRIPTOR_SIZE), np.float32),
                   np.zeros(0, np.float32), np.zeros(0, np.float32), np.zeros(0, np.float32))

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The arrays by name (for caching in an NPZ file)."""
        return {"points": self.points, "descriptors": self.descriptors, "sizes": self.sizes,
                "angles": self.angles, "responses": self.responses}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> Features:
        """Inverse of :meth:`to_arrays`; checks shapes, raises ValueError when inconsistent."""
        points = np.asarray(arrays["points"], np.float32).reshape(-1, 2)
        descriptors = np.asarray(arrays["descriptors"], np.float32)
        count = len(points)
        if descriptors.shape != (count, SIFT_DESCRIPTOR_SIZE):
            raise ValueError(f"descriptors have shape {descriptors.shape}, expected "
                             f"({count}, {SIFT_DESCRIPTOR_SIZE})")
        others = [np.asarray(arrays[key], np.float32).reshape(-1)
                  for key in ("sizes", "angles", "responses")]
        if any(len(a) != count for a in others):
            raise ValueError("sizes/angles/responses do not match the number of points")
        return cls(points, descriptors, *others)

    def subset(self, keep: np.ndarray) -> Features:
        """The features selected by a boolean mask or index array."""
        return Features(self.points[keep], self.descriptors[keep], self.sizes[keep],
                        self.angles[keep], self.responses[keep])


# OpenCV's SIFT doubles the first octave by sampling the input at x / 2 instead of at
# (x + 0.5) / 2 − 0.5 (pixel centres), so every keypoint it returns sits +0.25 px off in
# x and y, equal in every image: tie points never see it, ground control turns it into a
# pointing bias of the whole block (issue 14; the mirror test in tests/test_features.py).
# It is removed here rather than with ``enable_precise_upscale=True``: that option
# resamples the first octave differently and gave fewer keypoints (5955 vs 6043 on the
# demo pair) and larger residuals (0.198 vs 0.184 px RMS after rectification).
SIFT_UPSCALE_BIAS_PX = np.float32(0.25)


def detect_sift(image: np.ndarray, *, mask: np.ndarray | None = None, max_features: int = 0,
                contrast_threshold: float = 0.04, edge_threshold: float = 10.0,
                n_octave_layers: int = 3, border_px: int = 8,
                offset: tuple[float, float] = (0.0, 0.0)) -> Features:
    """Detect SIFT keypoints and compute their descriptors (Lowe 2004, OpenCV).

    Parameters
    ----------
    image : (H, W) array
        Grey image: float (any DN range, NaN = nodata; stretched with :func:`to_uint8`)
        or uint8.
    mask : (H, W) bool, optional
        True where keypoints may be detected (e.g. a region of interest).
    max_features : int
        Keep at most this many keypoints, the strongest first (0 = all).
    contrast_threshold : float
        OpenCV's SIFT contrast threshold (0.04 default; lower finds more keypoints
        in weak texture).
    edge_threshold : float
        Lowe's edge-response threshold r (sect. 4.1); larger keeps more edge-like points.
    n_octave_layers : int
        Scale layers per octave (3 in Lowe 2004).
    border_px : int
        Keypoints closer than this to nodata (NaN) or to the mask edge are dropped,
        since their descriptors would see the fill value.
    offset : (float, float)
        Added to the keypoint (x, y): the position of ``image[0, 0]`` in a larger
        image when ``image`` is a crop.

    Returns
    -------
    Features
        Possibly empty (a flat or all-nodata image has no keypoint).
    """
    import cv2

    if max_features < 0:
        raise ParameterError(f"max_features must be >= 0, got {max_features}")
    if contrast_threshold <= 0:
        raise ParameterError(f"contrast_threshold must be > 0, got {contrast_threshold}")
    image8, valid = to_uint8(image, mask)
    if not valid.any():
        return Features.empty()
    detect_mask = valid.astype(np.uint8)
    if border_px > 0 and not valid.all():
        kernel = np.ones((2 * border_px + 1, 2 * border_px + 1), np.uint8)
        detect_mask = cv2.erode(detect_mask, kernel, borderType=cv2.BORDER_REPLICATE)
    sift = cv2.SIFT_create(nfeatures=int(max_features), nOctaveLayers=int(n_octave_layers),
                           contrastThreshold=float(contrast_threshold),
                           edgeThreshold=float(edge_threshold))
    keypoints, descriptors = sift.detectAndCompute(image8, detect_mask)
    if not keypoints or descriptors is None:
        return Features.empty()
    points = np.array([kp.pt for kp in keypoints], dtype=np.float32).reshape(-1, 2)
    points += np.asarray(offset, dtype=np.float32) - SIFT_UPSCALE_BIAS_PX
    sizes = np.array([kp.size for kp in keypoints], dtype=np.float32)
    angles = np.array([kp.angle for kp in keypoints], dtype=np.float32)
    responses = np.array([kp.response for kp in keypoints], dtype=np.float32)
    features = Features(points, np.ascontiguousarray(descriptors, dtype=np.float32),
                        sizes, angles, responses)
    if max_features and len(features) > max_features:  # OpenCV may keep ties
        order = np.argsort(-responses, kind="stable")[:max_features]
        features = features.subset(np.sort(order))
    return features


# --------------------------------------------------------------------------------------
# Matching
# --------------------------------------------------------------------------------------


def _brute_force(a: np.ndarray, b: np.ndarray,
                 chunk_bytes: int = 64 << 20) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact nearest neighbours both ways from one distance matrix (BLAS, in row chunks).

    Returns, for each row of ``a``, the indices (Na, 2) and squared distances (Na, 2) of
    its two nearest rows of ``b`` (index -1, distance inf when ``b`` has one row), and
    for each row of ``b`` the index (Nb,) of its nearest row of ``a``
    (:func:`demtool.imaging.nearest.nearest_both_ways`; ties: the lower index).
    """
    from demtool.imaging.nearest import nearest_both_ways

    norms_b = np.einsum("ij,ij->i", b, b)
    indices = np.full((len(a), 2), -1, np.int64)
    distances = np.full((len(a), 2), np.inf, np.float64)
    best_a_for_b = np.zeros(len(b), np.int64)
    best_b_distance = np.full(len(b), np.inf, np.float64)
    rows = max(1, chunk_bytes // (4 * len(b)))
    for start in range(0, len(a), rows):
        block = a[start:start + rows]
        d2 = np.einsum("ij,ij->i", block, block)[:, None] + norms_b[None, :] - 2.0 * (block @ b.T)
        nearest_both_ways(d2, start, indices, distances, best_a_for_b, best_b_distance)
    return indices, distances, best_a_for_b


def _flann(query: np.ndarray, train: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Approximate k nearest train rows of each query row (FLANN k-d trees), (Nq, k).

    Missing neighbours get index -1 and distance inf.  Distances are squared.
    """
    import cv2

    matcher = cv2.FlannBasedMatcher({"algorithm": 1, "trees": 4}, {"checks": 64})
    indices = np.full((len(query), k), -1, dtype=np.int64)
    distances = np.full((len(query), k), np.inf, dtype=np.float64)
    for neighbours in matcher.knnMatch(query, train, k=k):
        for rank, m in enumerate(neighbours[:k]):
            indices[m.queryIdx, rank] = m.trainIdx
            distances[m.queryIdx, rank] = float(m.distance) ** 2
    return indices, distances


def match_descriptors(descriptors_a: np.ndarray, descriptors_b: np.ndarray, *,
                      ratio: float = 0.8, mutual: bool = True,
                      method: str = "auto") -> np.ndarray:
    """Match descriptors with Lowe's ratio test and an optional mutual check.

    A descriptor of ``a`` is matched to its nearest neighbour in ``b`` when the
    distance to it is below ``ratio`` times the distance to the second nearest
    (Lowe 2004, sect. 7.1: 0.8 rejects 90 % of false matches and 5 % of correct
    ones).  With ``mutual``, the match is kept only if the ``a`` descriptor is also
    the nearest neighbour of the ``b`` descriptor.

    Parameters
    ----------
    descriptors_a, descriptors_b : (Na, D), (Nb, D) float32
        Descriptors (e.g. :attr:`Features.descriptors`).
    ratio : float
        Ratio-test threshold in (0, 1]; 1 disables the test.
    mutual : bool
        Require mutual nearest neighbours.
    method : {"auto", "brute", "flann"}
        Exact brute force (one BLAS distance matrix, in chunks), or FLANN randomised
        k-d trees (approximate, for large sets); "auto" picks FLANN above 1e8
        descriptor pairs.

    Returns
    -------
    (M, 2) int64
        Index pairs ``(i, j)``: ``descriptors_a[i]`` matches ``descriptors_b[j]``,
        sorted by ``i``.  Each ``j`` appears at most once when ``mutual``.
    """
    if not 0.0 < ratio <= 1.0:
        raise ParameterError(f"ratio must be in (0, 1], got {ratio}")
    if method not in ("auto", "brute", "flann"):
        raise ParameterError(f"unknown matching method {method!r}; should be one of "
                             "auto, brute, flann")
    a = np.ascontiguousarray(descriptors_a, dtype=np.float32)
    b = np.ascontiguousarray(descriptors_b, dtype=np.float32)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise ParameterError(f"descriptor arrays must be (N, D) with the same D, got "
                             f"{a.shape} and {b.shape}")
    if len(a) == 0 or len(b) == 0:
        return np.zeros((0, 2), np.int64)
    use_flann = method == "flann" or (method == "auto"
                                      and len(a) * len(b) > _BRUTE_FORCE_LIMIT)
    if use_flann:
        indices, distances = _flann(a, b, 2)
    else:
        indices, distances, best_a_for_b = _brute_force(a, b)
    best, second = distances[:, 0], distances[:, 1]  # squared distances
    keep = indices[:, 0] >= 0
    if len(b) >= 2 and ratio < 1.0:
        keep &= best < ratio**2 * second
    pairs = np.column_stack([np.nonzero(keep)[0], indices[keep, 0]])
    if mutual and len(pairs):
        if use_flann:
            best_a_for_b = np.full(len(b), -1, np.int64)
            back, _ = _flann(b, a, 1)
            best_a_for_b[:] = back[:, 0]
        pairs = pairs[best_a_for_b[pairs[:, 1]] == pairs[:, 0]]
    return pairs.astype(np.int64)


__all__ = ["SIFT_DESCRIPTOR_SIZE", "Features", "detect_sift", "fit_fundamental",
           "match_descriptors", "ransac_fundamental", "sampson_distance", "to_uint8"]
