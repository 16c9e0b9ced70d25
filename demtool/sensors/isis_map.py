"""ISIS3 map-projected cubes (``cam2map``, ``map2map``): what the ``Mapping`` group says.

GDAL's ISIS3 driver (rasterio) reads such a cube *on its map*: the CRS from the
``Mapping`` group (projection, ``EquatorialRadius``/``PolarRadius``, ``CenterLongitude``
…) and the transform from ``UpperLeftCornerX/Y`` and ``PixelResolution``.  This module
adds what GDAL does not decide:

- :func:`mapping_summary`: one phrase naming the projection, the body and the pixel size,
  for messages;
- :func:`cube_values`: whether a cube's pixels are *heights* (a DEM: ISIS's DEM cubes carry
  no ``Instrument`` group and no ``BandBin``, or are tagged radius/elevation) or *image
  values* (I/F, DN: a camera image, even map-projected, keeps its ``Instrument`` group),
  so that a map-projected image is never taken for a DEM.

Reference: GDAL ``frmts/pds/isis3dataset.cpp`` (the ``Mapping`` group → OGR SRS).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


def mapping_summary(mapping: Any) -> str:
    """``"ISIS Mapping group: Equirectangular on Mars, 0.2526 m/px"`` from a Mapping group."""
    projection = str(mapping.get("ProjectionName", "unknown projection"))
    target = str(mapping.get("TargetName", "")) or "an unnamed body"
    resolution = mapping.get("PixelResolution")
    size = ""
    if resolution is not None:
        value = float(getattr(resolution, "value", resolution))
        size = f", {value:.4g} m/px"
    return f"ISIS Mapping group: {projection} on {target}{size}"


def read_cube_label(path: str | Path):
    """The PVL label of an ISIS3 cube, or None when the file is not an ISIS3 cube."""
    p = Path(path)
    try:
        with open(p, "rb") as handle:
            head = handle.read(200)
    except OSError:
        return None
    if b"IsisCube" not in head:
        return None
    from demtool.sensors.isis_label import read_label

    label, _ = read_label(p)
    return label


def cube_values(label: Any) -> str:
    """``"heights"`` or ``"image"``: what the pixels of a cube with this label are.

    A camera image keeps its ``Instrument`` group (and usually ``BandBin``) through
    ``cam2map``; ISIS's DEM cubes (``ldem``, ``mola``, ``demprep`` output) have neither.
    """
    cube = label["IsisCube"]
    if "Instrument" in cube or "BandBin" in cube:
        return "image"
    return "heights"


def refuse_image_as_dem(path: str | Path, what: str) -> None:
    """InputError when ``path`` is an ISIS cube of image values given as a DEM.

    Raises
    ------
    InputError
        One line naming the file, what it holds and the option (``what``).
    """
    from demtool.errors import InputError

    label = read_cube_label(path)
    if label is None or cube_values(label) == "heights":
        return
    cube = label["IsisCube"]
    instrument = cube.get("Instrument", {})
    camera = str(instrument.get("InstrumentId", "")) or "a camera"
    mapping = cube.get("Mapping")
    where = f" ({mapping_summary(mapping)})" if mapping is not None else ""
    raise InputError(f"{path}: is an image cube of {camera}{where}: its pixels are image "
                     f"values (I/F or DN), not heights; give a DEM as the {what}")


def refuse_cam2map_ortho(path: str | Path, what: str) -> None:
    """InputError when ``path`` is an ISIS map-projected image cube given to the
    map-projected stereo route (``sgm``/``dem --mapprojected``), which needs orthoimages
    demtool's ``mapproject`` tagged with their raw camera.

    Two ``cam2map`` cubes of line-scan cameras are read as such a pair
    (:mod:`demtool.sensors.isis_cam2map`: the raw camera from the cube's own tables);
    this refuses one given with an orthoimage of another kind, or a map-projected cube
    whose camera is not a line scanner, saying what to do instead.
    """
    from demtool.errors import InputError

    label = read_cube_label(path)
    if label is None or "Mapping" not in label["IsisCube"]:
        return
    cube = label["IsisCube"]
    instrument = cube.get("Instrument", {})
    camera = str(instrument.get("InstrumentId", "")) or "an unnamed camera"
    kind = "line-scan " if "LineExposureDuration" in instrument else ""
    raise InputError(f"{path}: {what} is an ISIS map-projected cube of {camera} "
                     f"({mapping_summary(cube['Mapping'])}) without demtool's mapproject "
                     f"tags: the map-projected route takes two ISIS cam2map cubes of "
                     f"line-scan cameras on one grid, or two orthoimages of demtool "
                     "mapproject; give the other image as such a cube, or map-project "
                     f"both raw {kind}images with demtool mapproject --sensor instead")
