"""Local ``--workers N`` on threads of the calling process (demtool.tiling.local_threads):
the same bytes as the tiles computed one after the other, a failed tile stops the queue
with its one line, a resumed run computes only the missing tiles."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from demtool import io as dio
from demtool import tiling
from demtool.errors import ProcessingError
from tests.helpers.sgm import count_sgm_tiles, write_tiling_pair
from tests.tiling.test_tiling import sgm


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """The tiling tests' 160 × 200 smooth-disparity pair."""
    folder = tmp_path_factory.mktemp("threads_pair")
    write_tiling_pair(folder)
    return folder


@pytest.fixture(scope="module")
def one_worker(pair, tmp_path_factory):
    """Tiles of 64 px one after the other in this process: disparity and confidence."""
    folder = tmp_path_factory.mktemp("one_worker")
    out, conf = folder / "d.tif", folder / "c.tif"
    result = sgm(pair, out, "--tile-size", "64", "--confidence", conf)
    assert result.exit_code == 0, result.output
    return read_both(out, conf)


def read_both(out: Path, conf: Path) -> tuple[np.ndarray, np.ndarray]:
    return dio.read_raster(out).data, dio.read_raster(conf).data


def same_bits(found: tuple[np.ndarray, ...], expected: tuple[np.ndarray, ...]) -> None:
    """Equal to the bit, NaNs included (the files' tags differ: they hold --workers)."""
    for a, b in zip(found, expected, strict=True):
        assert a.dtype == b.dtype and a.shape == b.shape
        np.testing.assert_array_equal(a.view(np.uint32), b.view(np.uint32))


def test_sgm_tiles_on_two_threads_give_the_same_bytes(pair, one_worker, tmp_path):
    import time

    out, conf = tmp_path / "d.tif", tmp_path / "c.tif"
    cpu = time.process_time()
    result = sgm(pair, out, "--tile-size", "64", "--confidence", conf, "--workers", "2")
    cpu = time.process_time() - cpu
    assert result.exit_code == 0, result.output
    same_bits(read_both(out, conf), one_worker)
    tiles = dio.read_json(Path(f"{out}.json"))["summary"]["tiling"]
    assert tiles["executor"] == "threads" and tiles["workers"] == 2
    # the tiles' CPU is this process's, counted once (not each overlapping tile's view
    # of the whole process's CPU summed)
    assert 0 < tiles["tile_cpu_seconds_sum"] <= cpu
    assert not tiling.work_folder(out).exists()


def test_a_failed_tile_on_threads_stops_then_the_run_resumes(pair, one_worker, tmp_path,
                                                             monkeypatch):
    calls = count_sgm_tiles(monkeypatch, fail_at=5)
    out, conf = tmp_path / "d.tif", tmp_path / "c.tif"
    result = sgm(pair, out, "--tile-size", "64", "--confidence", conf, "--workers", "2")
    assert result.exit_code == 1
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and "Traceback" not in result.output, result.output
    assert "tile 5 (rows 64–128, columns 64–128) failed: worker lost" in errors[0]
    assert not out.exists() and not conf.exists() and not Path(f"{out}.json").exists()
    assert not Path(f"{out}.lock").exists()
    cached = sorted(int(p.stem.split("_")[1]) for p in
                    tiling.work_folder(out).glob("*/tile_*.npy"))
    assert f"{len(cached)} finished tiles are cached" in errors[0]
    assert max(calls) <= 6 and 5 not in cached  # the queue stopped at the failure
    calls = count_sgm_tiles(monkeypatch)
    result = sgm(pair, out, "--tile-size", "64", "--confidence", conf, "--workers", "2")
    assert result.exit_code == 0, result.output
    assert sorted(calls) == sorted(set(range(12)) - set(cached))  # only the missing tiles
    same_bits(read_both(out, conf), one_worker)
    assert not tiling.work_folder(out).exists()


class _Job:
    """Writes its tile's index; tile ``bad`` raises once ``hold`` (tile 1) is running,
    and tile 1 finishes after the failure."""

    stage, bands, thread_safe = "test", ("index",), True

    def __init__(self, bad: int | None = 0) -> None:
        self.bad, self.calls, self.threads = bad, [], []
        self.running = threading.Event()

    def compute(self, tile, threads):
        from demtool.tiling.distributed import usable_threads

        self.calls.append(tile.index)
        self.threads.append((threads, usable_threads()))
        if tile.index == 1:
            self.running.set()
            time.sleep(0.3)  # still running when tile 0 fails
        if tile.index == self.bad:
            assert self.running.wait(30)
            raise ValueError(f"tile {tile.index} is bad")
        return np.full((1, *tile.core_shape), tile.index, dtype=np.float32), {}

    def memory_bytes(self, tile):
        return 0


