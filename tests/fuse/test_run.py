"""run_fuse on small lunar DEMs with known truth: shifts recovered, blunders rejected,
tiled and untiled runs agree, bad inputs refused."""

import numpy as np
import pytest

from demtool import io as dio
from demtool.errors import InputError, ParameterError
from demtool.fuse.params import FuseParams
from demtool.fuse.run import output_paths, run_fuse
from tests.helpers.fuse import truth_heights, write_dem, write_error

# three overlapping DEMs of one area (rows, cols of the common lattice)
WINDOWS = [(0, 80, 0, 90), (10, 100, 20, 110), (30, 110, 5, 100)]


@pytest.fixture()
def block(tmp_path):
    paths = []
    for i, window in enumerate(WINDOWS):
        path = tmp_path / f"dem_{i}.tif"
        shift = (0.0, 0.0, 0.0) if i == 0 else ((0.6, -0.4, 1.5) if i == 1 else (0, 0, -0.8))
        write_dem(path, window, noise=0.1, seed=i, shift=shift, outliers=0.01 * (i == 2))
        paths.append(path)
    return tmp_path, paths


def _truth_on(raster):
    rows, cols = np.mgrid[0:raster.data.shape[0], 0:raster.data.shape[1]].astype(float)
    inverse = ~raster.transform
    # the fused grid's cell centres on the common lattice
    c0, r0 = inverse @ (-200.0, 200.0)
    return truth_heights(rows - r0, cols - c0)


def test_fuse_aligns_rejects_blunders_and_beats_each_dem(block):
    folder, paths = block
    out = folder / "fused.tif"
    summary = run_fuse(paths, out, FuseParams(blend=8))
    fused = dio.read_raster(out)
    assert fused.data.shape == (110, 110)  # the union of the extents
    truth = _truth_on(fused)
    diff = fused.data - truth
    shifts = [d["alignment"]["shift"] for d in summary["dems"]]
    assert shifts[1]["dx_px"] == pytest.approx(-0.6, abs=0.1)
    assert shifts[1]["dy_px"] == pytest.approx(0.4, abs=0.1)
    assert shifts[1]["dz"] == pytest.approx(-1.5, abs=0.1)
    assert shifts[2]["dz"] == pytest.approx(0.8, abs=0.1)  # 1 % of +50 m blunders
    # the same shift in metres (2 m cells; +0.4 cells down is 0.8 m south) and own pixels
    second = summary["dems"][1]["alignment"]
    assert second["shift_m"]["east"] == pytest.approx(2.0 * shifts[1]["dx_px"], abs=1e-3)
    assert second["shift_m"]["north"] == pytest.approx(-2.0 * shifts[1]["dy_px"], abs=1e-3)
    assert second["shift_input_px"]["dem"]["dx_px"] == pytest.approx(shifts[1]["dx_px"])
    assert summary["dems"][0]["alignment"]["shift_m"]["east"] == 0.0
    count = dio.read_raster(output_paths(out)["count"]).data
    assert set(np.unique(count)) == {0, 1, 2, 3}
    assert np.isnan(fused.data[count == 0]).all()
    three = count == 3  # only there can a third value out-vote a blunder of DEM 2
    assert np.abs(diff[three]).max() < 0.4  # every 50 m blunder rejected
    assert np.sqrt(np.mean(diff[three] ** 2)) < 0.09  # 0.1 m noise averaged, shifts removed
    no_blunders = np.ones(count.shape, bool)
    no_blunders[30:110, 5:100] = False  # DEM 2's extent
    assert np.sqrt(np.nanmean(diff[no_blunders] ** 2)) < 0.12
    spread = dio.read_raster(output_paths(out)["spread"]).data
    # NMAD of three heights with 0.1 m noise: 1.4826 × the smaller distance to their
    # median, 0.054 m in the median (0.1 m is what three NMADs' rejection left, by
    # dropping the farthest of three good heights whenever it was 4.4 × the nearest)
    assert np.nanmedian(spread[three]) == pytest.approx(0.054, rel=0.25)
    assert np.isnan(spread[count == 1]).all()
    error = dio.read_raster(output_paths(out)["error"]).data
    assert np.isfinite(error[three]).all()


