"""Files of a synthetic rover pair (:mod:`demtool.synth.rover`) for tests and benchmarks.

``write_rover_pair(folder)`` writes ``left.tif``, ``right.tif`` (image frame rasters) and
``cameras.npz`` (the two local-frame pinholes, no body) and returns the
:class:`~demtool.synth.rover.RoverScene` (the truth).  ``local_dem_errors`` compares a
local DEM written by ``demtool dem`` with that truth.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from demtool import io as dio
from demtool.sensors.pinhole import cameras_to_arrays
from demtool.synth.rover import RoverScene, make_rover_pair


def write_rover_pair(folder: str | Path, **options: Any) -> RoverScene:
    """Write ``left.tif``, ``right.tif`` and ``cameras.npz`` of a rover pair into ``folder``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    scene = make_rover_pair(**options)
    for name, image in (("left", scene.left_image), ("right", scene.right_image)):
        dio.write_raster(folder / f"{name}.tif", image,
                         transform=dio.image_frame_transform(1.0),
                         tags={"frame": f"image:{name}"})
    dio.write_npz(folder / "cameras.npz", "cameras",
                  cameras_to_arrays(["left", "right"], [scene.left, scene.right]))
    return scene


def local_dem_errors(dem_path: str | Path, scene: RoverScene) -> dict[str, float]:
    """Height errors (m) of a local DEM (``frame=map:local``) against the scene's truth.

    Each valid cell's point (local x, y, height) is taken back to the models' frame
    through the axes in the DEM's tags; its error is its height minus the truth height
    of the ground at the same horizontal position (along up).  Also: the median range
    from the left camera to the cells (the scale of the 1 % target), the number of
    cells behind either camera, and the left camera's height above a plane fitted to
    the DEM's cells and to the truth at the same cells (the issue's held-out check on a
    real rover: the ground where the cameras say).
    """
    from demtool.dem.local import LocalFrame, cells_behind_cameras

    dem = dio.read_raster(dem_path, what="DEM")
    axes = np.stack([np.array([float(v) for v in dem.tags[key].split(",")])
                     for key in ("local_x_axis", "local_y_axis", "local_up")])
    frame = LocalFrame(axes)
    rr, cc = np.nonzero(np.isfinite(dem.data))
    t = dem.transform
    x = t.c + (cc + 0.5) * t.a
    y = t.f + (rr + 0.5) * t.e
    h = dem.data[rr, cc].astype(np.float64)
    points = frame.to_frame(np.stack([x, y, h], axis=-1))
    truth = frame.to_local(scene.truth_xyz(points))[:, 2]
    error = h - truth
    ranges = np.linalg.norm(points - scene.left.center, axis=1)
    camera = frame.to_local(scene.left.center[None])[0]

    def height_above_plane(values):  # the held-out check's figure: a plane fitted to
        design = np.column_stack([x, y, np.ones_like(x)])  # the ground, at the camera
        coefficients, *_ = np.linalg.lstsq(design, values, rcond=None)
        return float(camera[2] - coefficients @ [camera[0], camera[1], 1.0])
    return {
        "cells": int(len(h)),
        "rmse_m": float(np.sqrt(np.mean(error ** 2))),
        "median_error_m": float(np.median(error)),
        "nmad_m": float(1.4826 * np.median(np.abs(error - np.median(error)))),
        "median_range_m": float(np.median(ranges)),
        "behind_camera": cells_behind_cameras(dem.data, t, frame, (scene.left, scene.right)),
        "camera_above_plane_m": height_above_plane(h),
        "camera_above_plane_truth_m": height_above_plane(truth),
    }
