"""What compare accepts: two height rasters of one frame.

``compare`` measures height differences; it must refuse, in one line, inputs whose
difference means nothing:

* **not heights**: a raster whose own tags say it is an image — an instrument cube of
  ISIS (its label has an ``Instrument`` group: I/F or DN of a camera, raw or
  map-projected by ``cam2map``), a demtool image or disparity (``demtool_stage``
  rectify, sgm, match or mapproject), or a raster tagged with an image's units (synth's
  views: ``units=DN``, its albedo: ``units=1``);
* **different frames**: a raster in an image's pixel frame (no CRS, ``frame=image:…``)
  or in a local metric frame (no CRS, ``frame=map:local``) against one on a body's map
  (a CRS): the pixel grid of one has no relation to the other's coordinates.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from demtool.errors import InputError

#: demtool stages whose rasters are images or disparities, never heights
IMAGE_STAGES = ("rectify", "sgm", "match", "mapproject")
#: ``units`` tags of images and albedo maps (synth's views are DN, its albedo 1)
NOT_HEIGHT_UNITS = ("DN", "1", "I/F", "reflectance", "radiance")


def not_heights_reason(tags: dict[str, str], isis_label: str = "") -> str | None:
    """Why a raster is not a height raster (None when nothing says so).

    tags : the raster's default-domain tags; isis_label : the text of its ISIS label
    (GDAL's ``json:ISIS3`` metadata domain), empty for other files
    """
    if '"Instrument"' in isis_label:
        return ("an instrument image (its ISIS label has an Instrument group: I/F or DN "
                "of a camera), not heights")
    stage = tags.get("demtool_stage", "")
    if stage in IMAGE_STAGES:
        what = "a disparity map" if stage in ("sgm", "match") else "an image"
        return f"{what} written by demtool {stage}, not heights"
    units = tags.get("units", "")
    if units in NOT_HEIGHT_UNITS:
        return f"tagged units={units} (an image or albedo), not heights"
    return None


def frame_kind(crs: Any, tags: dict[str, str]) -> str:
    """``"map"`` (a CRS), ``"image"`` (``frame=image:…``), ``"local"`` (``frame=map:local``)
    or ``"unknown"`` (no CRS, no frame tag)."""
    if crs is not None:
        return "map"
    frame = tags.get("frame", "")
    if frame.startswith("image:"):
        return "image"
    if frame.startswith("map:"):
        return "local"
    return "unknown"


def check_comparable(dem: tuple[str, Any, dict], reference: tuple[str, Any, dict]) -> None:
    """InputError (one line) when a DEM on a body's map meets one in an image's pixel frame
    or a local frame.

    dem, reference : (path, crs or None, tags)
    """
    (path, crs, tags), (ref_path, ref_crs, ref_tags) = dem, reference
    kinds = frame_kind(crs, tags), frame_kind(ref_crs, ref_tags)
    if "map" in kinds and kinds[0] != kinds[1] and "unknown" not in kinds:
        def describe(kind, c, t):
            if kind == "map":
                return f"on a map ({c.to_string() if hasattr(c, 'to_string') else c})"
            frame = t.get("frame", "")
            return (f"in an image's pixel frame ({frame}, no CRS)" if kind == "image"
                    else f"in a local metric frame ({frame}, no CRS)")
        raise InputError(f"{path}: is {describe(kinds[0], crs, tags)} but the reference "
                         f"{ref_path} is {describe(kinds[1], ref_crs, ref_tags)}; compare "
                         "needs both in one frame (a DEM on the body's map comes from dem "
                         "with sensor models or --mapprojected)")


def read_header(path: str | Path, what: str = "raster") -> tuple[Any, dict[str, str], str]:
    """(crs or None, tags, ISIS label text) of a raster, without reading its pixels."""
    import warnings

    from demtool import io as dio

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with dio._open_dataset(Path(path), what) as dataset:
            label = ""
            if "json:ISIS3" in (dataset.tag_namespaces() or []):
                domain = dataset.tags(ns="json:ISIS3")
                label = " ".join([*domain.keys(), *map(str, domain.values())])
            return dataset.crs, dict(dataset.tags()), label


def check_inputs(dem_path, reference_path, also=()) -> None:
    """Refuse (InputError) any input that is not heights, and frames that do not meet."""
    headers = {}
    for path, what in ((dem_path, "DEM"), (reference_path, "reference DEM"),
                       *((p, "DEM (--also)") for p in also)):
        crs, tags, label = read_header(path, what)
        reason = not_heights_reason(tags, label)
        if reason is not None:
            raise InputError(f"{path}: is {reason}; compare takes a {what} (heights in "
                             "metres)")
        headers[str(path)] = (str(path), crs, tags)
    for path in (dem_path, *also):
        check_comparable(headers[str(path)], headers[str(reference_path)])
