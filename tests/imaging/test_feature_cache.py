"""Direct tests of demtool.imaging.feature_cache: keys, hits, misses, stale and broken entries."""

import numpy as np

from demtool.imaging.feature_cache import FeatureCache
from demtool.imaging.features import Features


def fake_features(n: int = 5, seed: int = 0) -> Features:
    rng = np.random.default_rng(seed)
    return Features(points=rng.uniform(0, 100, (n, 2)).astype(np.float32),
                    descriptors=rng.uniform(0, 255, (n, 128)).astype(np.float32),
                    sizes=np.full(n, 3.0, np.float32), angles=np.zeros(n, np.float32),
                    responses=np.linspace(1, 0.1, n).astype(np.float32))


def counting(found: Features):
    calls = []

    def compute():
        calls.append(1)
        return found
    return compute, calls


def test_second_request_is_a_hit_with_identical_arrays(tmp_path):
    image = tmp_path / "view_00.tif"
    image.write_bytes(b"image content")
    cache = FeatureCache(tmp_path / "cache")
    compute, calls = counting(fake_features())
    first = cache.get_or_compute(image, {"max_features": 0}, compute)
    second = cache.get_or_compute(image, {"max_features": 0}, compute)
    assert len(calls) == 1 and (cache.hits, cache.misses) == (1, 1)
    for name in ("points", "descriptors", "sizes", "angles", "responses"):
        np.testing.assert_array_equal(getattr(second, name), getattr(first, name))
    assert [p.name.startswith("view_00-") for p in (tmp_path / "cache").iterdir()] == [True]


def test_changed_content_or_parameters_miss(tmp_path):
    image = tmp_path / "view_00.tif"
    image.write_bytes(b"one")
    cache = FeatureCache(tmp_path / "cache")
    key = cache.key(image, {"max_features": 0})
    assert cache.key(image, {"max_features": 10}) != key
    image.write_bytes(b"two")
    assert cache.key(image, {"max_features": 0}) != key
    assert cache.load(image, key) is None


def test_broken_entry_is_recomputed_and_disabled_cache_never_writes(tmp_path):
    image = tmp_path / "a.tif"
    image.write_bytes(b"x")
    cache = FeatureCache(tmp_path / "cache")
    key = cache.key(image, {})
    (tmp_path / "cache").mkdir()
    (tmp_path / "cache" / f"a-{key}.npz").write_bytes(b"not a zip")
    compute, calls = counting(fake_features(3))
    found = cache.get_or_compute(image, {}, compute)
    assert len(calls) == 1 and len(found.points) == 3 and cache.misses == 1
    off = FeatureCache(None)
    compute, calls = counting(fake_features(2))
    off.get_or_compute(image, {}, compute)
    off.get_or_compute(image, {}, compute)
    assert len(calls) == 2 and (off.hits, off.misses) == (0, 0)
