"""The files of a rectified pair (``left_rect.tif``, ``right_rect.tif``, ``rectify.npz``
and its sidecar), written the same way by both rectify routes: from matches
(:mod:`demtool.rectify.run`) and from sensor models (:mod:`demtool.rectify.run_sensors`).
"""

from __future__ import annotations

from pathlib import Path

from demtool.stagerun import StageRun

LEFT_RECT = "left_rect.tif"
RIGHT_RECT = "right_rect.tif"
RECTIFY_NPZ = "rectify.npz"


def write_rectified_pair(run: StageRun, out: Path, images, names, arrays: dict,
                         summary: dict, side_tags=({}, {})) -> None:
    """Write OUT/left_rect.tif, OUT/right_rect.tif, OUT/rectify.npz and its sidecar in
    the run's transaction (both rectify routes).

    ``images``/``names``: (left, right) rectified rasters and original view names;
    ``arrays``: the rectification NPZ content; ``side_tags``: extra tags of each image.
    """
    from demtool import io as dio

    npz_path = out / RECTIFY_NPZ
    disparity_range = [float(v) for v in arrays["disparity_range"]]
    with run.transaction():
        for path, image, name, extra in zip((out / LEFT_RECT, out / RIGHT_RECT), images, names,
                                            side_tags, strict=True):
            dio.write_raster(path, image, transform=dio.image_frame_transform(1.0),
                             tags=run.provenance.tags(frame=f"image:{name}_rect",
                                                      rectified_from=name, **extra,
                                                      disparity_range=disparity_range))
        dio.write_npz(npz_path, "rectification", arrays)
        run.provenance.write_sidecar(npz_path, summary,
                                     outputs=[out / LEFT_RECT, out / RIGHT_RECT, npz_path])
