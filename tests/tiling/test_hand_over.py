"""The tile cache's hand-over (TileCache.hand_over, issue 47): a run that writes its
outputs while its tiles run on threads of this process takes the tiles from memory
instead of reading their files back; the files are written all the same (a rerun
resumes from them), at most ``count`` tiles are kept (the writer's next ones), and a
copy of the cache in a worker process keeps none."""

from __future__ import annotations

import pickle

import numpy as np

from demtool.tiling import Tile, TileCache


def _tile(index: int) -> Tile:
    return Tile(index, (0, 4, 0, 5), (0, 4, 0, 5))


def _values(index: int) -> np.ndarray:
    values = np.arange(20, dtype=np.float32).reshape(1, 4, 5) + 100 * index
    values[0, 1, 2] = np.nan
    return values


def test_kept_tiles_come_from_memory_and_their_files_are_written(tmp_path, monkeypatch):
    cache = TileCache(tmp_path / "cache")
    cache.hand_over(2)
    for index in (3, 1, 0, 2):  # finished out of order: the lowest indices stay
        cache.store(_tile(index), _values(index), {"index": index})
    reads = []
    original = np.load
    monkeypatch.setattr(np, "load", lambda *a, **k: (reads.append(a[0]), original(*a, **k))[1])
    for index in range(4):
        assert cache.done(_tile(index))
        found = cache.load(_tile(index))
        np.testing.assert_array_equal(found.view(np.uint32), _values(index).view(np.uint32))
        cache.release(_tile(index))
    # tiles 0 and 1 were handed over; 2 and 3 were read back from their files
    assert reads == [cache.path(_tile(2)), cache.path(_tile(3))]
    # every file is there, with the values, for a rerun
    fresh = TileCache(tmp_path / "cache")
    for index in range(4):
        assert fresh.done(_tile(index))
        np.testing.assert_array_equal(fresh.load(_tile(index)).view(np.uint32),
                                      _values(index).view(np.uint32))
    assert len(reads) == 6


def test_released_and_unkept_tiles_are_read_from_their_files(tmp_path):
    cache = TileCache(tmp_path / "cache")
    cache.store(_tile(0), _values(0), {})  # no hand-over: nothing kept
    assert cache._kept == {}
    cache.hand_over(3)
    cache.store(_tile(1), _values(1), {})
    assert set(cache._kept) == {1}
    cache.release(_tile(1))
    assert cache._kept == {}
    cache.store(_tile(2), _values(2), {})
    cache.hand_over(0)  # turning it off forgets what was kept
    assert cache._kept == {}


def test_a_copy_in_a_worker_process_keeps_nothing(tmp_path):
    cache = TileCache(tmp_path / "cache")
    cache.hand_over(4)
    cache.store(_tile(0), _values(0), {})
    copy = pickle.loads(pickle.dumps(cache))
    assert copy.folder == cache.folder and copy.done(_tile(0))
    copy.store(_tile(1), _values(1), {})
    assert copy._kept == {} and set(cache._kept) == {0}
