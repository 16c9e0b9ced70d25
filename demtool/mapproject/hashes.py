"""Content hashes of what an orthoimage was made from (issue 31, class 4).

``mapproject`` tags its orthoimage with the SHA-256 of the raw image, of the sensor model
and of the DEM it projected onto (:func:`hash_tags`); every stage that undoes the
projection (``dem --mapprojected``, ``refine`` on the map) checks them
(:func:`check_hashes`) and refuses an orthoimage whose sensor model or DEM has changed
since (a replaced ISD put a DEM 221 m off; a DEM raised 10 m afterwards a DEM 10 m high),
and a pair made of one image twice (:func:`check_distinct`).  Orthoimages written before
the hashes carry none and pass unchecked, with a note in the log.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from demtool.errors import InputError

IMAGE_HASH_TAG = "mapproject_image_sha256"
SENSOR_HASH_TAG = "mapproject_sensor_sha256"
DEM_HASH_TAG = "mapproject_dem_sha256"
#: the tag naming each hashed file, by hash tag (see demtool.mapproject.run)
NAMED_BY = {IMAGE_HASH_TAG: "mapproject_image", SENSOR_HASH_TAG: "mapproject_sensor",
            DEM_HASH_TAG: "mapproject_dem"}
_WHAT = {IMAGE_HASH_TAG: "raw image", SENSOR_HASH_TAG: "sensor model", DEM_HASH_TAG: "DEM"}


def hash_tags(image_path: str | os.PathLike, sensor_path: str | os.PathLike,
              dem_path: str | os.PathLike | None) -> dict[str, str]:
    """The SHA-256 tags of an orthoimage's raw image, sensor model and DEM (when given)."""
    from demtool.provenance import file_sha256

    tags = {IMAGE_HASH_TAG: file_sha256(image_path), SENSOR_HASH_TAG: file_sha256(sensor_path)}
    if dem_path is not None:
        tags[DEM_HASH_TAG] = file_sha256(dem_path)
    return {k: v for k, v in tags.items() if v}


def check_hashes(path: Any, tags: dict[str, Any], *, log=None,
                 which: tuple[str, ...] = (SENSOR_HASH_TAG, DEM_HASH_TAG)) -> None:
    """Refuse an orthoimage whose sensor model or DEM is not the one it was made with.

    Raises
    ------
    InputError
        One line naming the orthoimage, the changed file and both hashes' starts.
    """
    from demtool.provenance import file_sha256

    if not any(tag in tags for tag in which):
        if log is not None:
            log.info("%s: no content hashes (written before they were recorded): its sensor "
                     "model and DEM are taken as given", path)
        return
    for tag in which:
        recorded = tags.get(tag)
        named = tags.get(NAMED_BY[tag])
        if not recorded or not named:
            continue
        now = file_sha256(named)
        if now is None:
            continue  # a missing file is the reader's message
        if now != recorded:
            raise InputError(f"{path}: its {_WHAT[tag]} {named} has changed since it was "
                             f"map-projected (SHA-256 {recorded[:12]}… then, {now[:12]}… "
                             "now); map-project the image again")


def check_distinct(left_path: Any, left_tags: dict[str, Any], right_path: Any,
                   right_tags: dict[str, Any]) -> None:
    """Refuse a stereo pair of orthoimages that are one image (one file, or one raw image
    and sensor model projected twice): its parallax is zero everywhere."""
    same_file = Path(left_path).resolve() == Path(right_path).resolve()
    same_source = all(left_tags.get(t) and left_tags.get(t) == right_tags.get(t)
                      for t in (IMAGE_HASH_TAG, SENSOR_HASH_TAG))
    if same_file or same_source:
        raise InputError(f"{right_path}: is the same image as {left_path}"
                         f"{'' if same_file else ' (one raw image and sensor model)'}: a "
                         "stereo pair needs two views")


def check_pair_order(disparity_path: Any, left_path: Any, right_path: Any) -> None:
    """Refuse orthoimages that are not the pair the disparity was matched on, in its order.

    The disparity's provenance sidecar (``<disparity>.json``, written by ``sgm``/``match``)
    lists its inputs, left first, each with its SHA-256.  Given right as left, every
    parallax changes sign and the DEM is wrong everywhere (RMSE 3.55 m instead of 0.15 m);
    given orthoimages that are not the ones matched, the parallaxes belong to other
    images.  The check is by content (issue 46: a copied project folder kept the swap
    unseen while it compared paths): the two orthoimages' hashes must be the first two
    recorded, in that order.  A sidecar without hashes is compared by path; without a
    sidecar nothing is checked.
    """
    import json

    from demtool.provenance import file_sha256

    sidecar = Path(f"{disparity_path}.json")
    try:
        record = json.loads(sidecar.read_text())
        entries = [(Path(str(entry["path"])).resolve(), entry.get("sha256"))
                   for entry in record.get("inputs", [])]
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return
    recorded = [digest for _, digest in entries[:2]]
    if len(recorded) == 2 and all(recorded):
        given = [file_sha256(left_path), file_sha256(right_path)]
        if None in given or given == recorded:
            return
        if given == recorded[::-1]:
            _refuse_swapped(disparity_path, left_path, right_path, sidecar)
        which = [(what, path, now, then) for what, path, now, then in zip(
            ("left", "right"), (left_path, right_path), given, recorded, strict=True)
            if now != then]
        what, path, now, then = which[0]
        raise InputError(f"{path}: is not the {what} orthoimage {disparity_path} was matched "
                         f"on (SHA-256 {now[:12]}…, its sidecar records {then[:12]}…); give "
                         "the orthoimages it was matched on, or match these again")
    paths = [p for p, _ in entries]
    left, right = Path(left_path).resolve(), Path(right_path).resolve()
    if left in paths and right in paths and paths.index(left) > paths.index(right):
        _refuse_swapped(disparity_path, left_path, right_path, sidecar)


def _refuse_swapped(disparity_path: Any, left_path: Any, right_path: Any,
                    sidecar: Path) -> None:
    raise InputError(f"{disparity_path}: was matched with {right_path} as the left "
                     f"orthoimage and {left_path} as the right (its sidecar {sidecar}); give "
                     "them in that order")


def check_own_sensor(image_path: Any, tags: dict[str, Any], sensor_path: Any) -> bool:
    """Whether ``sensor_path`` is the model an orthoimage was map-projected through.

    ``refine IMAGE --sensor MODEL`` takes IMAGE as a raw image to map-project; given an
    orthoimage instead, MODEL must be the one it was made with (its SHA-256 tag, else the
    path it names): the sun and view of another image's model shade the DEM wrongly.

    Returns
    -------
    bool
        True when the orthoimage records this model (use the orthoimage as it is); False
        when it records none (a map image of unknown origin: the model is taken as given).

    Raises
    ------
    InputError
        The orthoimage records another model: one line naming both files.
    """
    from demtool.provenance import file_sha256

    recorded_hash = tags.get(SENSOR_HASH_TAG)
    recorded_path = tags.get(NAMED_BY[SENSOR_HASH_TAG])
    if not recorded_hash and not recorded_path:
        return False
    if recorded_hash:
        same = file_sha256(sensor_path) == recorded_hash
    else:
        same = Path(str(recorded_path)).resolve() == Path(sensor_path).resolve()
    if not same:
        raise InputError(f"{image_path}: is an orthoimage map-projected through "
                         f"{recorded_path or 'another sensor model'}, not through --sensor "
                         f"{sensor_path}: give the orthoimage's own model (or none), or the raw "
                         "image with this model")
    return True
