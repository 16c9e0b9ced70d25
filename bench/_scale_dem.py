"""A calibrated pair of any size with an exact disparity, for the `dem` rows of scale.py.

Two nadir pinholes 4000 m above smooth terrain (0.5 m GSD, B/H 0.3), the right
camera's principal point shifted by the mean disparity so the images overlap (the
left image frame is then the rectified frame: both homographies are the identity).
The disparity is exact (rays cut with the terrain by fixed-point iteration), with
holes (rectangles, a strip) and 0.5 % wild values; ``truth.npy`` holds the heights on
the left image's grid.  Written strip by strip, so 8192² fits in memory.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

ALTITUDE, FOCAL, BASE = 4000.0, 8000.0, 1200.0  # m, px, m


def terrain(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Heights, metres: hills and a finer undulation."""
    return 20.0 * np.sin(x / 150.0) * np.cos(y / 200.0) + 5.0 * np.sin(x / 37.0 + y / 53.0)


def cameras(size: int):
    from demtool.sensors.pinhole import PinholeCamera

    shift = FOCAL * BASE / ALTITUDE
    R = np.diag([1.0, -1.0, -1.0])  # looking down, image y toward −Y (north up)
    cameras = []
    for x, cx in ((0.0, 0.5 * (size - 1)), (BASE, 0.5 * (size - 1) + shift)):
        K = np.array([[FOCAL, 0.0, cx], [0.0, FOCAL, 0.5 * (size - 1)], [0.0, 0.0, 1.0]])
        cameras.append(PinholeCamera(K=K, R=R, t=-R @ np.array([x, 0.0, ALTITUDE]),
                                     width=size, height=size))
    return cameras


def write_dem_pair(folder: Path, size: int, strip: int = 256) -> None:
    """disparity.tif, rectify.npz, cameras.npz and truth.npy of a ``size²`` pair."""
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    from demtool import io as dio
    from demtool.sensors.pinhole import cameras_to_arrays

    folder.mkdir(parents=True, exist_ok=True)
    left, right = cameras(size)
    rng = np.random.default_rng(size)
    truth = np.empty((size, size), dtype=np.float32)
    profile = {"driver": "GTiff", "dtype": "float32", "nodata": float("nan"), "count": 1,
               "height": size, "width": size, "compress": "deflate", "predictor": 3,
               "tiled": True, "blockxsize": 256, "blockysize": 256,
               "transform": dio.image_frame_transform(1.0)}
    warnings.simplefilter("ignore", NotGeoreferencedWarning)
    with rasterio.open(folder / "disparity.tif", "w", **profile) as dst:
        for r0 in range(0, size, strip):
            rows, cols = np.mgrid[r0:min(size, r0 + strip), :size]
            pixels = np.column_stack([cols.ravel(), rows.ravel()]).astype(np.float64)
            heights = np.zeros(len(pixels))
            for _ in range(12):
                points = left.backproject(pixels, ALTITUDE - heights)
                heights = terrain(points[:, 0], points[:, 1])
            points = left.backproject(pixels, ALTITUDE - heights)
            disparity = (pixels[:, 0] - right.project(points)[:, 0]).reshape(rows.shape)
            wild = rng.random(disparity.shape) < 0.005
            disparity[wild] += rng.normal(0.0, 8.0, int(wild.sum()))
            truth[r0:r0 + rows.shape[0]] = points[:, 2].reshape(rows.shape)
            dst.write(disparity.astype(np.float32), 1,
                      window=rasterio.windows.Window(0, r0, size, rows.shape[0]))
        dst.update_tags(frame="image:left_rect")
        hole = size // 8  # a wide hole, a strip across, a hole on the edge
        for r0, r1, c0, c1 in ((size // 4, size // 4 + hole, size // 3, size // 3 + hole),
                               (size // 2, size // 2 + 6, 0, size),
                               (3 * size // 4, 3 * size // 4 + hole, 0, hole)):
            dst.write(np.full((r1 - r0, c1 - c0), np.nan, np.float32), 1,
                      window=rasterio.windows.Window(c0, r0, c1 - c0, r1 - r0))
    np.save(folder / "truth.npy", truth)
    dummy = np.zeros((4, 2))
    dio.write_npz(folder / "rectify.npz", "rectification", {
        "H_left": np.eye(3), "H_right": np.eye(3), "F": np.zeros((3, 3)),
        "size_left": np.array([size, size]), "size_right": np.array([size, size]),
        "size_rect": np.array([size, size]), "points_left": dummy, "points_right": dummy,
        "points_left_rect": dummy, "points_right_rect": dummy,
        "disparity_range": np.array([-25.0, 25.0]), "left_name": np.asarray("left"),
        "right_name": np.asarray("right")})
    dio.write_npz(folder / "cameras.npz", "cameras",
                  cameras_to_arrays(["left", "right"], [left, right]))