@pytest.mark.slow
def test_tiled_and_untiled_agree(block, tmp_path):
    folder, paths = block
    for i in (0, 1):  # holes, so that the gap closing and the border weights matter
        dem = dio.read_raster(paths[i])
        data = dem.data.copy()
        data[20:24, 30:70] = np.nan
        data[40:41, 10:13] = np.nan
        dio.write_raster(paths[i], data, transform=dem.transform, crs=dem.crs, tags=dem.tags)
    untiled = folder / "untiled.tif"
    tiled = folder / "tiled.tif"
    params = dict(blend=6, gap=2)  # margin 6 + 2 × 2 + 2 = 12 cells
    for method in ("mean", "huber"):
        run_fuse(paths, untiled, FuseParams(**params, method=method))
        run_fuse(paths, tiled, FuseParams(**params, method=method, tile_size=40))
        for name in ("dem", "count", "spread", "error"):
            a = dio.read_raster(output_paths(untiled)[name]).data
            b = dio.read_raster(output_paths(tiled)[name]).data
            np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
            np.testing.assert_allclose(b, a, atol=1e-4, equal_nan=True)


def test_huber_bounds_the_blunders_with_the_stack_scale(block):
    folder, paths = block
    out = folder / "huber.tif"
    summary = run_fuse(paths, out, FuseParams(blend=8, method="huber"))
    # 0.1 m noise per DEM: residuals to the median of two or three values
    assert 0.03 < summary["huber_scale_floor_m"] < 0.15
    fused = dio.read_raster(out)
    diff = fused.data - _truth_on(fused)
    count = dio.read_raster(output_paths(out)["count"]).data
    three = count == 3
    assert np.abs(diff[three]).max() < 0.4  # 50 m blunders weigh about c s / 50
    assert np.sqrt(np.mean(diff[three] ** 2)) < 0.09


def test_median_uses_error_rasters(tmp_path):
    folder, paths, errors = tmp_path, [], []
    for i, window in enumerate(WINDOWS):
        paths.append(folder / f"dem_{i}.tif")
        write_dem(paths[-1], window, noise=0.1, seed=i, shift=(0, 0, -0.8 * (i == 2)))
        errors.append(folder / f"err_{i}.tif")
        write_error(errors[-1], window, [0.1, 0.1, 5.0][i])
    out = folder / "median.tif"
    run_fuse(paths, out, FuseParams(method="median", align="none", outlier_k=50),
             errors=errors)
    fused = dio.read_raster(out)
    diff = fused.data - _truth_on(fused)
    count = dio.read_raster(output_paths(out)["count"]).data
    # the imprecise DEM 2 (error 5 m, 0.8 m too low, not aligned) loses wherever another
    # DEM is, also where it is one of two (an unweighted median would be 0.4 m low there)
    assert np.abs(diff[count >= 2]).max() < 0.6
    assert np.sqrt(np.mean(diff[count >= 2] ** 2)) < 0.12
    alone = np.zeros(count.shape, bool)
    alone[80:110, 5:100] = True  # DEM 2 only
    assert np.nanmedian(diff[alone & (count == 1)]) == pytest.approx(-0.8, abs=0.05)


def test_missing_error_raster_for_median_is_named(block):
    folder, paths = block
    write_error(folder / "dem_0_error.tif", WINDOWS[0], 0.1)  # found beside dem_0.tif only
    with pytest.raises(InputError, match=r"dem_1\.tif: no error raster.*--method median"):
        run_fuse(paths, folder / "m.tif", FuseParams(method="median"))
    assert not (folder / "m.tif").exists()
    with pytest.raises(ParameterError, match="one per DEM"):
        run_fuse(paths, folder / "m.tif", FuseParams(), errors=[folder / "dem_0_error.tif"])


