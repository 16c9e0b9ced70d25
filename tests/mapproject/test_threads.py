"""Every core on the map-projected stages' untiled paths (demtool/mapproject/threads.py):
results in order and equal to one thread's, an error raised where the results are read,
a line scanner's ground-to-image in batches equal to one call, and mapproject's
in-process loop on two threads writing the same orthoimage and angles as on one, with
its phases' wall and CPU seconds in the sidecar."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from demtool.mapproject import threads
from tests.helpers.linescan import linescan_sensor, write_scene


def test_ordered_map_keeps_the_order_and_gives_each_call_a_share_of_numba_threads():
    import numba

    def call(k):
        return k, numba.get_num_threads()

    got = list(threads.ordered_map(call, range(9), threads=2))
    assert [k for k, _ in got] == list(range(9))
    share = max(1, threads.available_threads() // 2)
    assert {n for _, n in got} == {share}
    assert list(threads.ordered_map(lambda k: k * k, range(5), threads=1)) == [
        0, 1, 4, 9, 16]


def test_ordered_map_raises_a_call_error_where_the_results_are_read():
    def call(k):
        if k == 3:
            raise ValueError("tile 3 failed")
        return k

    with pytest.raises(ValueError, match="tile 3 failed"):
        list(threads.ordered_map(call, range(6), threads=2))


def test_linescan_ground_to_image_in_batches_equals_one_call():
    sensor = linescan_sensor(lines=400, samples=300, roll_deg=10.0)
    rng = np.random.default_rng(1)
    line = rng.uniform(-20, 420, 5000)  # some beyond the image's lines
    sample = rng.uniform(0, 300, 5000)
    xyz = sensor.image_to_ground(line, sample, rng.uniform(-50, 50, 5000))
    xyz[::97] = np.nan  # no surface there
    one = sensor.ground_to_image(xyz)
    batched = threads.ground_to_image_threaded(sensor, xyz, threads=2, min_batch=500)
    for a, b in zip(one, batched, strict=True):
        assert np.array_equal(a, b, equal_nan=True)
    assert np.isfinite(one[0]).mean() > 0.9


def test_in_process_mapproject_on_two_threads_writes_what_one_thread_writes(
        tmp_path, monkeypatch):
    image, isd = write_scene(tmp_path, linescan_sensor(lines=150, samples=120,
                                                       roll_deg=12.0))
    for count in (1, 2):
        monkeypatch.setattr(threads, "available_threads", lambda count=count: count)
        out, angles = tmp_path / f"ortho_{count}.tif", tmp_path / f"angles_{count}.tif"
        result = CliRunner().invoke(cli, ["mapproject", str(image), "--sensor", str(isd),
                                          "--height", "0", "--tile-size", "40", "--out",
                                          str(out), "--angles-out", str(angles)])
        assert result.exit_code == 0, result.output
        summary = json.loads(out.with_suffix(".tif.json").read_text())["summary"]
        assert summary["threads"] == count
        assert summary["tiles"] >= 6
        timings = summary["timings_s"]
        for phase in ("setup", "project"):
            assert timings[phase] > 0 and timings[f"{phase}_cpu"] >= 0
    for name in ("ortho", "angles"):
        a = dio.read_raster(tmp_path / f"{name}_1.tif").data
        b = dio.read_raster(tmp_path / f"{name}_2.tif").data
        assert np.isfinite(a).mean() > 0.5
        assert np.array_equal(a, b, equal_nan=True), name


def test_dem_triangulation_and_gridding_on_two_threads_equal_one_thread(monkeypatch):
    """dem --mapprojected's batched steps (triangulate_sensors, dem_on_map with its
    overlap) give the values of one batch, batches forced small."""
    from demtool.dem.sensors import dem_on_map, triangulate_sensors
    from tests.helpers.linescan import MOON

    # rolled ±8° from tracks 0.2324° east and west of lon 10° (a positive roll looks
    # east): both views centred on the site
    left = linescan_sensor(lines=160, samples=140, roll_deg=-8.0, lon0=10.2324)
    right = linescan_sensor(lines=160, samples=140, roll_deg=8.0, lon0=9.7676)
    line, sample = np.meshgrid(np.arange(10, 150, 2.0) + 0.5, np.arange(10, 130, 2.0) + 0.5,
                               indexing="ij")
    xyz = left.image_to_ground(line.ravel(), sample.ravel(), 0.0)
    r_line, r_sample = right.ground_to_image(xyz)
    monkeypatch.setattr(threads, "MIN_BATCH", 200)
    runs = []
    for count in (1, 2):
        monkeypatch.setattr(threads, "available_threads", lambda count=count: count)
        tri = triangulate_sensors(left, right, line.ravel(), sample.ravel(), r_line, r_sample)
        ok = np.isfinite(tri.xyz).all(axis=1) & tri.in_front
        runs.append((tri, dem_on_map(tri.xyz[ok], tri.gap[ok], MOON, gsd_m=2.0,
                                     left=left, right=right)))
    (tri1, dem1), (tri2, dem2) = runs
    assert ((r_line > 0) & (r_line < 160) & (r_sample > 0) & (r_sample < 140)).mean() > 0.5
    for a, b in zip(tri1, tri2, strict=True):
        assert np.array_equal(a, b, equal_nan=True)
    assert np.nanmax(np.abs(tri1.gap)) < 1e-3  # the rays of one ground point meet
    for name in ("dem", "error", "filled", "overlap", "points"):
        assert np.array_equal(getattr(dem1, name), getattr(dem2, name), equal_nan=True), name
    assert np.isfinite(dem1.dem).mean() > 0.3
