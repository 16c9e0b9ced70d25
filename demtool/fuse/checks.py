"""What ``demtool fuse`` checks before any work: one body or one image frame, an error
raster that is not the DEM itself, and the fused grid's size (:mod:`demtool.sizes`)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from demtool.fuse.grids import bounds_in

PathLike = str | os.PathLike


def check_frames(infos, paths) -> None:
    from demtool.compare.planetary import check_bodies
    from demtool.errors import InputError

    with_crs = [p for p, i in zip(paths, infos, strict=True) if i.crs is not None]
    if with_crs and len(with_crs) != len(paths):
        without = next(p for p, i in zip(paths, infos, strict=True) if i.crs is None)
        raise InputError(f"{without}: has no CRS but {with_crs[0]} has one; fuse DEMs of one "
                         "map (give every DEM its CRS)")
    if not with_crs:
        check_image_frames(infos, paths)
    distinct: dict[str, Any] = {}  # one raster per CRS: finding a CRS's body is slow (PROJ)
    for path, info in zip(paths, infos, strict=True):
        if info.crs is not None:
            distinct.setdefault(info.crs.to_wkt(), (path, info.crs))
    try:
        check_bodies(list(distinct.values()))
    except InputError as exc:
        raise InputError(str(exc).replace("compare DEMs of one body",
                                          "fuse DEMs of one body")) from None


def check_image_frames(infos, paths) -> None:
    """Refuse DEMs in the pixel frames of different images (``frame=image:<name>`` tags):
    their cells are not one place on the ground, whatever their grids say (issue 46: two
    targets' DEMs were fused into one)."""
    from demtool.errors import InputError

    frames = [(p, str(i.tags.get("frame", ""))) for p, i in zip(paths, infos, strict=True)]
    tagged = [(p, f) for p, f in frames if f.startswith("image:")]
    if tagged and any(f != tagged[0][1] for _, f in tagged):
        first, other = tagged[0], next((p, f) for p, f in tagged if f != tagged[0][1])
        raise InputError(f"{other[0]}: is in the frame of another image ({other[1]}) than "
                         f"{first[0]} ({first[1]}); fuse DEMs of one target image (or DEMs "
                         "on a map)")


def check_size(target, dems: Sequence[Path], specs, grid_like, tile_size: int,
                out: PathLike, log) -> None:
    """The fused grid's size before anything is allocated (:mod:`demtool.sizes`): its
    memory when untiled, its files' disk space either way; the error names what made it
    so big (``--grid-like``, or the DEM of the largest extent in the union)."""
    from demtool import sizes

    if grid_like:
        option = f"--grid-like {grid_like}"
    else:
        extents = []
        for spec in specs:
            xmin, ymin, xmax, ymax = bounds_in(spec, target.crs())
            extents.append(abs((xmax - xmin) * (ymax - ymin)))
        option = f"{dems[int(np.argmax(extents))]} (the union of the DEMs' extents)"
    cells = int(target.shape[0]) * int(target.shape[1])
    if not tile_size:
        # the stack of every DEM's values, weights and errors (float64) plus the 4 bands
        sizes.check_grid(target.shape, bytes_per_cell=24 * len(dems) + 32,
                         what="fused DEM", option=option, log=log,
                         hint="fuse onto a smaller grid (--grid-like), leave out the DEM "
                         "of the largest extent, or tile it (--tile-size)")
    sizes.check_disk(out, 16 * cells, what="fused DEM and its count, spread and error",
                     option=option)


def same_content(a: Path, b: Path) -> bool:
    """One file, or two files of one content (SHA-256)."""
    from demtool.provenance import file_sha256

    a, b = Path(a), Path(b)
    if a.resolve() == b.resolve():
        return True
    try:
        if a.stat().st_size != b.stat().st_size:
            return False
    except OSError:
        return False
    return file_sha256(a) == file_sha256(b)
