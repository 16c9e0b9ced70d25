"""Synthetic bundle blocks with known truth: a 12-view ring and a 6-frame strip.

Both are small (256 px images, 50° diagonal field of view) and have no target view.
The ring's cameras have their principal point 15 px right and 6 px up of the image
centre (issue 14's check).
"""

from __future__ import annotations

from pathlib import Path

import pytest

COMMON = dict(seed=1, image_size=256, altitude_m=250.0, gsd_m=250.0 / 274.5, dem_size=640,
              crater_count=80, crater_max_diameter_m=60.0, boulder_count=300)
RING = dict(COMMON, layout="ring", n_views=12, bh_max=0.3, cx_offset_px=15.0,
            cy_offset_px=-6.0)
STRIP = dict(COMMON, layout="strip", n_views=6, partner_bh=0.25)


def write_block(folder: Path, params: dict) -> Path:
    """Render a scene and write its views (view_NN.tif) and cameras.npz into folder."""
    from demtool import io as dio
    from demtool.sensors.pinhole import cameras_to_arrays
    from demtool.synth import SceneParams, make_scene

    scene = make_scene(SceneParams(**params))
    folder.mkdir(parents=True, exist_ok=True)
    for name, image in scene.images.items():
        dio.write_raster(folder / f"{name}.tif", image)
    dio.write_npz(folder / "cameras.npz", "cameras",
                  cameras_to_arrays(list(scene.cameras), list(scene.cameras.values())))
    return folder


@pytest.fixture(scope="session")
def ring_dir(tmp_path_factory) -> Path:
    """A 12-view ring around the scene centre (read-only)."""
    return write_block(tmp_path_factory.mktemp("ring") / "ring", RING)


@pytest.fixture(scope="session")
def strip_dir(tmp_path_factory) -> Path:
    """Six nadir frames along a line, 25 % of the altitude apart (read-only)."""
    return write_block(tmp_path_factory.mktemp("strip") / "strip", STRIP)
