"""A ``.tsai`` pinhole in a body-fixed frame, put on its body for ``mapproject``.

ASP's ``cam_gen`` writes ``.tsai`` files for planetary frame cameras in the body-fixed
frame (ECEF-like, metres), but the file names neither the body nor the image size
(VisionWorkbench's ``PinholeModel`` carries neither).  ASP's ``mapproject`` takes both
from its inputs: the body from the DEM's datum, the size from the image.  So does
demtool: the body comes from ``--dem``'s CRS, else from ``--t-srs`` or ``--grid-like``;
the size from the image.  A ``.tsai`` in a rover's local frame, given a body, is then
refused by the sensor checks (a camera at the body's centre is inside the body).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

__all__ = ["TsaiOnBody", "tsai_on_body", "with_image_size"]


@dataclasses.dataclass(frozen=True)
class TsaiOnBody:
    """What a ``.tsai`` file lacks, taken from the run's other inputs.

    Attributes
    ----------
    radii : (float, float)
        The body's semi-major and semi-minor axes, metres.
    image_size : (int, int)
        The image's (lines, samples).
    source : str
        The input the body came from (``--dem``, ``--t-srs`` or ``--grid-like``).
    """

    radii: tuple[float, float]
    image_size: tuple[int, int]
    source: str


def with_image_size(sensor: Any, image_size: tuple[int, int] | None) -> Any:
    """The pinhole with the image's (lines, samples) where its file gave none."""
    if image_size is None or getattr(sensor, "lines", 1):
        return sensor
    lines, samples = image_size
    return dataclasses.replace(sensor, width=int(samples), height=int(lines))


def tsai_on_body(sensor_path: str | Path, image_size: tuple[int, int], *,
                 dem_crs: Any = None, t_srs: str | None = None,
                 grid_like_crs: Any = None) -> TsaiOnBody:
    """The body and image size of a ``.tsai`` camera, from the run's other inputs.

    Parameters
    ----------
    sensor_path : path-like
        The ``.tsai`` file (for the message).
    image_size : (int, int)
        The image's (lines, samples).
    dem_crs, grid_like_crs : CRS, optional
        The CRS of ``--dem`` and of ``--grid-like``.
    t_srs : str, optional
        ``--t-srs`` as given.

    Raises
    ------
    InputError
        When no input names the body (one line saying which options do).
    """
    from demtool.errors import InputError
    from demtool.maps import to_pyproj_crs
    from demtool.maps.bodies import body_from_crs

    for source, crs in (("--dem", dem_crs), ("--t-srs", t_srs), ("--grid-like", grid_like_crs)):
        if crs is None:
            continue
        body = body_from_crs(to_pyproj_crs(crs))
        return TsaiOnBody(radii=(float(body.a), float(body.c)),
                          image_size=(int(image_size[0]), int(image_size[1])), source=source)
    raise InputError(f"{sensor_path}: a .tsai file names no body: give --dem (a DEM on the "
                     "body), --t-srs or --grid-like (a map CRS of the body) so that its "
                     "body-fixed frame can be put on a body")


def ortho_sensor(sensor: Any, sensor_path: str | Path, crs: Any, image_size: Any) -> Any:
    """An orthoimage's sensor model, a ``.tsai`` put on the body of the map it was
    projected on (the ortho's CRS) at the image size ``mapproject`` recorded.

    Parameters
    ----------
    sensor : SensorModel
        The model as read from ``sensor_path`` (returned as is unless a ``.tsai`` with no
        body).
    sensor_path : path-like
        Its file.
    crs : CRS
        The orthoimage's map CRS.
    image_size : sequence of 2 ints or None
        The ``image_size`` tag mapproject wrote, (lines, samples).
    """
    from demtool.errors import InputError
    from demtool.sensors import read_sensor
    from demtool.sensors.tsai import TsaiCamera

    if not isinstance(sensor, TsaiCamera) or sensor.radii is not None:
        return sensor
    try:
        lines, samples = (int(v) for v in image_size)
    except (TypeError, ValueError):
        raise InputError(f"{sensor_path}: a .tsai carries no image size, and the "
                         f"orthoimage records none (image_size tag {image_size!r})") from None
    on_body = tsai_on_body(sensor_path, (lines, samples), dem_crs=crs)
    return with_image_size(read_sensor(sensor_path, radii=on_body.radii), on_body.image_size)