def test_different_bodies_and_no_overlap_are_refused(tmp_path):
    write_dem(tmp_path / "moon.tif", (0, 40, 0, 40))
    write_dem(tmp_path / "mars.tif", (0, 40, 0, 40), body_id=499)
    with pytest.raises(InputError, match="mars.tif: is on Mars.*fuse DEMs of one body"):
        run_fuse([tmp_path / "moon.tif", tmp_path / "mars.tif"], tmp_path / "f.tif")
    write_dem(tmp_path / "far.tif", (200, 240, 200, 240))
    with pytest.raises(InputError, match="far.tif: no common overlap with the reference"):
        run_fuse([tmp_path / "moon.tif", tmp_path / "far.tif"], tmp_path / "f.tif")
    assert not (tmp_path / "f.tif").exists()


def test_every_dem_rejected_as_outlier_is_refused(tmp_path):
    for i in range(3):
        write_dem(tmp_path / f"d{i}.tif", (0, 60, 0, 60), noise=1.0, seed=i)
    paths = [tmp_path / f"d{i}.tif" for i in range(3)]
    with pytest.raises(InputError, match="every DEM was rejected as an outlier"):
        run_fuse(paths, tmp_path / "f.tif", FuseParams(align="none", max_nmad=0.5))
    # one noisier DEM among precise ones is left out, the rest fused
    write_dem(tmp_path / "d0.tif", (0, 60, 0, 60), noise=0.05, seed=0)
    write_dem(tmp_path / "d1.tif", (0, 60, 0, 60), noise=0.05, seed=1)
    write_dem(tmp_path / "d2.tif", (0, 60, 0, 60), noise=0.05, seed=2)
    write_dem(tmp_path / "d3.tif", (0, 60, 0, 60), noise=3.0, seed=3)
    summary = run_fuse([*paths, tmp_path / "d3.tif"], tmp_path / "f.tif",
                       FuseParams(align="none", max_nmad=0.5))
    assert [d["used"] for d in summary["dems"]] == [True, True, True, False]


def test_row_strips_on_threads_give_the_single_strip_numbers_to_the_bit(block, monkeypatch):
    from demtool.fuse import tiled
    from demtool.tiling.distributed import available_cores, threads_limited

    folder, paths = block
    dem = dio.read_raster(paths[1])
    data = dem.data.copy()
    data[20:24, 30:70] = np.nan  # a hole near a strip's edge: the gap closing matters
    dio.write_raster(paths[1], data, transform=dem.transform, crs=dem.crs, tags=dem.tags)
    monkeypatch.setattr(tiled, "THREADED_CELLS", 64)  # the 110² test grid in strips
    outputs = {}
    for threads in (1, 2):
        out = folder / f"fused_{threads}.tif"
        with threads_limited(threads):
            summary = run_fuse(paths, out, FuseParams(blend=6, gap=2, method="huber"))
        assert summary["strips"] == min(threads, available_cores())
        assert summary["timings_s"]["combine_cpu"] >= 0
        assert set(summary["timings_s"]) >= {"coregister", "consensus", "combine", "write"}
        outputs[threads] = {name: dio.read_raster(output_paths(out)[name]).data
                            for name in ("dem", "count", "spread", "error")}
        shifts = [d["alignment"]["shift"] for d in summary["dems"]]
        outputs[threads]["shifts"] = np.array([[s["dx_px"], s["dy_px"], s["dz"]]
                                               for s in shifts])
    for name, single in outputs[1].items():
        np.testing.assert_array_equal(outputs[2][name], single)  # NaN where NaN