def test_run_tiles_on_threads_stops_the_queue_and_keeps_the_running_tile(tmp_path):
    from demtool.tiling.distributed import run_tiles

    plan = tiling.plan_tiles(40, 200, 20, overlap=0)  # 20 tiles
    cache = tiling.TileCache(tmp_path / "cache")
    job = _Job()
    with pytest.raises(ProcessingError, match=r"^test: tile 0 \(rows 0–20, columns 0–20\) "
                                              r"failed: tile 0 is bad; 1 finished tiles"):
        run_tiles(job, plan.tiles, cache, workers=2)
    assert sorted(job.calls) == [0, 1]  # no queued tile started after the failure
    assert cache.done(plan.tiles[1]) and not cache.done(plan.tiles[0])
    job = _Job(bad=None)
    infos = run_tiles(job, plan.tiles, cache, workers=2)
    assert sorted(job.calls) == [0, *range(2, 20)]  # resumed: tile 1 came from the cache
    assert [i["index"] for i in infos] == list(range(20))
    assert all(cache.load(t)[0, 0, 0] == t.index for t in plan.tiles)
    from demtool.tiling.distributed import available_cores

    share = max(1, available_cores() // 2)
    assert set(job.threads) == {(share, share)}  # each tile within its share of the cores


def test_fuse_tiles_on_two_threads_give_the_same_bits(tmp_path):
    """fuse (its kernels and compare's samplers release the GIL): tiles of 40 cells on two
    threads equal the tiles one after the other, every band to the bit."""
    from demtool.fuse.params import FuseParams
    from demtool.fuse.run import output_paths, run_fuse
    from tests.helpers.fuse import write_dem

    paths = []
    for i, window in enumerate([(0, 80, 0, 90), (10, 100, 20, 110), (30, 110, 5, 100)]):
        paths.append(tmp_path / f"dem_{i}.tif")
        write_dem(paths[-1], window, noise=0.1, seed=i, shift=(0.3 * i, -0.2 * i, 0.5 * i))
    one, two = tmp_path / "one.tif", tmp_path / "two.tif"
    for out, workers in ((one, 0), (two, 2)):
        run_fuse(paths, out, FuseParams(method="huber", blend=6, gap=2, tile_size=40,
                                        workers=workers))
    assert dio.read_json(Path(f"{two}.json"))["summary"]["tiling"]["executor"] == "threads"
    for name in ("dem", "count", "spread", "error"):
        a = dio.read_raster(output_paths(one)[name]).data
        b = dio.read_raster(output_paths(two)[name]).data
        np.testing.assert_array_equal(a.view(np.uint32), b.view(np.uint32))


def test_a_failure_of_the_writer_waits_for_the_running_tiles(tmp_path):
    """The calling thread failing (the in-order writer's disk full) must not leave tile
    threads computing and storing after run_tiles has raised (and the run's output
    transaction, lock and volumes are gone)."""
    from demtool.tiling.distributed import run_tiles

    plan = tiling.plan_tiles(20, 60, 20, overlap=0)  # 3 tiles
    cache = tiling.TileCache(tmp_path / "cache")
    job = _Job(bad=None)  # tile 1 sleeps 0.3 s
    calls = []

    def on_tile():
        calls.append(1)
        if len(calls) == 2:  # the first tile finished: writing it fails
            raise OSError("No space left on device")

    with pytest.raises(OSError, match="No space"):
        run_tiles(job, plan.tiles, cache, workers=2, on_tile=on_tile)
    running = [t.name for t in threading.enumerate() if t.name.startswith("demtool-tile-")]
    assert running == []
    stored = sorted(p.name for p in cache.folder.iterdir())
    time.sleep(0.4)
    assert sorted(p.name for p in cache.folder.iterdir()) == stored


class _NumbaJob:
    """Records the numba thread count its compute sees (jobs such as dem's ignore
    ``threads`` and size their pools from numba's count)."""

    stage, bands = "test", ("index",)

    def __init__(self) -> None:
        self.seen: list[int] = []

    def compute(self, tile, threads):
        import numba

        self.seen.append(numba.get_num_threads())
        return np.zeros((1, *tile.core_shape), dtype=np.float32), {}

    def memory_bytes(self, tile):
        return 0


def test_a_tile_task_keeps_numba_within_its_share_and_restores_it(tmp_path):
    """A Dask worker process's task (compute_tile with threads = cores // N) runs the
    job's kernels on that many numba threads, not on every core of the machine, and
    leaves the worker thread's own count as it was."""
    import numba

    from demtool.tiling.tasks import compute_tile

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("one numba thread: nothing to bound")
    plan = tiling.plan_tiles(20, 20, 20, overlap=0)
    job = _NumbaJob()
    before = numba.get_num_threads()
    compute_tile(job, plan.tiles[0], tiling.TileCache(tmp_path / "cache"), 1)
    assert job.seen == [1]
    assert numba.get_num_threads() == before
