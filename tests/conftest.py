"""Shared fixtures: a small synthetic scene, in memory and written by `demtool synth`.

The scene keeps the demo's geometry (nadir target ``view_00``, partner ``view_01``
with B/H 0.3 along image x, 1 m DEM cells, 0.5 m target GSD) at a size that renders
in about a second once numba's cache is warm.  Use ``small_scene`` for the arrays and
truth (``demtool.synth.Scene``), ``small_scene_dir`` for the files (read-only: copy
them before modifying anything).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

# Every write of a stage must be declared in its StageRun (demtool.outputs.CHECK_DECLARED_ENV).
os.environ.setdefault("DEMTOOL_CHECK_DECLARED_OUTPUTS", "1")


@pytest.fixture(autouse=True)
def _side_threads_end_with_the_test():
    """A side thread a test started itself (or a library call left) ends before the next
    test, whose streams and warning filters it would otherwise change
    (demtool.tiling.side_threads; the command group and the stages join their own)."""
    yield
    from demtool.tiling.side_threads import join_side_threads

    join_side_threads()


# The arguments of `demtool synth` for the small scene, and the same as SceneParams.
SMALL_SCENE_ARGS = ["--seed", "0", "--size", "256", "--views", "4", "--image-size", "192",
                    "--craters", "20", "--crater-max", "50", "--boulders", "100"]
SMALL_SCENE_PARAMS = dict(seed=0, dem_size=256, n_views=4, image_size=192, crater_count=20,
                          crater_max_diameter_m=50.0, boulder_count=100)


@pytest.fixture(scope="session")
def small_scene_params():
    """SceneParams of the small test scene."""
    from demtool.synth import SceneParams

    return SceneParams(**SMALL_SCENE_PARAMS)


@pytest.fixture(scope="session")
def small_scene(small_scene_params):
    """The small synthetic scene in memory (``demtool.synth.Scene``)."""
    from demtool.synth import make_scene

    return make_scene(small_scene_params)


@pytest.fixture(scope="session")
def small_scene_dir(tmp_path_factory) -> Path:
    """A folder written by ``demtool synth`` with the small scene (same as ``small_scene``).

    Contains view_00.tif (target) … view_03.tif, truth_dem.tif, truth_dem_target.tif,
    albedo.tif, cameras.npz, scene.json and scene.json.json.
    """
    from click.testing import CliRunner

    from demtool.cli import cli

    out = tmp_path_factory.mktemp("small_scene") / "scene"
    result = CliRunner().invoke(cli, ["-q", "synth", "--out", str(out), *SMALL_SCENE_ARGS])
    assert result.exit_code == 0, result.output
    return out


#: side of the ``stereo_scene`` images, pixels
STEREO_SCENE_SIZE = 256


@pytest.fixture(scope="session")
def stereo_scene():
    """A textured terrain seen by two cameras with known geometry (rectify tests)."""
    from tests.helpers.features import make_stereo_scene

    return make_stereo_scene(size=STEREO_SCENE_SIZE)