def test_row_strips_cover_the_core_with_the_margin_clipped_to_the_grid():
    from demtool.fuse.tiled import THREADED_CELLS, row_strips, single_tile
    from demtool.tiling import Tile

    side = int(np.sqrt(THREADED_CELLS))  # even
    grid = (side + 10, side)
    half = grid[0] // 2
    strips = row_strips(single_tile(grid), grid, 20, 2)
    assert [s.core for s in strips] == [(0, half, 0, side), (half, grid[0], 0, side)]
    assert [s.outer for s in strips] == [(0, half + 20, 0, side), (half - 20, grid[0], 0, side)]
    assert row_strips(single_tile((100, 100)), (100, 100), 20, 2) == [single_tile((100, 100))]
    inner = Tile(3, (0, side, 40, 80), (0, side + 10, 20, 100))  # a Dask tile's columns kept
    assert all(s.outer[2:] == (20, 100) for s in row_strips(inner, grid, 20, 2))
    assert row_strips(single_tile(grid), grid, 20, 1) == [single_tile(grid)]


def test_the_reference_read_once_gives_each_dems_window_to_the_bit(block, monkeypatch):
    """coreg_samples reads the reference once for windows that overlap, on their union,
    and cuts each DEM's window from it: the numbers of one read per window."""
    from demtool.fuse import tiled
    from demtool.fuse.grids import grid_of, union_grid
    from demtool.fuse.overlap import coreg_samples

    _, paths = block
    specs = [grid_of(dio.raster_info(p)) for p in paths]
    target = union_grid(specs, specs[0])
    plans = {1: (target, (20, 70, 25, 80), 1), 2: (target, (35, 75, 10, 70), 1)}
    reads: list[tuple] = []
    original = tiled.sample_on_grid

    def counted(path, *args, **kwargs):
        reads.append((path, args[2]))
        return original(path, *args, **kwargs)

    monkeypatch.setattr(tiled, "sample_on_grid", counted)
    samples = coreg_samples(plans, {i: (paths[i], specs[i]) for i in plans},
                            (paths[0], specs[0]))
    # once, on the union (in two halves of rows, on two threads: in either order)
    assert sorted(w for p, w in reads if p == paths[0]) == [(20, 47, 10, 80),
                                                             (47, 75, 10, 80)]
    for i, (_, window, _) in plans.items():
        dem, ref = samples[i]
        assert np.array_equal(dem, original(paths[i], specs[i], target, window),
                              equal_nan=True)
        alone = original(paths[0], specs[0], target, window)
        assert ref.flags.c_contiguous and np.isfinite(ref).any()
        assert np.array_equal(ref.view(np.uint64), alone.view(np.uint64))


def test_outputs_written_on_threads_inside_the_transaction(tmp_path, monkeypatch):
    """write_outputs writes the rasters at once on threads, each inside the caller's
    output transaction: they appear at its end, with their pixels, and a failed write
    leaves none."""
    import threading

    from demtool.errors import OutputError
    from demtool.fuse.run import write_outputs
    from demtool.fuse.tiled import GridSpec
    from demtool.outputs import output_transaction
    from demtool.tiling import distributed

    monkeypatch.setattr(distributed, "usable_threads", lambda: 2)
    target = GridSpec((6, 5), (1.0, 0.0, 0.0, 0.0, -1.0, 0.0))
    bands = np.arange(4 * 30, dtype=np.float32).reshape(4, 6, 5)
    outputs = [(tmp_path / f"{name}.tif", band, name, {}) for band, name in
               enumerate(("dem", "count", "spread", "error"))]
    writers: set[str] = set()
    original = dio.write_raster

    def recorded(path, *args, **kwargs):
        writers.add(threading.current_thread().name)
        if "spread" in str(path) and fail:
            raise OutputError(f"{path}: disk full")
        return original(path, *args, **kwargs)

    monkeypatch.setattr(dio, "write_raster", recorded)
    fail = False
    with output_transaction():
        write_outputs(outputs, bands, target)
        assert not any(path.exists() for path, *_ in outputs)  # renamed at the end
    for path, band, _, _ in outputs:
        assert np.array_equal(dio.read_raster(path).data, bands[band])
    assert writers and all(n.startswith("demtool-write") for n in writers)  # not here
    fail = True
    moved = [(tmp_path / "again" / path.name, *rest) for path, *rest in outputs]
    with pytest.raises(OutputError, match="disk full"), output_transaction():
        write_outputs(moved, bands, target)
    assert not (tmp_path / "again").exists()


