"""The tiles' kernels loaded ahead (demtool.mapproject.threads.load_tile_kernels) with
the argument types the tiles call them with: no second specialisation is compiled (a
fresh install would pay its compile), and a run that loads them ahead writes the same
orthoimage."""

import numba
import numpy as np
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from demtool.mapproject import core, sampling, threads
from demtool.sensors import kernels, read_sensor
from tests.helpers.linescan import linescan_sensor, write_scene


def _recording(monkeypatch, module, name, calls):
    kernel = getattr(module, name)

    def record(*args):
        calls.setdefault(name, set()).add(tuple(numba.typeof(a) for a in args))
        return kernel(*args)

    monkeypatch.setattr(module, name, record)


KERNELS = ((core, "_interpolate_lattice"), (sampling, "_bicubic_csm"),
           (sampling, "_on_image_bounds"), (kernels, "_detector_view_rows"))


def test_kernels_loaded_ahead_with_the_tiles_argument_types(tmp_path, monkeypatch):
    image, isd = write_scene(tmp_path, linescan_sensor(lines=150, samples=120,
                                                       roll_deg=12.0))
    ahead, tiles = {}, {}
    for module, name in KERNELS:
        _recording(monkeypatch, module, name, ahead)
    assert threads.load_tile_kernels(read_sensor(isd)) is True
    assert set(ahead) == {name for _, name in KERNELS}
    monkeypatch.undo()
    for module, name in KERNELS:
        _recording(monkeypatch, module, name, tiles)
    # the run loads them ahead too: not recorded (a thread of its own)
    monkeypatch.setattr(threads, "load_tile_kernels", lambda sensor=None: True)
    outs = []
    for ahead_run in (False, True):
        if ahead_run:
            monkeypatch.undo()
        out = tmp_path / f"ortho_{ahead_run}.tif"
        result = CliRunner().invoke(cli, ["mapproject", str(image), "--sensor", str(isd),
                                          "--height", "0", "--tile-size", "40", "--out",
                                          str(out)])
        assert result.exit_code == 0, result.output
        outs.append(dio.read_raster(out).data)
    assert tiles == ahead  # (the pose kernel's type in the set-up's calls too)
    assert np.isfinite(outs[0]).mean() > 0.5
    assert np.array_equal(outs[0], outs[1], equal_nan=True)


def test_a_failed_load_ahead_is_no_error(monkeypatch):
    def broken(*args):
        raise RuntimeError("no cache")

    monkeypatch.setattr(core, "_interpolate_lattice", broken)
    assert threads.load_tile_kernels() is False
    assert threads.KernelsAhead().wait() is False


def test_a_refused_run_leaves_no_kernel_thread_running(tmp_path, monkeypatch):
    """The load starts before the checks; a refusal (bounds off the footprint) waits for
    it, so no numba compile goes on after the ``Error:`` line in the caller's process
    (CI, issue 47: such a compile put back another command's ``sys.stderr``)."""
    import threading

    from demtool.tiling import side_threads

    image, isd = write_scene(tmp_path, linescan_sensor(lines=150, samples=120,
                                                       roll_deg=12.0))
    release, started = threading.Event(), []

    def slow_load(sensor=None):  # a compile that outlasts the checks
        started.append(threading.current_thread())
        assert release.wait(10)
        return True

    monkeypatch.setattr(threads, "load_tile_kernels", slow_load)
    real_join = side_threads.join_side_threads

    def join_after_release():  # the checks are done and refused: let the load end
        release.set()
        return real_join()

    monkeypatch.setattr(side_threads, "join_side_threads", join_after_release)
    monkeypatch.setattr(threads.KernelsAhead, "wait",
                        lambda self: (release.set(), self._thread.join())[1])
    result = CliRunner().invoke(cli, ["-q", "mapproject", str(image), "--sensor", str(isd),
                                      "--height", "0", "--bounds", "100", "10", "101", "11",
                                      "--out", str(tmp_path / "o.tif")])
    assert result.exit_code == 1
    assert "does not overlap the image's footprint" in result.output
    assert started and not started[0].is_alive()
    assert not (tmp_path / "o.tif").exists()