def test_consensus_read_in_halves_and_figures_on_threads_give_the_numbers_of_one_each(
        block, monkeypatch):
    """consensus_stack reads each DEM in two halves of rows, on threads, and
    consensus_figures computes the N NMADs and the stack's beside each other: the numbers
    of one read per DEM and of consensus_nmad and stack_nmad in turn, to the bit."""
    from demtool.fuse import tiled
    from demtool.fuse.core import consensus_nmad, stack_nmad
    from demtool.fuse.grids import grid_of, union_grid
    from demtool.fuse.overlap import consensus_figures, consensus_stack
    from demtool.tiling import distributed

    monkeypatch.setattr(distributed, "usable_threads", lambda: 2)
    _, paths = block
    specs = [grid_of(dio.raster_info(p)) for p in paths]
    target = union_grid(specs, specs[0])
    shifts = [(0.0, 0.0, 0.0), (-0.6, 0.4, -1.5), (0.25, 0.0, 0.8)]
    window = (15, 96, 8, 101)
    reads: list[tuple] = []
    original = tiled.sample_on_grid

    def counted(path, src, dst, cells, *args, **kwargs):
        reads.append((path, cells))
        return original(path, src, dst, cells, *args, **kwargs)

    monkeypatch.setattr(tiled, "sample_on_grid", counted)
    stack = consensus_stack(list(zip(paths, specs, shifts, strict=True)), target, window)
    assert sorted(cells for p, cells in reads if p == paths[1]) == [(15, 55, 8, 101),
                                                                    (55, 96, 8, 101)]
    whole = np.stack([original(p, s, target, window, shift)
                      for p, s, shift in zip(paths, specs, shifts, strict=True)])
    assert np.array_equal(stack.view(np.uint64), whole.view(np.uint64))
    nmads, floor = consensus_figures(stack, scale=True)
    assert np.array_equal(nmads, consensus_nmad(stack), equal_nan=True)
    assert floor == stack_nmad(stack) > 0
    again, none = consensus_figures(stack, scale=False)
    assert np.array_equal(again, nmads, equal_nan=True) and none == 0.0


def test_on_threads_maps_in_order_on_the_callers_limits(monkeypatch):
    """on_threads is demtool.tiling.rows.ordered_map on min(usable threads, items)
    threads: results in the items' order, each call with the caller's context; here in
    turn where numba's threading layer cannot launch kernels from two threads."""
    import threading

    from demtool.fuse.tiled import on_threads
    from demtool.tiling import distributed, local_threads
    from demtool.tiling.tasks import threads_limited

    def where(item):
        return item, threading.current_thread().name, distributed.usable_threads()

    monkeypatch.setattr(local_threads, "kernels_run_concurrently", lambda: True)
    with threads_limited(2):
        results = on_threads(where, range(5))
    assert [r[0] for r in results] == list(range(5))
    if distributed.available_cores() >= 2:
        assert all(name.startswith("demtool") for _, name, _ in results)
        assert {limit for *_, limit in results} == {2}  # the caller's limit, carried
    here = threading.current_thread().name
    with threads_limited(1):
        assert {r[1] for r in on_threads(where, range(3))} == {here}
    monkeypatch.setattr(local_threads, "kernels_run_concurrently", lambda: False)
    assert {r[1] for r in on_threads(where, range(3))} == {here}
